//! Random capsule-likelihood cases shared by the GPU tests: poses of the default human, point
//! sets with the hard cases, and the tolerance policy (ARCHITECTURE.md, "How close a kernel and its twin must be") for a sample's sum M_j.
//!
//! Tolerance: the sums agree to 1e-4 relative, plus what an f32 error of 3e-5 of each point's
//! depth in its distance adds to its square (f32 geometry and partial sums against the
//! f64-accumulated reference), except that a point whose ray grazes a capsule — some capsule's
//! hit/miss answer changes, or its hit moves by more than 1 mm, when every radius moves by ±1e-3
//! relative, i.e. the quadratic's discriminant is within about 2·q2·r²·1e-3 of zero (ten times
//! f32's rounding of q1² at a few metres) — may differ by up to τ² (a flip, or a tangent hit whose
//! depth the rounding decides).

use body_tracker::capsule::Capsule;
use body_tracker::human::human_skeleton;
use body_tracker::likelihood::{Rays, point_min_distance};
use nalgebra::{Vector3, vector};

pub const TAU: f32 = 0.1;

/// Samples of capsules: random poses of the default human, plus extra capsules of zero length.
pub fn samples(seed: u64, count: usize, capsules: usize, zero_length: bool) -> Vec<Vec<Capsule>> {
    let skeleton = human_skeleton(capsules).unwrap();
    let mut rng = pf_core::RandomStreams::new(seed).stream(0, pf_core::Stage::Model(0));
    (0..count)
        .map(|_| {
            let theta = random_pose(&skeleton, &mut rng);
            let mut caps = skeleton.capsules(&theta).unwrap();
            if zero_length {
                let last = caps.len() - 1;
                caps[last].b = caps[last].a;
            }
            caps
        })
        .collect()
}

/// Points: on the first sample's surface (ray-cast, with depth noise), random points in the
/// scene, points behind the camera, and points whose rays graze a capsule.
pub fn points(caps: &[Capsule], seed: u64, count: usize) -> Vec<Vector3<f32>> {
    let mut rng = pf_core::RandomStreams::new(seed).stream(1, pf_core::Stage::Model(1));
    let origin = Vector3::zeros();
    let mut out = Vec::with_capacity(count);
    while out.len() < count {
        let kind = out.len() % 8;
        let p = match kind {
            0..=3 => {
                let dir =
                    vector![0.4 * rng.gaussian_f32(), 0.5 * rng.gaussian_f32(), 1.0].normalize();
                let hit = caps
                    .iter()
                    .filter_map(|c| body_tracker::ray_capsule(&origin, &dir, c))
                    .fold(f32::INFINITY, f32::min);
                if !hit.is_finite() {
                    continue;
                }
                dir * (hit + 0.05 * rng.gaussian_f32())
            }
            4 | 5 => vector![
                rng.gaussian_f32(),
                rng.gaussian_f32(),
                3.0 + rng.gaussian_f32()
            ],
            6 => vector![
                rng.gaussian_f32(),
                rng.gaussian_f32(),
                -1.0 - rng.uniform() as f32
            ],
            _ => {
                // Tangent to a capsule's side: a point at distance r from the axis, seen along a
                // direction perpendicular to both the axis and the offset.
                let c = caps[(rng.uniform() * caps.len() as f64) as usize % caps.len()];
                let axis = (c.b - c.a).try_normalize(1e-6).unwrap_or(Vector3::y());
                let side = axis.cross(&c.a).try_normalize(1e-6).unwrap_or(Vector3::x());
                c.a + axis * 0.5 * (c.b - c.a).norm() + side * c.radius
            }
        };
        if p.norm() > 1e-3 {
            out.push(p);
        }
    }
    out
}

pub fn scaled(caps: &[Capsule], factor: f32) -> Vec<Capsule> {
    caps.iter()
        .map(|c| Capsule {
            radius: c.radius * factor,
            ..*c
        })
        .collect()
}

/// A random pose about 3 m in front of the camera, joint angles uniform within their limits.
pub fn random_pose(skeleton: &body_tracker::Skeleton, rng: &mut pf_core::RandomStream) -> Vec<f32> {
    let (lo, hi) = skeleton.limits();
    (0..skeleton.dofs())
        .map(|i| match i {
            0 | 1 => 0.2 * rng.gaussian_f32(),
            2 => 3.0 + 0.2 * rng.gaussian_f32(),
            3..=5 => 0.3 * rng.gaussian_f32(),
            _ => lo[i] + (hi[i] - lo[i]) * rng.uniform() as f32,
        })
        .collect()
}

/// How far a GPU sum may be from the CPU's `want` for one sample's capsules (see the module doc).
pub fn sum_tolerance(caps: &[Capsule], rays: &Rays, want: f64) -> (f64, usize) {
    let (smaller, larger) = (scaled(caps, 1.0 - 1e-3), scaled(caps, 1.0 + 1e-3));
    // A ray grazes when some capsule's answer is ill-conditioned: hit/miss changes with
    // the radius, or the hit moves by more than 1 mm (a near-zero discriminant, whose
    // square root amplifies rounding).
    let grazing = rays
        .directions
        .iter()
        .filter(|d| {
            smaller.iter().zip(&larger).any(|(a, b)| {
                match (
                    body_tracker::ray_capsule(&rays.origin, d, a),
                    body_tracker::ray_capsule(&rays.origin, d, b),
                ) {
                    (Some(x), Some(y)) => (x - y).abs() > 1e-3,
                    (None, None) => false,
                    _ => true,
                }
            })
        })
        .count();
    // Each point's distance may carry 3e-5 of its depth in f32 rounding (the
    // quadratics' discriminants are differences of terms ~depth², so rays near a
    // capsule's silhouette lose a few hundred ulps of the hit distance; measured up
    // to 1.2e-5): its square changes by 2·d·δ + δ².
    let rounding: f64 = rays
        .directions
        .iter()
        .zip(&rays.depths)
        .map(|(d, &depth)| {
            let di = f64::from(point_min_distance(caps, &rays.origin, d, depth, TAU));
            let delta = 3e-5 * f64::from(depth);
            2.0 * di * delta + delta * delta
        })
        .sum();
    // The tolerance policy, plus the rounding above (near zero, a sum of a few points close to
    // the capsules, where that rounding can be exceeded by a ray near a silhouette).
    let tol = pf_gpu::model::tolerance(want) + rounding + grazing as f64 * f64::from(TAU * TAU);
    (tol, grazing)
}
