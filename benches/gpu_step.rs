//! The whole filter step per frame — resample, diffuse, measure (toy 7-D Gaussian likelihood),
//! normalise, estimate — for T ∈ {1, 16, 64} targets × M = 1000 particles: the same filter on the
//! CPU engine, all cores (pf-core's batch filter, the model's CPU twin) against the GPU driver (one
//! submission per frame, estimates and statistics read back), with the likelihood written by hand
//! (`gpu`) and through the model plug-in (`gpu_plugin`, `pf_gpu::toy::TOY_MODEL`). Then resampling alone on the GPU
//! for one target of N = 10^3 … 10^6 particles, against pf-core's CPU resamplers.
//!
//! Then the plug-in model with five annealing layers over every GPU of the host
//! (`plugin_over_gpus_7d_1000`: `ShardedModelFilter`, two frames in flight) against the same
//! filter on one GPU, for 256 and 1024 targets.
//!
//! Then the annealed step (five survival-rule layers, the face tracker's schedule) of the plug-in
//! model for T ∈ {1, 16, 64, 256} targets, fused (`StepLayout::Fused`, the default: a layer is
//! two engine dispatches, select and move, and the model's) against staged (every stage its own dispatch), each with
//! the GPU's own time printed (timestamps, median of 50 steps).
//!
//! Then the marginal backward smoother (`pf_gpu::smooth::GpuSmoother`, each of the 7 values its
//! own block, 1 000 particles): a whole run of 1 000 frames × 64 targets, and the fixed-lag
//! smoother's window (8 frames behind: 9 frames × 64 targets) that a frame recomputes, against the
//! CPU twin (`pf_core::smooth::smooth_values`, all cores) on the window of 4 targets.
//!
//! Every GPU timing includes the submission, the device wait and the readback. The adapter is
//! printed at the start; set WGPU_ADAPTER_NAME to choose one.

mod common;

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use pf_core::anneal::{Annealing, Tempering};
use pf_core::batch::{BatchConfig, BatchShape, gaussian_clouds};
use pf_core::resample::{Metropolis, Systematic};
use pf_core::smooth::motion::{OnlineMotion, smooth_values_by_evidence};
use pf_core::smooth::{Cloud, GaussianTransition, smooth_values};
use pf_core::{RandomStreams, Resampler, ResamplerKind, Stage};
use pf_gpu::engine::Filter;
use pf_gpu::model::{ModelFilter, Plugin, ShardedModelFilter, ShardedPending};
use pf_gpu::smooth::GpuSmoother;
use pf_gpu::toy::{TOY_MODEL, ToyConstants, ToyGaussianLikelihood, ToyObservation, ToyTwin};
use pf_gpu::{
    ContextOptions, GpuContext, GpuFilter, GpuLikelihood, GpuResampler, GpuStage, NoLikelihood,
    StepLayout,
};
use std::collections::VecDeque;

const D: usize = 7;
const M: usize = 1000;
const ANGLES: [bool; D] = [false, false, false, true, true, true, false];
const OBS_SIGMA: [f32; D] = [4.0, 4.0, 0.05, 0.1, 0.1, 0.1, 0.05];
const DIFFUSION: [f32; D] = [3.0, 3.0, 0.02, 0.05, 0.08, 0.05, 0.02];

fn observed(t: usize, s: usize) -> [f32; D] {
    let (t, s) = (t as f32, s as f32);
    [
        100.0 + 20.0 * t + 2.0 * s,
        50.0 + 40.0 * (0.05 * s).sin(),
        1.0,
        0.1,
        0.05 * s % 3.0,
        0.0,
        1.0,
    ]
}

fn context() -> GpuContext {
    // Benchmarks want the real GPU; a software adapter only when nothing else exists.
    let ctx = GpuContext::new(&ContextOptions::default())
        .or_else(|_| GpuContext::new(&ContextOptions::for_tests()))
        .expect("a GPU adapter (see `streampf devices`)");
    let a = ctx.adapter();
    eprintln!("GPU adapter: {} ({}, {})", a.name, a.device_type, a.backend);
    ctx
}

/// The toy tracker's filter for `targets` targets (systematic resampling every step, no bounds)
/// with `annealing`, and its starting clouds about each target's first observation.
fn toy_batch(targets: usize, annealing: Annealing) -> (BatchConfig, Vec<f32>) {
    let shape = BatchShape::new(targets, M, D).unwrap();
    let mut config = BatchConfig::new(shape, 1, DIFFUSION.to_vec());
    config.angular = ANGLES.to_vec();
    config.annealing = annealing;
    let means: Vec<f32> = (0..targets).flat_map(|t| observed(t, 0)).collect();
    let initial = gaussian_clouds(&shape, 1, &means, &OBS_SIGMA);
    (config, initial)
}

/// The toy model through the plug-in API (`pf_gpu::model`) for `config` and `initial` (from
/// [`toy_batch`]), systematic resampling.
fn toy_plugin(
    ctx: &GpuContext,
    config: &BatchConfig,
    initial: &[f32],
) -> ModelFilter<ToyObservation, ToyConstants> {
    let constants = ToyConstants::from_sigma(&OBS_SIGMA).unwrap();
    ModelFilter::new(
        ctx,
        config,
        GpuResampler::Systematic,
        initial,
        TOY_MODEL,
        &constants,
    )
    .unwrap()
}

fn bench_whole_step(c: &mut Criterion) {
    let ctx = context();
    let mut group = c.benchmark_group("whole_step_7d_1000");
    group.sample_size(20);
    for &targets in &[1usize, 16, 64] {
        group.throughput(Throughput::Elements((targets * M) as u64));
        let (config, initial) = toy_batch(targets, Default::default());

        // GPU: one submission per frame.
        let mut gpu = GpuFilter::new(&ctx, &config, GpuResampler::Systematic, &initial).unwrap();
        let mut toy = ToyGaussianLikelihood::new(&ctx, targets, &OBS_SIGMA).unwrap();
        toy.prepare(&ctx, &gpu.likelihood_inputs()).unwrap();
        let mut frame = 0;
        group.bench_function(BenchmarkId::new("gpu", targets), |b| {
            b.iter(|| {
                let obs: Vec<f32> = (0..targets).flat_map(|t| observed(t, frame)).collect();
                toy.upload_observations(&ctx, &obs).unwrap();
                frame += 1;
                std::hint::black_box(gpu.step(&ctx, &toy).unwrap());
            })
        });

        // The same model through the plug-in API (pf_gpu::model), same filter settings.
        let constants = ToyConstants::from_sigma(&OBS_SIGMA).unwrap();
        let mut plugin = toy_plugin(&ctx, &config, &initial);
        let mut frame = 0;
        group.bench_function(BenchmarkId::new("gpu_plugin", targets), |b| {
            b.iter(|| {
                let obs: Vec<ToyObservation> = (0..targets)
                    .map(|t| ToyObservation {
                        z: observed(t, frame),
                    })
                    .collect();
                frame += 1;
                std::hint::black_box(plugin.step(&obs).unwrap());
            })
        });

        // CPU, all cores: the same filter on the CPU engine (pf-core's batch filter, each stage
        // over the targets and particles in parallel), the same model's CPU twin.
        let twin = ToyTwin { angular: ANGLES };
        let mut cpu = Filter::on_cpu(
            &config,
            ResamplerKind::Systematic,
            initial.clone(),
            Plugin::cpu(twin, constants),
        )
        .unwrap();
        let mut frame = 0;
        group.bench_function(BenchmarkId::new("cpu_all_cores", targets), |b| {
            b.iter(|| {
                let obs: Vec<ToyObservation> = (0..targets)
                    .map(|t| ToyObservation {
                        z: observed(t, frame),
                    })
                    .collect();
                frame += 1;
                std::hint::black_box(cpu.step(&obs).unwrap());
            })
        });
    }
    group.finish();
}

fn bench_resampling_alone(c: &mut Criterion) {
    let ctx = context();
    let mut group = c.benchmark_group("resample_alone");
    group.sample_size(10);
    for &n in &[1_000usize, 10_000, 100_000, 1_000_000] {
        group.throughput(Throughput::Elements(n as u64));
        let shape = BatchShape::new(1, n, 1).unwrap();
        let config = BatchConfig {
            shape,
            seed: 2,
            sigma: vec![0.0],
            bounds: None,
            angular: vec![false],
            ess_threshold: f64::INFINITY,
            best: 0,
            annealing: Default::default(),
            motion: Default::default(),
        };
        // Uneven weights: a Gaussian likelihood over a Gaussian cloud.
        let mut rng = RandomStreams::new(3).stream(0, Stage::Model(0));
        let states: Vec<f32> = (0..n).map(|_| rng.gaussian_f32()).collect();
        let loglik: Vec<f32> = states.iter().map(|x| -0.5 * x * x).collect();
        let lse = pf_core::weights::log_sum_exp(&loglik).unwrap();
        let weights: Vec<f64> = loglik
            .iter()
            .map(|&l| lse.normalised_log(l).exp())
            .collect();
        let weights_f32: Vec<f32> = weights.iter().map(|&w| w as f32).collect();
        for (name, resampler) in [
            ("systematic", GpuResampler::Systematic),
            ("metropolis_b32", GpuResampler::Metropolis(32)),
        ] {
            let mut gpu = GpuFilter::new(&ctx, &config, resampler, &states).unwrap();
            gpu.streams().weights.upload(&ctx, &weights_f32).unwrap();
            group.bench_function(BenchmarkId::new(format!("gpu_{name}"), n), |b| {
                b.iter(|| {
                    std::hint::black_box(
                        gpu.run_stages(&ctx, &[GpuStage::Resample], &NoLikelihood)
                            .unwrap(),
                    )
                })
            });
        }
        let uniforms = RandomStreams::new(4).counter_uniforms(0, Stage::Resampling, 0);
        let mut ancestors = vec![0u32; n];
        for (name, r) in [
            ("systematic", Box::new(Systematic) as Box<dyn Resampler>),
            ("metropolis_b32", Box::new(Metropolis::new(32))),
        ] {
            group.bench_function(BenchmarkId::new(format!("cpu_{name}"), n), |b| {
                b.iter(|| {
                    r.resample(&weights, &uniforms, &mut ancestors).unwrap();
                    std::hint::black_box(&ancestors);
                })
            });
        }
    }
    group.finish();
}

/// A frame's observations for `targets` toy targets.
fn toy_observations(targets: usize, frame: usize) -> Vec<ToyObservation> {
    (0..targets)
        .map(|t| ToyObservation {
            z: observed(t, frame),
        })
        .collect()
}

fn bench_plugin_over_gpus(c: &mut Criterion) {
    let options = ContextOptions::default();
    let gpus = GpuContext::all(&options).map_or(0, |all| all.len());
    if gpus == 0 {
        eprintln!("plugin_over_gpus: no hardware GPU adapter; not measured");
        return;
    }
    let mut group = c.benchmark_group("plugin_over_gpus_7d_1000");
    group.sample_size(10);
    let constants = ToyConstants::from_sigma(&OBS_SIGMA).unwrap();
    for &targets in &[256usize, 1024] {
        group.throughput(Throughput::Elements((targets * M) as u64));
        let (config, initial) = toy_batch(targets, Annealing::survival(5, 0.5, 0.6));
        let mut counts = vec![1, gpus];
        counts.dedup();
        for count in counts {
            let contexts: Vec<GpuContext> = GpuContext::all(&options)
                .unwrap()
                .into_iter()
                .take(count)
                .collect();
            for ctx in &contexts {
                let a = ctx.adapter();
                eprintln!(
                    "plugin_over_gpus: {} ({}, {})",
                    a.name, a.device_type, a.backend
                );
            }
            let mut filter = ShardedModelFilter::new(
                contexts,
                &config,
                GpuResampler::Systematic,
                &initial,
                TOY_MODEL,
                &constants,
            )
            .unwrap();
            // Two frames in flight: each iteration submits a frame and reads the one before.
            let mut pending: Option<ShardedPending> = None;
            let mut frame = 0;
            group.bench_function(BenchmarkId::new(format!("gpus_{count}"), targets), |b| {
                b.iter(|| {
                    let next = filter.submit(&toy_observations(targets, frame)).unwrap();
                    frame += 1;
                    if let Some(previous) = pending.replace(next) {
                        std::hint::black_box(filter.finish(previous).unwrap());
                    }
                })
            });
            if let Some(last) = pending.take() {
                filter.finish(last).unwrap();
            }
        }
    }
    group.finish();
}

/// The plug-in model with the face tracker's five annealing layers, fused against staged; and
/// fused with five fixed exponents instead of the survival rule's (what choosing β costs).
fn bench_annealed_layouts(c: &mut Criterion) {
    let ctx = context();
    // Under `cargo test` (no `--bench`) each layout runs once at two sizes, unreported: the
    // check that the benchmark works, not a measurement (all four sizes with their 50 timed
    // steps took 2.5 minutes on lavapipe).
    let measuring = std::env::args().any(|a| a == "--bench");
    let mut group = c.benchmark_group("annealed_step_7d_1000");
    group.sample_size(20);
    let fixed = Annealing {
        tempering: Tempering::Fixed(vec![0.2, 0.35, 0.5, 0.75, 1.0]),
        ..Annealing::survival(5, 0.5, 0.7)
    };
    let schedules = [
        ("fused", StepLayout::Fused, Annealing::survival(5, 0.5, 0.7)),
        (
            "staged",
            StepLayout::Staged,
            Annealing::survival(5, 0.5, 0.7),
        ),
        ("fused_fixed_beta", StepLayout::Fused, fixed),
    ];
    let sizes: &[usize] = if measuring {
        &[1, 16, 64, 256]
    } else {
        &[1, 16]
    };
    for &targets in sizes {
        group.throughput(Throughput::Elements((targets * M) as u64));
        for (name, layout, annealing) in &schedules {
            let (config, initial) = toy_batch(targets, annealing.clone());
            let layout = *layout;
            let mut plugin = toy_plugin(&ctx, &config, &initial);
            plugin
                .gpu_parts()
                .unwrap()
                .1
                .set_step_layout(layout)
                .unwrap();
            let mut frame = 0;
            let mut step = move |plugin: &mut ModelFilter<ToyObservation, ToyConstants>| {
                let obs: Vec<ToyObservation> = (0..targets)
                    .map(|t| ToyObservation {
                        z: observed(t, frame),
                    })
                    .collect();
                frame += 1;
                plugin.step(&obs).unwrap()
            };
            let mut reported = !measuring;
            group.bench_function(BenchmarkId::new(*name, targets), |b| {
                b.iter(|| std::hint::black_box(step(&mut plugin)));
                if !reported {
                    let own = || {
                        let time = step(&mut plugin).gpu_time?;
                        Some(time.duration().as_secs_f64() * 1e6)
                    };
                    if let Some(median) = median_of_50(own) {
                        eprintln!("annealed step, {name}, {targets} targets: GPU's own time {median:.1} us (median of 50)");
                    }
                    reported = true;
                }
            });
        }
    }
    group.finish();
}

/// Where a plain step's GPU time goes: each stage alone, one submission each (the staged
/// dispatches, with the step's copies back and timestamps), at 1 and 64 targets of the toy
/// model; and the fused annealed step at one to five layers. Under `--bench` each prints the
/// GPU's own time (timestamps, median of 50 steps).
fn bench_stage_times(c: &mut Criterion) {
    let ctx = context();
    let measuring = std::env::args().any(|a| a == "--bench");
    let mut group = c.benchmark_group("stage_times_7d_1000");
    group.sample_size(10);
    let stages: [(&str, &[GpuStage]); 7] = [
        ("resample", &[GpuStage::Resample]),
        ("gather", &[GpuStage::Gather]),
        ("diffuse", &[GpuStage::Diffuse]),
        ("likelihood", &[GpuStage::Likelihood]),
        ("normalise", &[GpuStage::Normalise]),
        ("estimate", &[GpuStage::Estimate]),
        ("whole_step", &GpuStage::ALL),
    ];
    for &targets in &[1usize, 64] {
        let (config, initial) = toy_batch(targets, Default::default());
        let mut gpu = GpuFilter::new(&ctx, &config, GpuResampler::Systematic, &initial).unwrap();
        let mut toy = ToyGaussianLikelihood::new(&ctx, targets, &OBS_SIGMA).unwrap();
        toy.prepare(&ctx, &gpu.likelihood_inputs()).unwrap();
        let obs: Vec<f32> = (0..targets).flat_map(|t| observed(t, 1)).collect();
        toy.upload_observations(&ctx, &obs).unwrap();
        for (name, only) in stages {
            group.bench_function(BenchmarkId::new(name, targets), |b| {
                b.iter(|| std::hint::black_box(gpu.run_stages(&ctx, only, &toy).unwrap()))
            });
            if measuring {
                let time = || {
                    let report = gpu.run_stages(&ctx, only, &toy).ok()?;
                    Some(report.time.duration().as_secs_f64() * 1e6)
                };
                if let Some(us) = median_of_50(time) {
                    eprintln!("stage {name}, {targets} targets: GPU's own time {us:.1} us");
                }
            }
        }
    }
    for layers in [1usize, 2, 5] {
        let (config, initial) = toy_batch(1, Annealing::survival(layers, 0.5, 0.7));
        let mut plugin = toy_plugin(&ctx, &config, &initial);
        let obs = [ToyObservation { z: observed(0, 1) }];
        group.bench_function(BenchmarkId::new("fused_layers", layers), |b| {
            b.iter(|| std::hint::black_box(plugin.step(&obs).unwrap()))
        });
        if measuring {
            let time = || {
                let gpu_time = plugin.step(&obs).ok()?.gpu_time?;
                Some(gpu_time.duration().as_secs_f64() * 1e6)
            };
            if let Some(us) = median_of_50(time) {
                eprintln!(
                    "fused annealed step, {layers} layers, 1 target: GPU's own time {us:.1} us"
                );
            }
        }
    }
    group.finish();
    if measuring {
        profile_fused_dispatches(&ctx);
    }
}

/// Each dispatch of the fused five-layer annealed step of the toy plug-in, at 1 and 64
/// targets, timed in a pass of its own (`GpuFilter::profile_dispatches`).
fn profile_fused_dispatches(ctx: &GpuContext) {
    for targets in [1usize, 64] {
        let (config, initial) = toy_batch(targets, Annealing::survival(5, 0.5, 0.7));
        let mut plugin = toy_plugin(ctx, &config, &initial);
        let obs: Vec<ToyObservation> = (0..targets)
            .map(|t| ToyObservation { z: observed(t, 1) })
            .collect();
        let Some((ctx, gpu, _)) = plugin.gpu_parts() else {
            return;
        };
        if let Err(e) = gpu.profile_dispatches(ctx, true) {
            eprintln!("dispatch profile: {e}");
            return;
        }
        common::report_dispatch_profile(
            &format!("fused annealed step, 5 layers, {targets} targets"),
            || {
                plugin.step(&obs).ok()?;
                let (ctx, gpu, _) = plugin.gpu_parts()?;
                gpu.dispatch_times(ctx).ok()
            },
        );
    }
}

/// The median of 50 of `sample`'s values (those it gives).
fn median_of_50(mut sample: impl FnMut() -> Option<f64>) -> Option<f64> {
    let mut values: Vec<f64> = (0..50).filter_map(|_| sample()).collect();
    values.sort_by(f64::total_cmp);
    values.get(values.len() / 2).copied()
}

/// A track of `frames` random clouds of M particles in D values (the smoother's time does not
/// depend on the values).
fn random_track(frames: usize, seed: u64) -> Vec<Cloud> {
    (0..frames)
        .map(|f| {
            let shape = BatchShape::new(1, M, D).unwrap();
            let states = gaussian_clouds(&shape, seed + f as u64, &[0.0; D], &[1.0; D]);
            Cloud {
                states,
                weights: vec![1.0 / M as f64; M],
                drift: vec![0.01; D],
            }
        })
        .collect()
}

fn bench_smoother(c: &mut Criterion) {
    let ctx = context();
    let smoother = GpuSmoother::new(&ctx).unwrap();
    let transition = GaussianTransition {
        sigma: DIFFUSION.to_vec(),
        angular: ANGLES.to_vec(),
    };
    let mut group = c.benchmark_group("smoother_7d_1000");
    group.sample_size(10);
    // `cargo test --benches` runs each once: a token size there (lavapipe would take hours).
    let full = std::env::args().any(|a| a == "--bench");
    let (targets, cpu_targets, frames) = if full { (64, 4, 1000) } else { (2, 1, 4) };
    let window: Vec<Vec<Cloud>> = (0..targets).map(|t| random_track(9, 100 * t)).collect();
    let views: Vec<&[Cloud]> = window.iter().map(Vec::as_slice).collect();
    group.bench_function("gpu_fixed_lag_8_window_64_targets", |b| {
        b.iter(|| std::hint::black_box(smoother.smooth(&ctx, &views, &transition).unwrap()))
    });
    group.bench_function("cpu_fixed_lag_8_window_4_targets", |b| {
        b.iter(|| {
            for track in &window[..cpu_targets] {
                std::hint::black_box(smooth_values(track, &transition).unwrap());
            }
        })
    });
    let run: Vec<Vec<Cloud>> = (0..targets)
        .map(|t| random_track(frames, 10_000 * t))
        .collect();
    let views: Vec<&[Cloud]> = run.iter().map(Vec::as_slice).collect();
    group.bench_function("gpu_full_run_1000_frames_64_targets", |b| {
        b.iter(|| std::hint::black_box(smoother.smooth(&ctx, &views, &transition).unwrap()))
    });
    // The motion chosen by the evidence (`--smooth-motion auto`, on the CPU's cores whatever
    // the tracker ran on): one target's whole run; 64 targets cost 64 times it.
    group.bench_function("cpu_by_evidence_full_run_1000_frames_1_target", |b| {
        b.iter(|| std::hint::black_box(smooth_values_by_evidence(&run[0], &transition).unwrap()))
    });
    // The same with a lag (`--smooth-lag 8 --smooth-motion auto`): a frame of 4 targets, each
    // re-weighted for every candidate motion and its window's first frame smoothed.
    let mut online: Vec<(OnlineMotion, VecDeque<Cloud>)> = (0..cpu_targets)
        .map(|t| {
            let mut motion = OnlineMotion::new(transition.clone());
            let mut window = VecDeque::new();
            for k in 0..8 {
                let cloud = &run[t][k % frames];
                motion.push(cloud).unwrap();
                window.push_back(cloud.clone());
            }
            (motion, window)
        })
        .collect();
    let mut next = 8;
    group.bench_function("cpu_by_evidence_fixed_lag_8_a_frame_4_targets", |b| {
        b.iter(|| {
            for (t, (motion, window)) in online.iter_mut().enumerate() {
                let cloud = &run[t][next % frames];
                motion.push(cloud).unwrap();
                window.push_back(cloud.clone());
                std::hint::black_box(motion.smooth_first(window.make_contiguous()).unwrap());
                window.pop_front();
            }
            next += 1;
        })
    });
    group.finish();
}

criterion_group!(
    benches,
    bench_smoother,
    bench_annealed_layouts,
    bench_stage_times,
    bench_whole_step,
    bench_resampling_alone,
    bench_plugin_over_gpus
);
criterion_main!(benches);
