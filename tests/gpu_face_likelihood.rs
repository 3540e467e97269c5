//! The GPU face likelihood (per-face, batched and packed dispatch) against the CPU reference: random
//! frames, templates and particles, with faces partly out of the frame and turned up to ±90°, seen
//! through weak perspective or a pinhole (from a long lens to one that puts points at or behind
//! the camera).
//!
//! Tolerance (the tolerance policy in ARCHITECTURE.md): ε agrees to 1e-4 relative plus 1e-5, plus what each point's ρ can move
//! when its projection moves by 1e-3 px (f32 rounding of the projection is ~1e-4 px at these
//! sizes; bilinear sampling is continuous, so this bounds the change in I) and its sample moves by
//! the texture unit's rounding (below), all over the number of visible points.
//!
//! The texture unit's bound: the GPU samples through the hardware filter, whose weights carry 8
//! fractional bits (`pf_gpu::image`); the CPU twin rounds its weights to the nearest 1/256, and a
//! unit may truncate instead, so each weight may differ from the exact one by up to 1/256 on the
//! GPU and 1/512 on the CPU. A bilinear value moves by at most the cell's range (largest minus
//! smallest of its four levels) times the weight's change, per axis: both samples lie within
//! 2·range/256 of the exact bilinear value. One more level is allowed for a unit that returns the
//! filtered value at 8-bit precision (Mesa's lavapipe filters 8-bit textures in 8-bit arithmetic).
//! A coordinate off by half a pixel, or a filter other than bilinear, moves a sample by up to half
//! the range and fails. Two flips are allowed and counted: a point within 1e-3 px of the frame's edge
//! (inside or outside decides between its ρ and 1), and a point whose rotated normal has
//! |n_z| < 1e-5 (visible or occluded: it moves ε by at most 1/(N−1), or to 1 when it carries the
//! visible count across the minimum share). Through a pinhole, a point nearer the camera than a
//! quarter of the face's distance counts as a flip too (magnified so much that rounding moves it
//! further than the shift, or not imaged).

mod common;

use face_tracker::likelihood::gpu::{FaceDispatch, FaceLikelihoodGpu};
use face_tracker::likelihood::{
    Lens, MIN_ERROR, MIN_VISIBLE_SHARE, log_weight, residual_error, residual_error_through, rho,
};
use face_tracker::projection::{DIMS, Pose};
use face_tracker::{FeaturePoint, GrayImage, Template};
use nalgebra::Vector3;
use pf_core::batch::{BatchConfig, BatchShape};
use pf_gpu::{GpuError, GpuFilter, GpuLikelihood, GpuResampler, GpuStage};
use proptest::prelude::*;
use proptest::test_runner::TestRunner;

const SHARPNESS: f32 = 1.0;
const SHIFT: f32 = 1e-3;
/// Through a pinhole, a point whose distance from the camera is under this share of the face's
/// (magnified more than four times, or not imaged at all below `Lens::MIN_DISTANCE_SHARE`) is
/// counted as a flip: rounding moves it by more than `SHIFT`.
const NEAR_CAMERA: f32 = 0.25;

fn frame(rng: &mut pf_core::RandomStream, width: u32, height: u32) -> GrayImage {
    // Smooth structure plus pixel noise: gradients of every size.
    let (fx, fy) = (
        0.05 + 0.3 * rng.uniform() as f32,
        0.05 + 0.3 * rng.uniform() as f32,
    );
    let data: Vec<f32> = (0..width * height)
        .map(|i| {
            let (x, y) = ((i % width) as f32, (i / width) as f32);
            128.0 + 80.0 * (fx * x).sin() * (fy * y).cos() + 40.0 * rng.gaussian_f32()
        })
        .collect();
    GrayImage::from_levels(width, height, &data).unwrap()
}

fn template(rng: &mut pf_core::RandomStream, n: usize) -> Template {
    let points = (0..n)
        .map(|_| {
            let normal = Vector3::new(rng.gaussian_f32(), rng.gaussian_f32(), rng.gaussian_f32());
            let normal = normal.try_normalize(1e-6).unwrap_or(Vector3::z());
            FeaturePoint::new(
                [
                    60.0 * (rng.uniform() as f32 - 0.5),
                    80.0 * (rng.uniform() as f32 - 0.5),
                    30.0 * rng.uniform() as f32,
                ],
                normal.into(),
                1.0 + 254.0 * rng.uniform() as f32,
            )
        })
        .collect();
    Template::new(points).unwrap()
}

fn state(rng: &mut pf_core::RandomStream, width: u32, height: u32) -> [f32; DIMS] {
    let turn =
        |rng: &mut pf_core::RandomStream| (rng.uniform() as f32 - 0.5) * std::f32::consts::PI;
    [
        (1.4 * rng.uniform() as f32 - 0.2) * width as f32,
        (1.4 * rng.uniform() as f32 - 0.2) * height as f32,
        0.3 + 2.7 * rng.uniform() as f32,
        turn(rng),
        turn(rng),
        turn(rng),
        0.5 + 1.5 * rng.uniform() as f32,
    ]
}

/// The texture unit's bound on a sample at (x, y) against the exact bilinear value, in levels
/// (see the module doc).
fn texture_unit_bound(image: &GrayImage, x: f32, y: f32) -> f32 {
    let x0 = (x as u32).min(image.width - 2);
    let y0 = (y as u32).min(image.height - 2);
    let cell = [(0, 0), (1, 0), (0, 1), (1, 1)].map(|(dx, dy)| image.at(x0 + dx, y0 + dy));
    let range = cell.iter().cloned().fold(f32::NEG_INFINITY, f32::max)
        - cell.iter().cloned().fold(f32::INFINITY, f32::min);
    2.0 * range / 256.0 + 1.0
}

/// The allowed |ε_GPU − ε_CPU| for one particle (see the module doc).
fn tolerance(
    s: &[f32; DIMS],
    template: &Template,
    image: &GrayImage,
    lens: &Lens,
    want: f64,
) -> f64 {
    let pose = Pose::new(s);
    let mut spread = 0.0f64;
    let mut visible = 0usize;
    let mut flips = 0usize;
    for q in &template.points {
        let n = pose.rotation * Vector3::from(q.normal);
        if n.z.abs() < 1e-5 {
            flips += 1;
        }
        if n.z < 0.0 {
            continue;
        }
        visible += 1;
        let position = pose.rotation * Vector3::from(q.position);
        let distance = 1.0 - pose.scale * position.z * lens.inverse_focal;
        if distance < NEAR_CAMERA {
            // Magnified many times or not imaged: a flip.
            flips += 1;
            continue;
        }
        let Some(p) = pose.project_through(&Vector3::from(q.position), lens) else {
            continue;
        };
        let shifted = [
            (0.0, 0.0),
            (SHIFT, 0.0),
            (-SHIFT, 0.0),
            (0.0, SHIFT),
            (0.0, -SHIFT),
        ]
        .map(|(dx, dy)| {
            let (x, y) = (p.x + dx, p.y + dy);
            image
                .bilinear(x, y)
                .map(|v| (v, texture_unit_bound(image, x, y)))
        });
        if shifted.iter().any(|v| v.is_none()) {
            if shifted.iter().any(|v| v.is_some()) {
                flips += 1;
            }
            continue;
        }
        // Each sample widened by the texture unit's bound, both ways (α > 0).
        let kappas = shifted.map(|v| {
            let (level, bound) = v.unwrap_or((0.0, 0.0));
            [level - bound, level + bound].map(|l| (pose.alpha * l - q.gray) / q.gray)
        });
        let kappas = kappas.as_flattened();
        let lo = kappas.iter().cloned().fold(f32::INFINITY, f32::min);
        let hi = kappas.iter().cloned().fold(f32::NEG_INFINITY, f32::max);
        let rhos = [
            rho(lo),
            rho(hi),
            if lo <= 0.0 && hi >= 0.0 { 0.0 } else { rho(lo) },
        ];
        let range = rhos.iter().cloned().fold(f32::NEG_INFINITY, f32::max)
            - rhos.iter().cloned().fold(f32::INFINITY, f32::min);
        spread += f64::from(range) + 1e-6;
    }
    // An occlusion flip may also carry the visible count across the minimum share (ε jumps to 1).
    let threshold = MIN_VISIBLE_SHARE * template.len() as f32;
    if flips > 0
        && ((visible.saturating_sub(flips)) as f32) < threshold
        && ((visible + flips) as f32) >= threshold
    {
        return 1.0;
    }
    let denominator = visible.saturating_sub(flips).max(1) as f64;
    pf_gpu::model::tolerance(want) + spread / denominator + flips as f64 / denominator
}

fn check(dispatch: FaceDispatch, cases: u32) {
    let Some(ctx) = common::gpu_context("face likelihood") else {
        return;
    };
    let mut runner = TestRunner::new(common::property::config(cases));
    let strategy = (
        any::<u64>(),
        1usize..4,
        prop_oneof![Just(1usize), Just(64), 2usize..300],
        prop_oneof![Just(1usize), Just(255), Just(256), Just(257), 2usize..400],
        (2u32..300, 2u32..200),
        // Weak perspective, or a pinhole from a long lens to one nearer than the faces' depth.
        prop_oneof![Just(None), (20f32..3000.0).prop_map(Some)],
    );
    runner
        .run(&strategy, |(seed, faces, particles, points, (width, height), focal)| {
            let lens = focal.map_or(Lens::WEAK, |f| Lens::pinhole(f, width, height).unwrap());
            let mut rng = pf_core::RandomStreams::new(seed).stream(0, pf_core::Stage::Model(3));
            let image = frame(&mut rng, width, height);
            let templates: Vec<Template> = (0..faces)
                .map(|f| template(&mut rng, if f == 0 { points } else { 1 + points / (f + 1) }))
                .collect();
            let states: Vec<[f32; DIMS]> =
                (0..faces * particles).map(|_| state(&mut rng, width, height)).collect();
            let shape = BatchShape::new(faces, particles, DIMS).unwrap();
            let mut layout = vec![0.0f32; shape.state_len()];
            for t in 0..faces {
                for m in 0..particles {
                    for d in 0..DIMS {
                        layout[shape.state_index(t, d, m)] = states[t * particles + m][d];
                    }
                }
            }
            let config = BatchConfig {
                shape,
                seed,
                sigma: vec![0.0; DIMS],
                bounds: None,
                angular: vec![false, false, false, true, true, true, false],
                ess_threshold: f64::INFINITY,
                best: 0,
                annealing: Default::default(),
                motion: Default::default(),
            };
            let mut filter = GpuFilter::new(&ctx, &config, GpuResampler::Systematic, &layout).unwrap();
            let max_points = templates.iter().map(Template::len).max().unwrap();
            let mut gpu = FaceLikelihoodGpu::new(
                &ctx,
                dispatch,
                faces,
                max_points,
                width,
                height,
                SHARPNESS,
                MIN_ERROR,
                MIN_VISIBLE_SHARE,
                lens,
            )
            .unwrap();
            gpu.upload_frame(&ctx, &image.data).unwrap();
            for (f, t) in templates.iter().enumerate() {
                gpu.upload_template(&ctx, f, &t.gpu_layout()).unwrap();
            }
            gpu.prepare(&ctx, &filter.likelihood_inputs()).unwrap();
            filter.run_stages(&ctx, &[GpuStage::Likelihood], &gpu).unwrap();
            let errors = gpu.download_errors(&ctx).unwrap();
            let log_likelihood = filter.streams().log_likelihood.download(&ctx).unwrap();
            for t in 0..faces {
                for m in 0..particles {
                    let s = &states[t * particles + m];
                    let want = residual_error_through(s, &templates[t], &image, &lens);
                    let got = f64::from(errors[t * particles + m]);
                    let tol = tolerance(s, &templates[t], &image, &lens, want);
                    prop_assert!(
                        (got - want).abs() <= tol,
                        "face {t} particle {m}: GPU ε {got} vs CPU {want} (tolerance {tol}), state {s:?}"
                    );
                    let lw = log_weight(got, SHARPNESS);
                    prop_assert!((log_likelihood[t * particles + m] - lw).abs() <= 1e-4 * (1.0 + lw.abs()));
                }
            }
            Ok(())
        })
        .unwrap_or_else(common::property::report);
}

#[test]
fn per_face_dispatch_matches_cpu_within_tolerance() {
    check(FaceDispatch::PerFace, 10);
}

#[test]
fn batched_dispatch_matches_cpu_within_tolerance() {
    check(FaceDispatch::Batched, 10);
}

#[test]
fn packed_dispatch_matches_cpu_within_tolerance() {
    check(FaceDispatch::PackedByLoad, 10);
}

/// Every lane count a particle: one lane looping over every point, more lanes than points, a
/// whole workgroup a particle.
#[test]
fn packed_dispatch_with_any_lanes_matches_cpu_within_tolerance() {
    // 16 and 4 are what the tracker takes for 16 and 64 faces (`packed_lanes_for`); up to
    // `STAGED_MAX_LANES` (16) the kernel stages the template in workgroup memory, above it not.
    for lanes in [1, 4, 8, 16, 32, 256] {
        check(FaceDispatch::Packed { lanes }, 3);
    }
}

#[test]
fn packed_dispatch_refuses_lanes_that_do_not_divide_a_workgroup() {
    let Some(ctx) = common::gpu_context("packed lanes refused") else {
        return;
    };
    for lanes in [0, 3, 48, 512] {
        let built = FaceLikelihoodGpu::new(
            &ctx,
            FaceDispatch::Packed { lanes },
            1,
            10,
            64,
            48,
            SHARPNESS,
            MIN_ERROR,
            MIN_VISIBLE_SHARE,
            Lens::WEAK,
        );
        match built {
            Err(GpuError::InvalidConfig(message)) => {
                assert!(message.contains("lanes"), "{message}")
            }
            Err(other) => panic!("{lanes} lanes: {other}"),
            Ok(_) => panic!("{lanes} lanes were accepted"),
        }
    }
}

/// The check of each face's estimate after a whole step (the tracker's failure test) against
/// `residual_error` at the estimate the step read back: the best-M′ mean, or the weighted mean
/// when the filter computes no best-M′ mean.
#[test]
fn estimate_check_matches_cpu_within_tolerance() {
    let Some(ctx) = common::gpu_context("face estimate check") else {
        return;
    };
    let mut runner = TestRunner::new(common::property::config(8));
    let strategy = (
        any::<u64>(),
        1usize..5,
        prop_oneof![Just(1usize), 2usize..200],
        prop_oneof![Just(1usize), Just(257), 2usize..300],
        (2u32..200, 2u32..150),
        prop_oneof![Just(0usize), 1usize..20],
    );
    runner
        .run(&strategy, |(seed, faces, particles, points, (width, height), best)| {
            let best = best.min(particles);
            let mut rng = pf_core::RandomStreams::new(seed).stream(0, pf_core::Stage::Model(4));
            let image = frame(&mut rng, width, height);
            let templates: Vec<Template> = (0..faces).map(|_| template(&mut rng, points)).collect();
            let shape = BatchShape::new(faces, particles, DIMS).unwrap();
            let mut layout = vec![0.0f32; shape.state_len()];
            for t in 0..faces {
                // A cloud around one random pose per face, so that the estimate is a pose too.
                let centre = state(&mut rng, width, height);
                for m in 0..particles {
                    for d in 0..DIMS {
                        layout[shape.state_index(t, d, m)] =
                            centre[d] + 0.02 * rng.gaussian_f32() * (1.0 + centre[d].abs());
                    }
                }
            }
            let config = BatchConfig {
                shape,
                seed,
                sigma: vec![0.0; DIMS],
                bounds: None,
                angular: vec![false, false, false, true, true, true, false],
                ess_threshold: f64::INFINITY,
                best,
                annealing: Default::default(),
                motion: Default::default(),
            };
            let mut filter =
                GpuFilter::new(&ctx, &config, GpuResampler::Systematic, &layout).unwrap();
            let mut gpu = FaceLikelihoodGpu::new(
                &ctx,
                FaceDispatch::PackedByLoad,
                faces,
                points,
                width,
                height,
                SHARPNESS,
                MIN_ERROR,
                MIN_VISIBLE_SHARE,
                Lens::WEAK,
            )
            .unwrap();
            prop_assert!(gpu.readbacks().is_empty(), "no readback before prepare");
            gpu.upload_frame(&ctx, &image.data).unwrap();
            for (f, t) in templates.iter().enumerate() {
                gpu.upload_template(&ctx, f, &t.gpu_layout()).unwrap();
            }
            gpu.prepare(&ctx, &filter.likelihood_inputs()).unwrap();
            for step in 0..2 {
                let report = filter.step(&ctx, &gpu).unwrap();
                let estimates = if best > 0 { &report.best_estimates } else { &report.estimates };
                let errors: Vec<f32> =
                    report.likelihood.get(FaceLikelihoodGpu::ESTIMATE_ERRORS).unwrap();
                prop_assert_eq!(errors.len(), faces);
                prop_assert!(report.likelihood.get::<f32>("no such section").is_err());
                prop_assert!(
                    report.likelihood.get::<[f32; 3]>(FaceLikelihoodGpu::ESTIMATE_ERRORS).is_err()
                        || faces % 3 == 0,
                    "{faces} values are not a whole number of 12-byte values"
                );
                for t in 0..faces {
                    let s: [f32; DIMS] = std::array::from_fn(|d| estimates[t * DIMS + d]);
                    let want = residual_error(&s, &templates[t], &image);
                    let tol = tolerance(&s, &templates[t], &image, &Lens::WEAK, want);
                    let got = f64::from(errors[t]);
                    prop_assert!(
                        (got - want).abs() <= tol,
                        "step {step} face {t}: GPU ε {got} vs CPU {want} (tolerance {tol}), estimate {s:?}"
                    );
                }
            }
            Ok(())
        })
        .unwrap_or_else(common::property::report);
}

#[test]
fn invalid_face_setups_are_typed_errors() {
    let Some(ctx) = common::gpu_context("face setups") else {
        return;
    };
    let make = |faces, points, w, h, sharpness| {
        FaceLikelihoodGpu::new(
            &ctx,
            FaceDispatch::Batched,
            faces,
            points,
            w,
            h,
            sharpness,
            MIN_ERROR,
            MIN_VISIBLE_SHARE,
            Lens::WEAK,
        )
    };
    assert!(make(0, 10, 64, 48, 1.0).is_err());
    assert!(make(1, 0, 64, 48, 1.0).is_err());
    assert!(make(1, 10, 1, 48, 1.0).is_err());
    assert!(make(1, 10, 64, 48, f32::NAN).is_err());
    assert!(make(1, 10, 64, 48, -1.0).is_err());
    // γ = 0 is the flat likelihood of the diffusion-only baseline.
    assert!(make(1, 10, 64, 48, 0.0).is_ok());
    let gpu = make(2, 3, 64, 48, 1.0).unwrap();
    assert!(gpu.upload_frame(&ctx, &[0; 10]).is_err());
    assert!(gpu.upload_frame(&ctx, &[0; 64 * 48 + 1]).is_err());
    assert!(gpu.upload_template(&ctx, 2, &[[0.0; 4]; 2]).is_err());
    assert!(gpu.upload_template(&ctx, 0, &[[0.0; 4]; 8]).is_err());
    assert!(gpu.upload_template(&ctx, 0, &[[0.0; 4]; 3]).is_err());
    assert!(gpu.download_errors(&ctx).is_err());
}
