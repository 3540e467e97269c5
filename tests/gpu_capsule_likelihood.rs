//! The GPU capsule likelihood (paper layout and fast kernel) against Listing 1.2 on the CPU:
//! random skeleton poses and point sets, with points behind the camera, rays tangent to
//! capsules and zero-length bones.
//!
//! Tolerance (DESIGN.md): the sums agree to 1e-4 relative, plus what an f32 error of 3e-5 of each
//! point's depth in its distance adds to its square (f32 geometry and partial sums against the
//! f64-accumulated reference), except that a point whose ray grazes
//! a capsule — some capsule's hit/miss answer changes, or its hit moves by more than 1 mm, when
//! every radius moves by ±1e-3 relative, i.e. the quadratic's discriminant is within about
//! 2·q2·r²·1e-3 of zero (ten times f32's rounding of q1² at a few metres) — may differ by up to
//! τ² (a flip, or a tangent hit whose depth the rounding decides).

mod common;

use body_tracker::capsule::Capsule;
use body_tracker::human::human_skeleton;
use body_tracker::likelihood::{Rays, capsules_gpu_layout, listing_1_2, point_min_distance};
use nalgebra::{Vector3, vector};
use pf_gpu::capsules::{CapsuleKernel, CapsuleLikelihoodGpu};
use proptest::prelude::*;
use proptest::test_runner::{Config, TestRunner};

const TAU: f32 = 0.1;

/// Samples of capsules: random poses of the default human, plus extra capsules of zero length.
fn samples(seed: u64, count: usize, capsules: usize, zero_length: bool) -> Vec<Vec<Capsule>> {
    let skeleton = human_skeleton(capsules).unwrap();
    let (lo, hi) = skeleton.limits();
    let mut rng = pf_core::RandomStreams::new(seed).stream(0, pf_core::Stage::Model(0));
    (0..count)
        .map(|_| {
            let theta: Vec<f32> = (0..skeleton.dofs())
                .map(|i| match i {
                    0 | 1 => 0.2 * rng.gaussian_f32(),
                    2 => 3.0 + 0.2 * rng.gaussian_f32(),
                    3..=5 => 0.3 * rng.gaussian_f32(),
                    _ => lo[i] + (hi[i] - lo[i]) * rng.uniform() as f32,
                })
                .collect();
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
fn points(caps: &[Capsule], seed: u64, count: usize) -> Vec<Vector3<f32>> {
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

fn scaled(caps: &[Capsule], factor: f32) -> Vec<Capsule> {
    caps.iter()
        .map(|c| Capsule {
            radius: c.radius * factor,
            ..*c
        })
        .collect()
}

fn check(kernel: CapsuleKernel, cases: u32) {
    let Some(ctx) = common::gpu_context("capsule likelihood") else {
        return;
    };
    let mut runner = TestRunner::new(Config {
        cases,
        failure_persistence: None,
        ..Config::default()
    });
    let strategy = (
        any::<u64>(),
        1usize..40,
        prop_oneof![Just(1usize), Just(255), Just(256), Just(257), 2usize..1500],
        prop_oneof![Just(19usize), Just(48), 19usize..70],
        any::<bool>(),
    );
    runner
        .run(&strategy, |(seed, j, i, k, zero_length)| {
            let caps = samples(seed, j, k, zero_length);
            let pts = points(&caps[0], seed, i);
            let rays = Rays::through(Vector3::zeros(), &pts).unwrap();
            let want = listing_1_2(&caps, &rays, TAU);
            let gpu = CapsuleLikelihoodGpu::new(&ctx, kernel, j, i, k, [0.0; 3], TAU).unwrap();
            gpu.upload_rays(&ctx, &rays.gpu_layout()).unwrap();
            let mut flat = Vec::with_capacity(j * k * 2);
            for c in &caps {
                capsules_gpu_layout(c, &mut flat);
            }
            gpu.upload_capsules(&ctx, &flat).unwrap();
            let got = gpu.evaluate(&ctx).unwrap();
            for s in 0..j {
                let (smaller, larger) =
                    (scaled(&caps[s], 1.0 - 1e-3), scaled(&caps[s], 1.0 + 1e-3));
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
                        let di =
                            f64::from(point_min_distance(&caps[s], &rays.origin, d, depth, TAU));
                        let delta = 3e-5 * f64::from(depth);
                        2.0 * di * delta + delta * delta
                    })
                    .sum();
                let tol = 1e-4 * want[s] + rounding + grazing as f64 * f64::from(TAU * TAU);
                prop_assert!(
                    (f64::from(got[s]) - want[s]).abs() <= tol,
                    "sample {}: GPU {} vs CPU {} ({} grazing rays, tolerance {})",
                    s,
                    got[s],
                    want[s],
                    grazing,
                    tol
                );
            }
            Ok(())
        })
        .unwrap();
}

#[test]
fn paper_layout_matches_cpu_within_tolerance() {
    check(CapsuleKernel::PaperLayout, 12);
}

#[test]
fn fast_kernel_matches_cpu_within_tolerance() {
    check(CapsuleKernel::Fast, 12);
}

#[test]
fn invalid_shapes_are_typed_errors() {
    let Some(ctx) = common::gpu_context("capsule shapes") else {
        return;
    };
    assert!(
        CapsuleLikelihoodGpu::new(&ctx, CapsuleKernel::Fast, 0, 10, 10, [0.0; 3], TAU).is_err()
    );
    assert!(
        CapsuleLikelihoodGpu::new(&ctx, CapsuleKernel::Fast, 1, 10, 129, [0.0; 3], TAU).is_err()
    );
    assert!(
        CapsuleLikelihoodGpu::new(&ctx, CapsuleKernel::Fast, 1, 10, 10, [0.0; 3], -1.0).is_err()
    );
    let gpu = CapsuleLikelihoodGpu::new(&ctx, CapsuleKernel::PaperLayout, 2, 10, 3, [0.0; 3], TAU)
        .unwrap();
    assert!(gpu.upload_capsules(&ctx, &[[0.0; 4]; 11]).is_err());
}
