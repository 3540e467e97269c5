//! The marginal backward smoother on the GPU (`shaders/engine/smooth.wgsl`,
//! `pf_gpu::smooth::GpuSmoother`) against its CPU twin (`pf_core::smooth::smooth_all` over each
//! value's block, as `smooth_values` runs it), on fresh random tracks: one to four tracks of one
//! to six frames, clouds of 1, 2, 64 or up to 300 particles, angles (differences across ±π),
//! values that do not move (σ = 0), drifts, and particles of zero weight.
//!
//! Tolerance: each normalised smoothed weight within 2e-3 of the twin's relative to the largest
//! weight of its frame, plus 1e-3 of its own value. The GPU sums M terms of f32 (log-sum-exp and
//! the reweighing) where the twin sums f64, and the error grows with each backward step it
//! passes through; at these sizes lavapipe's largest difference was well inside the bound.

mod common;

use pf_core::smooth::{Cloud, GaussianTransition, smooth_all, smooth_values};
use pf_core::smooth_tracks::TrackSmoother;
use pf_gpu::smooth::GpuSmoother;
use proptest::prelude::*;

fn cloud(particles: usize, dims: usize, seed: u64, zero_some: bool) -> Cloud {
    // A small deterministic generator: the property test draws the seed.
    let mut state = seed
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    let mut next = || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((state >> 33) as f64) / f64::from(1u32 << 31)
    };
    let states: Vec<f32> = (0..dims * particles)
        .map(|_| (next() * 6.0 - 3.0) as f32)
        .collect();
    let mut weights: Vec<f64> = (0..particles).map(|_| 0.05 + next()).collect();
    if zero_some && particles > 1 {
        for w in weights.iter_mut().step_by(3) {
            *w = 0.0;
        }
    }
    let total: f64 = weights.iter().sum();
    weights.iter_mut().for_each(|w| *w /= total);
    let drift = (0..dims).map(|_| (next() * 0.4 - 0.2) as f32).collect();
    Cloud {
        states,
        weights,
        drift,
    }
}

#[derive(Debug, Clone)]
struct Case {
    particles: usize,
    sigma: Vec<f32>,
    angular: Vec<bool>,
    lengths: Vec<usize>,
    seed: u64,
    zero_some: bool,
}

fn case() -> impl Strategy<Value = Case> {
    let particles = prop_oneof![Just(1usize), Just(2), Just(64), 3usize..300];
    (particles, 1usize..=4)
        .prop_flat_map(|(particles, dims)| {
            (
                Just(particles),
                prop::collection::vec(prop_oneof![Just(0.0f32), 0.2f32..2.0], dims),
                prop::collection::vec(any::<bool>(), dims),
                prop::collection::vec(1usize..=6, 1..=4),
                any::<u64>(),
                any::<bool>(),
            )
        })
        .prop_map(
            |(particles, sigma, angular, lengths, seed, zero_some)| Case {
                particles,
                sigma,
                angular,
                lengths,
                seed,
                zero_some,
            },
        )
}

fn tracks(case: &Case) -> Vec<Vec<Cloud>> {
    let dims = case.sigma.len();
    case.lengths
        .iter()
        .enumerate()
        .map(|(r, &len)| {
            (0..len)
                .map(|f| {
                    let seed = case.seed ^ ((r as u64) << 40) ^ (f as u64 * 7919);
                    cloud(case.particles, dims, seed, case.zero_some)
                })
                .collect()
        })
        .collect()
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    #[test]
    fn gpu_smoother_matches_cpu_within_tolerance(case in case()) {
        let Some(ctx) = common::gpu_context("GPU smoother against the CPU") else {
            return Ok(());
        };
        let transition = GaussianTransition {
            sigma: case.sigma.clone(),
            angular: case.angular.clone(),
        };
        let tracks = tracks(&case);
        let views: Vec<&[Cloud]> = tracks.iter().map(Vec::as_slice).collect();
        let gpu = GpuSmoother::new(&ctx).unwrap().smooth(&ctx, &views, &transition).unwrap();
        for (r, frames) in tracks.iter().enumerate() {
            for d in 0..case.sigma.len() {
                let cpu = smooth_all(frames, &transition.block(&[d])).unwrap();
                for (f, expected) in cpu.iter().enumerate() {
                    let got = gpu.get(r, f, d).unwrap();
                    let largest = expected.iter().cloned().fold(0.0, f64::max);
                    for (m, (&g, &c)) in got.iter().zip(expected).enumerate() {
                        let bound = 2e-3 * largest + 1e-3 * c;
                        prop_assert!(
                            (f64::from(g) - c).abs() <= bound,
                            "track {} frame {} value {} particle {}: GPU {} CPU {}", r, f, d, m, g, c
                        );
                    }
                }
            }
            // The summaries the trackers write: each frame's smoothed means where the values
            // do not wrap, within what the weights' bound lets them move (each weight's bound
            // times the frame's largest |value|, summed over the particles).
            let cpu = smooth_values(frames, &transition).unwrap();
            let summaries = gpu.summaries(r, frames, &case.angular).unwrap();
            prop_assert_eq!(cpu.len(), summaries.len());
            for (f, (c_row, g_row)) in cpu.iter().zip(&summaries).enumerate() {
                let cloud = &frames[f];
                let largest = cloud.states.iter().fold(0.0f32, |m, v| m.max(v.abs()));
                for d in (0..case.sigma.len()).filter(|&d| !case.angular[d]) {
                    let weights = &smooth_all(frames, &transition.block(&[d])).unwrap()[f];
                    let heaviest = weights.iter().cloned().fold(0.0, f64::max) as f32;
                    let bound = largest * (2e-3 * heaviest * case.particles as f32 + 1e-3);
                    prop_assert!(
                        (c_row[d].mean - g_row[d].mean).abs() <= bound.max(1e-4),
                        "track {} frame {} value {}: mean GPU {} CPU {}", r, f, d, g_row[d].mean, c_row[d].mean
                    );
                }
            }
        }
    }
}

/// Clouds that disagree with each other or with the transition are refused, with the reason.
#[test]
fn mismatched_clouds_are_refused() {
    let Some(ctx) = common::gpu_context("GPU smoother refusals") else {
        return;
    };
    let smoother = GpuSmoother::new(&ctx).unwrap();
    let transition = GaussianTransition {
        sigma: vec![1.0, 1.0],
        angular: vec![false, false],
    };
    let good = cloud(10, 2, 1, false);
    let short = cloud(9, 2, 2, false);
    let frames = [good.clone(), short];
    let error = smoother
        .smooth(&ctx, &[&frames[..]], &transition)
        .unwrap_err();
    assert!(error.to_string().contains("10 particles"), "{error}");
    let bad_sigma = GaussianTransition {
        sigma: vec![1.0, f32::NAN],
        angular: vec![false, false],
    };
    let one = [good];
    let error = smoother.smooth(&ctx, &[&one[..]], &bad_sigma).unwrap_err();
    assert!(error.to_string().contains("sigma"), "{error}");
}

/// The trackers' smoother (`TrackSmoother`) on the GPU writes the rows it writes on the CPU: the
/// same frames and tracks, every smoothed mean within 0.05 of the CPU's (values over ±3), online
/// with a lag (the marginal smoother over each window) and over whole tracks.
#[test]
fn the_track_smoother_on_the_gpu_writes_the_cpus_rows() {
    let Some(ctx) = common::gpu_context("track smoother on the GPU") else {
        return;
    };
    let transition = GaussianTransition {
        sigma: vec![0.5, 0.0, 1.5],
        angular: vec![false, false, true],
    };
    let on_gpu = std::sync::Arc::new(pf_gpu::smooth::OnGpu::new(&ctx).unwrap());
    for lag in [None, Some(2)] {
        // A lag window smoothed by the marginal smoother runs on the backend too (the
        // ancestry's, on the host, does not).
        let smoother = || {
            TrackSmoother::new(lag, transition.clone(), 0.5)
                .lagging_by(pf_core::smooth_tracks::LagSmoother::Marginal)
        };
        let mut cpu = smoother();
        let mut gpu = smoother().on(on_gpu.clone());
        let (mut rows_cpu, mut rows_gpu) = (Vec::new(), Vec::new());
        for frame in 0..6 {
            // Track 0 all along, track 1 from frame 1 to 3.
            let tracks: Vec<usize> = (0..2)
                .filter(|&t| t == 0 || (1..=3).contains(&frame))
                .collect();
            let clouds = |_: ()| -> Vec<pf_core::smooth_tracks::TrackCloud> {
                tracks
                    .iter()
                    .map(|&t| {
                        let c = cloud(50, 3, (frame * 10 + t) as u64, false);
                        let log_weights = c.weights.iter().map(|w| (*w as f32).ln()).collect();
                        (t, c.states, log_weights).into()
                    })
                    .collect()
            };
            rows_cpu.extend(cpu.add_frame(frame, clouds(())).unwrap());
            rows_gpu.extend(gpu.add_frame(frame, clouds(())).unwrap());
        }
        rows_cpu.extend(cpu.finish().unwrap());
        rows_gpu.extend(gpu.finish().unwrap());
        assert_eq!(rows_cpu.len(), rows_gpu.len(), "lag {lag:?}");
        for (c, g) in rows_cpu.iter().zip(&rows_gpu) {
            assert_eq!((c.frame, c.track), (g.frame, g.track));
            for d in [0usize, 1] {
                let (a, b) = (c.values[d].mean, g.values[d].mean);
                assert!(
                    (a - b).abs() <= 0.05,
                    "lag {lag:?} frame {} track {} value {d}: CPU {a} GPU {b}",
                    c.frame,
                    c.track
                );
            }
        }
    }
    assert!(!on_gpu.fell_back());
}
