//! The GPU capsule likelihood (paper layout and fast kernel) against Listing 1.2 on the CPU:
//! random skeleton poses and point sets, with points behind the camera, rays tangent to
//! capsules and zero-length bones.
//!
//! Tolerance: `common::capsule_cases` (the tolerance policy in ARCHITECTURE.md).

mod common;

use body_tracker::likelihood::gpu::{CapsuleKernel, CapsuleLikelihoodGpu};
use body_tracker::likelihood::{CoarseLayers, Rays, capsules_gpu_layout, listing_1_2};
use body_tracker::skeleton::gpu::prepare_body_rays;
use common::capsule_cases::{TAU, points, samples, sum_tolerance};
use nalgebra::Vector3;
use proptest::prelude::*;
use proptest::test_runner::TestRunner;

fn check(kernel: CapsuleKernel, cases: u32) {
    let Some(ctx) = common::gpu_context("capsule likelihood") else {
        return;
    };
    let mut runner = TestRunner::new(common::property::config(cases));
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
        .unwrap_or_else(common::property::report);
}

#[test]
fn paper_layout_matches_cpu_within_tolerance() {
    check(CapsuleKernel::PaperLayout, 12);
}

#[test]
fn fast_kernel_matches_cpu_within_tolerance() {
    check(CapsuleKernel::Fast, 12);
}

/// The fast kernel over rays in levels (every point, then a coarse subset, as the body
/// tracker's coarse annealing layers weigh them): each level's sums against Listing 1.2 over
/// that level's points alone, the subset any size from one point to all of them, with spare
/// room in both levels' buffers.
#[test]
fn fast_kernel_levels_each_match_cpu_over_their_own_points() {
    let Some(ctx) = common::gpu_context("capsule likelihood levels") else {
        return;
    };
    let mut runner = TestRunner::new(common::property::config(10));
    let strategy = (
        any::<u64>(),
        1usize..24,
        prop_oneof![Just(1usize), Just(1024), Just(1025), 2usize..2500],
        1usize..3000,
        prop_oneof![Just(0usize), 1usize..1100],
        prop_oneof![Just(19usize), Just(48)],
    );
    runner
        .run(&strategy, |(seed, j, i, coarse_points, spare, k)| {
            let coarse = CoarseLayers {
                points: coarse_points,
                layers: 1,
            };
            let caps = samples(seed, j, k, false);
            let pts = points(&caps[0], seed, i);
            let rays = Rays::through(Vector3::zeros(), &pts).unwrap();
            let subset = Rays {
                origin: rays.origin,
                directions: coarse.subset(&rays.directions),
                depths: coarse.subset(&rays.depths),
            };
            let capacity = i + spare;
            let levels = [capacity, coarse.capacity(capacity)];
            let gpu = CapsuleLikelihoodGpu::with_levels(
                &ctx,
                CapsuleKernel::Fast,
                j,
                &levels,
                k,
                [0.0; 3],
                TAU,
            )
            .unwrap();
            let prepared = prepare_body_rays(&rays.gpu_layout(), capacity, Some(&coarse)).unwrap();
            prop_assert_eq!(prepared.levels()[1].points, subset.len());
            gpu.upload_prepared_rays(&ctx, &prepared).unwrap();
            let mut flat = Vec::with_capacity(j * k * 2);
            for c in &caps {
                capsules_gpu_layout(c, &mut flat);
            }
            gpu.upload_capsules(&ctx, &flat).unwrap();
            for (level, rays) in [(0, &rays), (1, &subset)] {
                let want = listing_1_2(&caps, rays, TAU);
                let got = gpu.evaluate_level(&ctx, level).unwrap();
                for s in 0..j {
                    let (tol, _) = sum_tolerance(&caps[s], rays, want[s]);
                    prop_assert!(
                        (f64::from(got[s]) - want[s]).abs() <= tol,
                        "level {level} sample {s}: GPU {} vs CPU {} (tolerance {tol})",
                        got[s],
                        want[s]
                    );
                }
            }
            // Rays prepared for other levels are refused, not weighed.
            let one_level = prepare_body_rays(&rays.gpu_layout(), capacity, None).unwrap();
            prop_assert!(gpu.upload_prepared_rays(&ctx, &one_level).is_err());
            prop_assert!(gpu.evaluate_level(&ctx, 2).is_err());
            Ok(())
        })
        .unwrap_or_else(common::property::report);
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

/// Bones pointing nearly at the camera, so that the camera lies inside some capsules' infinite
/// cylinders (the fast kernel's general branch) and outside others' (its two-root branch), with
/// points on, in front of and behind them: the fast kernel against Listing 1.2.
#[test]
fn fast_kernel_matches_cpu_for_bones_along_the_line_of_sight() {
    let Some(ctx) = common::gpu_context("capsules along the line of sight") else {
        return;
    };
    let mut runner = TestRunner::new(common::property::config(24));
    // Per capsule: its near end's offset from the axis of sight, the far end's, depth, length
    // and radius; the camera is inside the infinite cylinder when the bone's line passes
    // within the radius of the origin.
    let capsule = (
        (-0.1f32..0.1, -0.1f32..0.1),
        (-0.04f32..0.04, -0.04f32..0.04),
        1.0f32..4.0,
        prop_oneof![Just(0.0f32), 0.05f32..0.6],
        0.02f32..0.25,
    );
    let strategy = (
        proptest::collection::vec(capsule, 1..8),
        proptest::collection::vec((-0.2f32..0.2, -0.2f32..0.2, -0.3f32..0.3), 1..300),
    );
    runner
        .run(&strategy, |case| line_of_sight_sums_agree(&ctx, case))
        .unwrap_or_else(common::property::report);
}

/// A zero-length bone (a sphere) seen by rays near its silhouette: the fast kernel once took its
/// degenerate axis for a cylinder's and hit it wherever a ray passed (a case the long run drew,
/// reduced to its capsule and its first three points).
#[test]
fn fast_kernel_matches_cpu_for_a_zero_length_bone() {
    let Some(ctx) = common::gpu_context("a zero-length bone") else {
        return;
    };
    line_of_sight_sums_agree(
        &ctx,
        (
            vec![((0.0, -0.07082491), (0.0, 0.0), 1.0, 0.0, 0.052282095)],
            vec![
                (0.051772438, 1.7561881e-6, 0.05403482),
                (-0.11165298, -0.17859092, -0.11616045),
                (0.12569602, -0.026407292, 0.13774376),
            ],
        ),
    )
    .unwrap();
}

/// One capsule per spec (near end's offset from the axis of sight, the far end's, depth, length,
/// radius) and points offset from their near ends: the fast kernel's sum against Listing 1.2.
#[allow(clippy::type_complexity)]
fn line_of_sight_sums_agree(
    ctx: &pf_gpu::GpuContext,
    (specs, offsets): (
        Vec<((f32, f32), (f32, f32), f32, f32, f32)>,
        Vec<(f32, f32, f32)>,
    ),
) -> Result<(), proptest::test_runner::TestCaseError> {
    use body_tracker::capsule::Capsule;
    let caps: Vec<Capsule> = specs
        .iter()
        .map(|&((ax, ay), (bx, by), depth, length, radius)| {
            let a = Vector3::new(ax, ay, depth);
            // Along the line from the camera through a, bent by (bx, by).
            let b = a + (a.normalize() + Vector3::new(bx, by, 0.0)).normalize() * length;
            Capsule { a, b, radius }
        })
        .collect();
    // Points near each capsule's near end, in front of it and behind it.
    let pts: Vec<Vector3<f32>> = offsets
        .iter()
        .enumerate()
        .map(|(n, &(x, y, dz))| caps[n % caps.len()].a + Vector3::new(x, y, dz))
        .filter(|p| p.z > 0.1)
        .collect();
    prop_assume!(!pts.is_empty());
    let rays = Rays::through(Vector3::zeros(), &pts).unwrap();
    let want = listing_1_2(std::slice::from_ref(&caps), &rays, TAU)[0];
    let gpu = CapsuleLikelihoodGpu::new(
        ctx,
        CapsuleKernel::Fast,
        1,
        pts.len(),
        caps.len(),
        [0.0; 3],
        TAU,
    )
    .unwrap();
    gpu.upload_rays(ctx, &rays.gpu_layout()).unwrap();
    let mut flat = Vec::new();
    capsules_gpu_layout(&caps, &mut flat);
    gpu.upload_capsules(ctx, &flat).unwrap();
    let got = f64::from(gpu.evaluate(ctx).unwrap()[0]);
    let (tol, grazing) = sum_tolerance(&caps, &rays, want);
    prop_assert!(
        (got - want).abs() <= tol,
        "GPU {got} vs CPU {want} ({grazing} grazing rays, tolerance {tol})"
    );
    Ok(())
}
