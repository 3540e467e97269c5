//! Capsules and the ray–capsule intersection of the paper's Appendix A.
//!
//! A capsule is the set of points within `radius` of the segment a→b: an open cylinder around
//! the axis plus two end spheres. A ray from the camera origin `p` with unit direction `v` first
//! enters the capsule at the smallest non-negative root among
//! - P_c, the infinite cylinder `|w⊥ + Δ v⊥|² = r²` (w = p − a, ⊥: the part orthogonal to the
//!   axis), valid only where the hit projects inside the segment, and
//! - P_a, P_b, the spheres `|p + Δ v − a|² = r²` and the same around b,
//!
//! because the union's first entry is the earliest entry into any of its parts (the cylinder's
//! caps lie inside the spheres). A zero-length bone is a sphere.

use nalgebra::Vector3;

/// One capsule: the segment a→b and its radius.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Capsule {
    pub a: Vector3<f32>,
    pub b: Vector3<f32>,
    pub radius: f32,
}

/// The smallest root ≥ 0 of `q2 Δ² + 2 q1 Δ + q0 = 0`, if any (`q2 > 0`), given its
/// discriminant `disc` = q1² − q2·q0.
///
/// The caller computes `disc` without that subtraction: near a silhouette q1² and q2·q0 are
/// both of the order of q2·|w⊥|² (the camera's distance from the axis, metres, squared) while
/// their difference is of the order of q2·r², so f32 loses most of its digits there (a point
/// 2.9 m away came out 0.2 mm off). Lagrange's identity gives the same difference from terms
/// the size of the answer: for the cylinder q2·r² − |v⊥ × w⊥|², for a sphere (unit `dir`)
/// r² − |dir × w|². The GPU kernel (`shaders/body/likelihood.wgsl`) does the same.
fn first_nonnegative_root(q2: f32, q1: f32, disc: f32) -> Option<f32> {
    if disc < 0.0 {
        return None;
    }
    let s = disc.sqrt();
    let near = (-q1 - s) / q2;
    if near >= 0.0 {
        return Some(near);
    }
    let far = (-q1 + s) / q2;
    (far >= 0.0).then_some(far)
}

/// Where the ray `origin + Δ·dir` (unit `dir`) first meets a sphere, Δ ≥ 0.
pub fn ray_sphere(
    origin: &Vector3<f32>,
    dir: &Vector3<f32>,
    centre: &Vector3<f32>,
    radius: f32,
) -> Option<f32> {
    let w = origin - centre;
    let disc = radius * radius - dir.cross(&w).norm_squared();
    first_nonnegative_root(1.0, dir.dot(&w), disc)
}

/// Where the ray `origin + Δ·dir` (unit `dir`) first meets the capsule, Δ ≥ 0 (Appendix A).
pub fn ray_capsule(origin: &Vector3<f32>, dir: &Vector3<f32>, c: &Capsule) -> Option<f32> {
    let axis = c.b - c.a;
    let length = axis.norm();
    let mut best: Option<f32> = None;
    let mut keep = |hit: Option<f32>| {
        if let Some(h) = hit {
            best = Some(best.map_or(h, |b: f32| b.min(h)));
        }
    };
    if length > 0.0 {
        let u = axis / length;
        let w = origin - c.a;
        let v_perp = dir - u * dir.dot(&u);
        let w_perp = w - u * w.dot(&u);
        let q2 = v_perp.norm_squared();
        // A ray parallel to the axis never meets the side (only the spheres).
        if q2 > 0.0 {
            // |v⊥ × w⊥|², as (dir · (w⊥ × u))²: both lie across the axis, so their cross
            // product runs along it (the GPU keeps w⊥ × u per capsule: one dot product a ray).
            let n = dir.dot(&w_perp.cross(&u));
            let disc = q2 * c.radius * c.radius - n * n;
            let hit = first_nonnegative_root(q2, v_perp.dot(&w_perp), disc);
            if let Some(delta) = hit {
                let along = (w + dir * delta).dot(&u);
                if (0.0..=length).contains(&along) {
                    keep(Some(delta));
                }
            }
        }
    }
    keep(ray_sphere(origin, dir, &c.a, c.radius));
    keep(ray_sphere(origin, dir, &c.b, c.radius));
    best
}

/// The truncated metric of eq. 6: `|Δ_hit − Δ|` when the ray hits and that is at most τ, else τ.
pub fn truncated_distance(hit: Option<f32>, depth: f32, tau: f32) -> f32 {
    match hit {
        Some(h) => (h - depth).abs().min(tau),
        None => tau,
    }
}
