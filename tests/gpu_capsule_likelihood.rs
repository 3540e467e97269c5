//! The GPU capsule likelihood (paper layout and fast kernel) against Listing 1.2 on the CPU:
//! random skeleton poses and point sets, with points behind the camera, rays tangent to
//! capsules and zero-length bones.
//!
//! Tolerance: `common::capsule_cases` (DESIGN.md).

mod common;

use body_tracker::likelihood::{Rays, capsules_gpu_layout, listing_1_2};
use common::capsule_cases::{TAU, points, samples, sum_tolerance};
use nalgebra::Vector3;
use pf_gpu::capsules::{CapsuleKernel, CapsuleLikelihoodGpu};
use proptest::prelude::*;
use proptest::test_runner::{Config, TestRunner};

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
                let (tol, grazing) = sum_tolerance(&caps[s], &rays, want[s]);
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
