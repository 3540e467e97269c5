//! Fixed-lag smoothing from the ancestry on the GPU (`pf_gpu::GpuFilter::keep_lag_window`,
//! `shaders/engine/lag_summary.wgsl`) against its CPU twin (`pf_core::smooth::lag_window::
//! LagWindow`) fed with the same filter's particles, log-weights and lineages read back each
//! frame. Fresh random configurations: shapes with edge cases (one particle, a workgroup's
//! 256 and one more), one to six values with angles among them, lags 1 to 4, one to three
//! survival layers, the fused and the staged step, and a target restarted mid-run (its frames
//! before the restart cannot be traced from after it: no summary).
//!
//! Tolerances: the GPU sums in f32 where the twin sums in f64, so a mean may differ by a few
//! ulps of its magnitude, and a quantile's cumulative weight by about 1e-6: an interval's end
//! may then be the next particle's value in sorted order, but never one that more than 1e-4 of
//! the weight separates from the twin's.

mod common;

use bytemuck::{Pod, Zeroable};
use pf_core::anneal::Annealing;
use pf_core::batch::{BatchConfig, BatchShape, gaussian_clouds, wrap_angle_floor};
use pf_core::smooth::ancestry::trace_back;
use pf_core::smooth::lag_window::{LagWindow, LaggedSummaries};
use pf_core::smooth::{Cloud, Summary};
use pf_gpu::model::{ModelFilter, ModelSource};
use pf_gpu::{GpuResampler, StepLayout};
use proptest::prelude::*;

/// A Gaussian around the observation, over every value.
const MODEL: &str = "
struct Observation { z: array<f32, 8> }
struct Constants { sigma: f32, unused: f32 }
fn log_likelihood(x: State, o: Observation, c: Constants) -> f32 {
    var z = o.z;
    var sum = 0.0;
    for (var d = 0u; d < min(DIMS, 8u); d++) {
        let e = (x[d] - z[d]) / c.sigma;
        sum += e * e;
    }
    return -0.5 * sum;
}";

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Observed {
    z: [f32; 8],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Constants {
    sigma: f32,
    unused: f32,
}

const CONSTANTS: Constants = Constants {
    sigma: 0.3,
    unused: 0.0,
};

#[derive(Debug, Clone)]
struct Case {
    config: BatchConfig,
    lag: usize,
    angular: Vec<bool>,
    staged: bool,
    /// Systematic and stratified resampling draw ancestors in order; Metropolis does not (its
    /// lineages cross), and runs staged.
    resampler: GpuResampler,
    /// (target, the frame it is restarted before).
    restart: (usize, usize),
}

fn case() -> impl Strategy<Value = Case> {
    (
        (
            1usize..=3,
            prop_oneof![Just(1usize), Just(256), Just(257), Just(1025), 2usize..400],
        ),
        1usize..=6,
        (1usize..=4, 1usize..=3, 0.3f32..0.8),
        (any::<u64>(), any::<u32>(), any::<bool>(), any::<usize>()),
        prop_oneof![
            Just(GpuResampler::Systematic),
            Just(GpuResampler::Stratified),
            Just(GpuResampler::Metropolis(8)),
        ],
    )
        .prop_map(
            |(
                (targets, particles),
                dims,
                (lag, layers, rate),
                (seed, mask, staged, r),
                resampler,
            )| {
                let shape = BatchShape::new(targets, particles, dims).unwrap();
                let angular: Vec<bool> = (0..dims).map(|d| (mask >> d) & 1 == 1).collect();
                let mut config = BatchConfig::new(shape, seed, vec![0.15; dims]);
                config.angular = angular.clone();
                config.annealing = Annealing::survival(layers, rate, 0.7);
                Case {
                    config,
                    lag,
                    angular,
                    staged: staged || matches!(resampler, GpuResampler::Metropolis(_)),
                    resampler,
                    restart: (r % targets, 1 + r % (lag + 2)),
                }
            },
        )
}

fn observations(targets: usize, frame: usize) -> Vec<Observed> {
    (0..targets)
        .map(|t| Observed {
            z: std::array::from_fn(|d| 2.5 * ((t + 2 * d) as f32 * 0.7 + 0.4 * frame as f32).sin()),
        })
        .collect()
}

fn start(shape: &BatchShape) -> Vec<f32> {
    let means = vec![0.0; shape.targets * shape.dims];
    gaussian_clouds(shape, 5, &means, &vec![0.8; shape.dims])
}

/// The weight of the particles whose offset lies strictly between `a` and `b`.
fn weight_between(offsets: &[(f64, f64)], a: f64, b: f64) -> f64 {
    let (lo, hi) = (a.min(b), a.max(b));
    offsets
        .iter()
        .filter(|(e, _)| *e > lo + 1e-6 && *e < hi - 1e-6)
        .map(|(_, w)| w)
        .sum()
}

/// The GPU's summary of one value against the twin's, given the cloud and smoothing weights
/// the twin used (to judge a quantile's end by the weight between the two).
fn check_value(
    gpu: Summary,
    cpu: Summary,
    (xs, weights): (&[f32], &[f64]),
    angle: bool,
    what: &str,
) -> Result<(), TestCaseError> {
    let gap = |a: f32, b: f32| {
        let e = a - b;
        if angle {
            wrap_angle_floor(e).abs()
        } else {
            e.abs()
        }
    };
    let scale = 1.0
        + cpu
            .mean
            .abs()
            .max(xs.iter().fold(0.0f32, |m, x| m.max(x.abs())));
    prop_assert!(
        gap(gpu.mean, cpu.mean) <= 2e-5 * scale,
        "{what}: mean {} against {}",
        gpu.mean,
        cpu.mean
    );
    let mean = f64::from(cpu.mean);
    let offsets: Vec<(f64, f64)> = (xs.iter().zip(weights))
        .filter(|(_, w)| **w > 0.0)
        .map(|(&x, &w)| {
            let e = f64::from(x) - mean;
            let e = if angle {
                f64::from(wrap_angle_floor(e as f32))
            } else {
                e
            };
            (e, w)
        })
        .collect();
    for (name, g, c) in [
        ("lower", gpu.lower, cpu.lower),
        ("upper", gpu.upper, cpu.upper),
    ] {
        let (g, c) = (f64::from(g) - mean, f64::from(c) - mean);
        let (g, c) = if angle {
            (
                f64::from(wrap_angle_floor(g as f32)),
                f64::from(wrap_angle_floor(c as f32)),
            )
        } else {
            (g, c)
        };
        let close = (g - c).abs() <= 4e-5 * f64::from(scale);
        prop_assert!(
            close || weight_between(&offsets, g, c) <= 1e-4,
            "{what}: {name} end {g} against {c} (offsets from the mean)"
        );
    }
    Ok(())
}

/// What the twin smoothed for target `t`, frame by frame kept by the test: the lagged frame's
/// states and the traced weights (to judge the GPU's quantiles).
struct Kept {
    states: Vec<Vec<f32>>,
    log_weights: Vec<Vec<f32>>,
    lineage: Vec<Vec<u32>>,
}

fn check_report(
    case: &Case,
    kept: &Kept,
    gpu: Option<&LaggedSummaries>,
    cpu: Option<&LaggedSummaries>,
    frame: usize,
) -> Result<(), TestCaseError> {
    let (Some(gpu), Some(cpu)) = (gpu, cpu) else {
        prop_assert_eq!(
            gpu.is_some(),
            cpu.is_some(),
            "frame {}: a summary on one side only",
            frame
        );
        return Ok(());
    };
    prop_assert_eq!(gpu.lag, cpu.lag);
    let shape = case.config.shape;
    let (dims, m) = (shape.dims, shape.particles);
    let first = kept.states.len() - case.lag - 1;
    for (t, (g, c)) in gpu.targets.iter().zip(&cpu.targets).enumerate() {
        let (Some(g), Some(c)) = (g, c) else {
            prop_assert_eq!(
                g.is_some(),
                c.is_some(),
                "frame {} target {}: traceable on one side only",
                frame,
                t
            );
            continue;
        };
        prop_assert!(
            (g.kept - c.kept).abs() <= 1e-4 * (1.0 + c.kept),
            "frame {frame} target {t}: kept {} against {}",
            g.kept,
            c.kept
        );
        let newest = Cloud::of_target(
            dims,
            m,
            t,
            &kept.states[first + case.lag],
            &kept.log_weights[first + case.lag],
            vec![0.0; dims],
        )
        .unwrap();
        let lineages: Vec<&[u32]> = (first + 1..=first + case.lag)
            .map(|k| &kept.lineage[k][t * m..(t + 1) * m])
            .collect();
        let traced = trace_back(&newest.weights, &lineages).unwrap();
        let lagged = Cloud::of_target(
            dims,
            m,
            t,
            &kept.states[first],
            &kept.log_weights[first],
            vec![0.0; dims],
        )
        .unwrap();
        for d in 0..dims {
            let xs = &lagged.states[d * m..(d + 1) * m];
            let what = format!("frame {frame} target {t} value {d}");
            let angle = case.angular[d];
            check_value(
                g.smoothed[d],
                c.smoothed[d],
                (xs, &traced[0]),
                angle,
                &format!("{what} smoothed"),
            )?;
            check_value(
                g.filtered[d],
                c.filtered[d],
                (xs, &lagged.weights),
                angle,
                &format!("{what} filtered"),
            )?;
        }
    }
    Ok(())
}

fn check_gpu(ctx: &pf_gpu::GpuContext, case: &Case) -> Result<(), TestCaseError> {
    let shape = case.config.shape;
    let mut filter = gaussian_filter(ctx, &case.config, case.resampler);
    filter.engine_mut().keep_lag_window(case.lag, true).unwrap();
    let layout = if case.staged {
        StepLayout::Staged
    } else {
        StepLayout::Fused
    };
    let (_, gpu, _) = filter.gpu_parts().unwrap();
    gpu.set_step_layout(layout).unwrap();
    let mut twin = LagWindow::new(shape, case.lag, case.angular.clone(), true).unwrap();
    let mut kept = Kept {
        states: Vec::new(),
        log_weights: Vec::new(),
        lineage: Vec::new(),
    };
    let (restarted, before) = case.restart;
    for frame in 0..case.lag + 4 {
        if frame == before {
            let block = shape.dims * shape.particles;
            let fresh = start(&BatchShape::new(1, shape.particles, shape.dims).unwrap());
            filter.reset_target(restarted, &fresh[..block]).unwrap();
        }
        let report = filter.step(&observations(shape.targets, frame)).unwrap();
        let (_, gpu, _) = filter.gpu_parts().unwrap();
        let back = gpu.download_particles(ctx).unwrap();
        let lineage = back.lineage.unwrap();
        let expected = twin
            .push(&back.states, &back.log_weights, &lineage)
            .unwrap();
        kept.states.push(back.states);
        kept.log_weights.push(back.log_weights);
        kept.lineage.push(lineage);
        check_report(
            case,
            &kept,
            report.lagged.as_ref(),
            expected.as_ref(),
            frame,
        )?;
        if frame >= case.lag {
            prop_assert!(
                report.lagged.is_some(),
                "frame {frame}: no summary with the window full"
            );
        }
    }
    // The frames still in the window, read back for a host that smooths a target's last frames.
    let (_, gpu, _) = filter.gpu_parts().unwrap();
    // The ring holds the last lag + 2 steps (numbered from 1): the window and a spare.
    let recorded = kept.states.len() as u64;
    prop_assert_eq!(gpu.lag_steps_recorded(), Some(recorded));
    let first = recorded - case.lag as u64 - 1;
    let frames = gpu
        .download_lag_frames(ctx, 0, first, case.lag + 2)
        .unwrap();
    prop_assert!(
        gpu.download_lag_frames(ctx, 0, first - 1, 1).is_err(),
        "a step the ring overwrote"
    );
    prop_assert!(
        gpu.download_lag_frames(ctx, 0, recorded, 2).is_err(),
        "a step not yet taken"
    );
    prop_assert!(
        gpu.download_lag_frames(ctx, 0, 0, 0).is_err(),
        "no steps: step 0, count 0"
    );
    prop_assert!(
        gpu.download_lag_frames(ctx, shape.targets, first, 1)
            .is_err(),
        "no such target"
    );
    let m = shape.particles;
    for (k, f) in frames.iter().enumerate() {
        let at = first as usize - 1 + k;
        prop_assert_eq!(&f.states[..], &kept.states[at][..shape.dims * m]);
        prop_assert_eq!(&f.log_weights[..], &kept.log_weights[at][..m]);
        prop_assert_eq!(&f.lineage[..], &kept.lineage[at][..m]);
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 12, ..ProptestConfig::default() })]

    #[test]
    fn the_gpu_lag_window_summarises_as_its_twin(case in case()) {
        let Some(ctx) = common::gpu_context("the lag window on the GPU") else {
            return Ok(());
        };
        check_gpu(&ctx, &case)?;
    }
}

/// The Gaussian test model's filter on the GPU with `resampler`, started at `start`.
fn gaussian_filter(
    ctx: &pf_gpu::GpuContext,
    config: &BatchConfig,
    resampler: GpuResampler,
) -> ModelFilter<Observed, Constants> {
    let source = ModelSource {
        name: "Gaussian",
        wgsl: MODEL,
    };
    let start = start(&config.shape);
    ModelFilter::new(ctx, config, resampler, &start, source, &CONSTANTS).unwrap()
}

/// Lags the window cannot keep, and a window on the CPU engine, are refused with the reason.
#[test]
fn a_lag_window_out_of_range_is_refused() {
    let Some(ctx) = common::gpu_context("lag window refusals") else {
        return;
    };
    let shape = BatchShape::new(1, 16, 2).unwrap();
    let config = BatchConfig::new(shape, 1, vec![0.1; 2]);
    let mut filter = gaussian_filter(&ctx, &config, GpuResampler::Systematic);
    for lag in [0, pf_gpu::MAX_LAG + 1] {
        let err = filter.engine_mut().keep_lag_window(lag, false).unwrap_err();
        assert!(err.to_string().contains("lag"), "{err}");
    }
    let (_, gpu, _) = filter.gpu_parts().unwrap();
    assert!(
        gpu.download_lag_frames(&ctx, 0, 1, 1).is_err(),
        "no window, nothing to read"
    );
    let mut cpu = pf_gpu::engine::FilterEngine::cpu(
        &config,
        pf_core::ResamplerKind::Systematic,
        start(&shape),
    )
    .unwrap();
    let err = cpu.keep_lag_window(2, false).unwrap_err();
    assert!(err.to_string().contains("host"), "{err}");
    cpu.drop_lag_window().unwrap();
    // More particles a target than the kernel's invocations take (16 each, MAX_CHUNK).
    let kernel = pf_gpu::kernels::sources::LAG_SUMMARY;
    let chunk = pf_gpu::MAX_LAG_PARTICLES / 256;
    assert!(kernel.contains(&format!("const MAX_CHUNK: u32 = {chunk}u;")));
    let many = BatchShape::new(1, pf_gpu::MAX_LAG_PARTICLES + 1, 1).unwrap();
    let config = BatchConfig::new(many, 1, vec![0.1]);
    let mut filter = gaussian_filter(&ctx, &config, GpuResampler::Systematic);
    let err = filter.engine_mut().keep_lag_window(2, false).unwrap_err();
    assert!(err.to_string().contains("at most"), "{err}");
}

/// A window dropped summarises no more steps and keeps no frames; kept again, it fills anew.
#[test]
fn a_dropped_lag_window_summarises_nothing_until_kept_again() {
    let Some(ctx) = common::gpu_context("lag window dropped") else {
        return;
    };
    let shape = BatchShape::new(2, 16, 2).unwrap();
    let config = BatchConfig::new(shape, 3, vec![0.1; 2]);
    let mut filter = gaussian_filter(&ctx, &config, GpuResampler::Systematic);
    let lag = 2;
    filter.engine_mut().keep_lag_window(lag, false).unwrap();
    let mut frame = 0;
    let mut step = |filter: &mut ModelFilter<Observed, Constants>| {
        frame += 1;
        filter
            .step(&observations(2, frame))
            .unwrap()
            .lagged
            .is_some()
    };
    let summarised: Vec<bool> = (0..lag + 2).map(|_| step(&mut filter)).collect();
    assert_eq!(summarised, [false, false, true, true]);
    filter.engine_mut().drop_lag_window().unwrap();
    assert!(
        (0..3).all(|_| !step(&mut filter)),
        "a dropped window summarised"
    );
    let (_, gpu, _) = filter.gpu_parts().unwrap();
    assert_eq!(gpu.lag_window(), None);
    assert!(gpu.download_lag_frames(&ctx, 0, 1, 1).is_err());
    filter.engine_mut().keep_lag_window(lag, false).unwrap();
    let again: Vec<bool> = (0..lag + 1).map(|_| step(&mut filter)).collect();
    assert_eq!(again, [false, false, true]);
}

/// A profiled step (`GpuFilter::profile_dispatches`) times the lag window's dispatch after the
/// step's own: the step kept in the ring, with the summary once the window is full (what
/// smoothing adds to a frame on the GPU is then read apart from the benchmark's whole-step
/// spread), and summarises as an unprofiled step does.
#[test]
fn a_profiled_step_times_the_lag_window_last() {
    let Some(ctx) = common::gpu_context("lag window profiled") else {
        return;
    };
    let shape = BatchShape::new(2, 40, 3).unwrap();
    let mut config = BatchConfig::new(shape, 5, vec![0.1; 3]);
    config.annealing = Annealing::survival(2, 0.5, 0.7);
    let lag = 2;
    let mut plain = gaussian_filter(&ctx, &config, GpuResampler::Systematic);
    let mut profiled = gaussian_filter(&ctx, &config, GpuResampler::Systematic);
    for filter in [&mut plain, &mut profiled] {
        let (ctx, gpu, _) = filter.gpu_parts().unwrap();
        gpu.set_step_layout(StepLayout::Fused).unwrap();
        gpu.keep_lag_window(ctx, lag, false).unwrap();
    }
    let (ctx_p, gpu, _) = profiled.gpu_parts().unwrap();
    if !ctx_p.has_timestamps() {
        assert!(gpu.profile_dispatches(ctx_p, true).is_err());
        return;
    }
    gpu.profile_dispatches(ctx_p, true).unwrap();
    for frame in 1..=lag + 2 {
        let z = observations(2, frame);
        let expected = plain.step(&z).unwrap();
        let got = profiled.step(&z).unwrap();
        assert_eq!(got.estimates, expected.estimates);
        assert_eq!(got.lagged, expected.lagged);
        let (ctx_p, gpu, _) = profiled.gpu_parts().unwrap();
        let times = gpu.dispatch_times(ctx_p).unwrap();
        let labels: Vec<&str> = times.iter().map(|d| d.label.as_str()).collect();
        let summarised = frame > lag;
        let expected = if summarised {
            ["estimate", "lag window: summary and the step kept"]
        } else {
            ["estimate", "lag window: the step kept"]
        };
        assert_eq!(
            labels[labels.len() - expected.len()..],
            expected,
            "{labels:?}"
        );
        // In order on the GPU's clock: each starts after the one before has ended.
        for pair in times[times.len() - expected.len()..].windows(2) {
            assert!(
                pair[1].start >= pair[0].start + pair[0].duration,
                "{times:?}"
            );
        }
    }
}
