//! The ray-cast capsule likelihood (eq. 3 and 6 of the body paper) on the CPU: Listing 1.2's
//! single-thread loop (the baseline every speed-up is quoted against) and a rayon version over
//! samples. The GPU kernels ([`gpu`], `shaders/body/likelihood.wgsl`) are tested against these.
//!
//! For a sample j with capsules C_j: M_j = Σ_i (min_k d_ik)², d from [`truncated_distance`], and
//! log p(X | θ_j) = −M_j / (2σ²). Sums are accumulated in f64.

use nalgebra::Vector3;
use rayon::prelude::*;

use crate::capsule::{Capsule, ray_capsule, truncated_distance};
use crate::error::BodyError;

mod coarse;
pub mod gpu;
mod gpu_rays;

pub use coarse::CoarseLayers;

/// Points per workgroup tile of the paper's layout (`TILE` in the shader).
pub(crate) const TILE: usize = 256;
/// Points per workgroup tile of the fast kernel (`FAST_POINTS * TILE`).
pub(crate) const FAST_TILE: usize = 4 * TILE;

/// The WGSL of the capsule likelihood, launched by [`gpu::CapsuleLikelihoodGpu`]; this module's
/// sums are its CPU twin.
pub const SHADER: &str = include_str!("../../../../shaders/body/likelihood.wgsl");

/// The rays of a stereo point cloud seen from one camera: per point, the unit direction from the
/// camera origin and the distance Δ_i along it.
#[derive(Debug, Clone, PartialEq)]
pub struct Rays {
    pub origin: Vector3<f32>,
    pub directions: Vec<Vector3<f32>>,
    pub depths: Vec<f32>,
}

impl Rays {
    /// Rays from `origin` through each point. A non-finite point, or one at the origin itself (no
    /// direction), is an error naming it.
    pub fn through(origin: Vector3<f32>, points: &[Vector3<f32>]) -> Result<Self, BodyError> {
        let mut directions = Vec::with_capacity(points.len());
        let mut depths = Vec::with_capacity(points.len());
        for (i, p) in points.iter().enumerate() {
            if !p.iter().all(|x| x.is_finite()) {
                return Err(BodyError::InvalidInput(format!(
                    "point {i} is not finite: ({}, {}, {})",
                    p.x, p.y, p.z
                )));
            }
            let offset = p - origin;
            let depth = offset.norm();
            if depth <= 0.0 || depth.is_nan() {
                return Err(BodyError::InvalidInput(format!(
                    "point {i} lies on the camera origin"
                )));
            }
            directions.push(offset / depth);
            depths.push(depth);
        }
        Ok(Self {
            origin,
            directions,
            depths,
        })
    }

    pub fn len(&self) -> usize {
        self.depths.len()
    }

    /// The GPU layout: `[dir.x, dir.y, dir.z, depth]` per point.
    pub fn gpu_layout(&self) -> Vec<[f32; 4]> {
        self.directions
            .iter()
            .zip(&self.depths)
            .map(|(d, &depth)| [d.x, d.y, d.z, depth])
            .collect()
    }

    pub fn is_empty(&self) -> bool {
        self.depths.is_empty()
    }
}

/// The likelihood's parameters: the truncation τ (eq. 6) and the noise σ (eq. 3).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CapsuleLikelihoodParams {
    pub tau: f32,
    pub sigma: f32,
}

impl CapsuleLikelihoodParams {
    /// The largest τ, in metres: a scene is a few metres across, and a τ² summed over a frame's
    /// points must stay far from f32's range on the GPU (a τ of 1e19 made every log-weight −∞).
    pub const TAU_MAX: f32 = 100.0;

    pub fn new(tau: f32, sigma: f32) -> Result<Self, BodyError> {
        if !(tau > 0.0 && tau <= Self::TAU_MAX && sigma.is_finite() && sigma > 0.0) {
            return Err(BodyError::InvalidInput(format!(
                "tau must be above 0 and at most {} m, and sigma finite and > 0 (got tau {tau}, sigma {sigma})",
                Self::TAU_MAX
            )));
        }
        Ok(Self { tau, sigma })
    }

    /// log p(X | θ) = −M / (2σ²).
    pub fn log_likelihood(&self, sum_sq: f64) -> f64 {
        -sum_sq / (2.0 * f64::from(self.sigma) * f64::from(self.sigma))
    }
}

/// M = Σ_i (min_k d_ik)² for one sample's capsules: the body of Listing 1.2's sample loop.
pub fn sum_of_squared_distances(capsules: &[Capsule], rays: &Rays, tau: f32) -> f64 {
    let mut sum = 0.0f64;
    for (dir, &depth) in rays.directions.iter().zip(&rays.depths) {
        let best = point_min_distance(capsules, &rays.origin, dir, depth, tau);
        sum += f64::from(best) * f64::from(best);
    }
    sum
}

/// Listing 1.2: every sample, every point, every capsule, on one thread. `samples[j]` holds the
/// capsules of sample j; returns M_j.
pub fn listing_1_2(samples: &[Vec<Capsule>], rays: &Rays, tau: f32) -> Vec<f64> {
    samples
        .iter()
        .map(|c| sum_of_squared_distances(c, rays, tau))
        .collect()
}

/// The same on all cores, samples in parallel.
pub fn parallel_over_samples(samples: &[Vec<Capsule>], rays: &Rays, tau: f32) -> Vec<f64> {
    samples
        .par_iter()
        .map(|c| sum_of_squared_distances(c, rays, tau))
        .collect()
}

/// The GPU layout of capsules: `[a.x, a.y, a.z, r]`, `[b.x, b.y, b.z, 0]` per capsule, appended
/// to `out` (call once per sample, in sample order).
pub fn capsules_gpu_layout(capsules: &[Capsule], out: &mut Vec<[f32; 4]>) {
    for c in capsules {
        out.push([c.a.x, c.a.y, c.a.z, c.radius]);
        out.push([c.b.x, c.b.y, c.b.z, 0.0]);
    }
}

/// A capsule's bounding sphere (centre, radius) for [`culled_sum_of_squared_distances`].
fn bounding_sphere(c: &Capsule) -> (Vector3<f32>, f32) {
    ((c.a + c.b) * 0.5, (c.b - c.a).norm() * 0.5 + c.radius)
}

/// Whether the ray can meet the sphere within τ of `depth`: if not, the capsule inside it is at
/// distance τ for this point and its quadratics need not be solved.
fn sphere_may_matter(
    origin: &Vector3<f32>,
    dir: &Vector3<f32>,
    sphere: &(Vector3<f32>, f32),
    depth: f32,
    tau: f32,
) -> bool {
    let w = origin - sphere.0;
    let b = dir.dot(&w);
    let disc = b * b - (w.norm_squared() - sphere.1 * sphere.1);
    if disc < 0.0 {
        return false;
    }
    let s = disc.sqrt();
    let (enter, exit) = (-b - s, -b + s);
    // A small margin keeps rounding from culling a capsule whose hit is right at depth ± τ.
    let margin = 1e-4 * (1.0 + depth);
    exit >= 0.0 && enter <= depth + tau + margin && exit >= depth - tau - margin
}

/// M for one sample, as [`sum_of_squared_distances`], but each capsule's bounding sphere is
/// tested first (the CPU form of the fast GPU kernel's culling): the tracker's CPU path.
pub fn culled_sum_of_squared_distances(capsules: &[Capsule], rays: &Rays, tau: f32) -> f64 {
    culled_sum_over(capsules, &rays.origin, &rays.directions, &rays.depths, tau)
}

/// The culled M over some of a frame's rays.
fn culled_sum_over(
    capsules: &[Capsule],
    origin: &Vector3<f32>,
    directions: &[Vector3<f32>],
    depths: &[f32],
    tau: f32,
) -> f64 {
    let spheres: Vec<_> = capsules.iter().map(bounding_sphere).collect();
    let mut sum = 0.0f64;
    for (dir, &depth) in directions.iter().zip(depths) {
        let mut best = tau;
        for (c, sphere) in capsules.iter().zip(&spheres) {
            if sphere_may_matter(origin, dir, sphere, depth, tau) {
                best = best.min(truncated_distance(ray_capsule(origin, dir, c), depth, tau));
            }
        }
        sum += f64::from(best) * f64::from(best);
    }
    sum
}

/// The same M over all cores, the rays in chunks (each chunk summed in order, then the chunks in
/// order, so the result does not depend on the threads): one sample against a large frame, the
/// tracker's check of its estimate (5.5 ms on one core for 42 000 rays).
pub fn culled_sum_of_squared_distances_parallel(
    capsules: &[Capsule],
    rays: &Rays,
    tau: f32,
) -> f64 {
    const CHUNK: usize = 2048;
    let sums: Vec<f64> = rays
        .directions
        .par_chunks(CHUNK)
        .zip(rays.depths.par_chunks(CHUNK))
        .map(|(directions, depths)| {
            culled_sum_over(capsules, &rays.origin, directions, depths, tau)
        })
        .collect();
    sums.iter().sum()
}

/// min_k d_ik for one ray (the inner loops of Listing 1.2).
pub fn point_min_distance(
    capsules: &[Capsule],
    origin: &Vector3<f32>,
    dir: &Vector3<f32>,
    depth: f32,
    tau: f32,
) -> f32 {
    capsules
        .iter()
        .map(|c| truncated_distance(ray_capsule(origin, dir, c), depth, tau))
        .fold(tau, f32::min)
}
