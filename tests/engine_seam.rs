//! The engine seam (`pf_gpu::engine::FilterEngine`): one set of checks written once and run on
//! every engine (cubecl's `testgen` style) — a step that follows its observations, a target
//! reset, the particles read back — and the two engines against each other on the same seed.
//!
//! Bounds. Four 7-D targets, 512 particles, the toy Gaussian likelihood (σ as below) around an
//! observation that moves 1 px a step (the filter's diffusion σ is 1 px): after 20 steps the test
//! asks each target's estimate to be within 2 px of its observation — one observation σ — on
//! both engines; after one step the two engines' estimates must agree within 1e-3 relative (the
//! same random numbers; f32 sums on the GPU).

mod common;

use std::ops::Range;

use pf_core::batch::{BatchConfig, BatchShape, gaussian_clouds};
use pf_gpu::engine::{EngineReport, FilterEngine};
use pf_gpu::toy::ToyGaussianLikelihood;
use pf_gpu::{GpuError, GpuLikelihood};

const D: usize = 7;
const TARGETS: usize = 4;
const PARTICLES: usize = 512;
const SIGMA: [f32; D] = [2.0, 2.0, 0.05, 0.1, 0.1, 0.1, 0.05];
const ANGLES: [bool; D] = [false, false, false, true, true, true, false];

fn config() -> BatchConfig {
    config_for(TARGETS)
}

fn config_for(targets: usize) -> BatchConfig {
    BatchConfig {
        shape: BatchShape::new(targets, PARTICLES, D).unwrap(),
        seed: 9,
        sigma: vec![1.0, 1.0, 0.01, 0.02, 0.02, 0.02, 0.01],
        bounds: None,
        angular: ANGLES.to_vec(),
        ess_threshold: f64::INFINITY,
        best: 0,
        annealing: Default::default(),
        motion: Default::default(),
    }
}

fn observation(t: usize, step: usize) -> [f32; D] {
    [10.0 * t as f32 + step as f32, 5.0, 1.0, 0.1, -0.2, 0.0, 1.0]
}

/// An engine with its GPU likelihood (the toy's hand-written kernel, prepared once), for the
/// targets `targets` of the whole batch of [`TARGETS`].
struct Rig {
    engine: FilterEngine,
    toy: Option<ToyGaussianLikelihood>,
    targets: Range<usize>,
}

fn start() -> Vec<f32> {
    let means: Vec<f32> = (0..TARGETS).flat_map(|t| observation(t, 0)).collect();
    gaussian_clouds(&config().shape, 3, &means, &SIGMA)
}

/// The whole batch's starting clouds of `targets`.
fn start_of(targets: &Range<usize>) -> Vec<f32> {
    let block = D * PARTICLES;
    start()[targets.start * block..targets.end * block].to_vec()
}

fn cpu() -> Option<Rig> {
    cpu_part(0..TARGETS)
}

/// The CPU engine for `targets` of the whole batch, numbered as in the whole.
fn cpu_part(targets: Range<usize>) -> Option<Rig> {
    let mut engine = FilterEngine::cpu(&config_for(targets.len()), start_of(&targets)).unwrap();
    engine.number_targets_from(targets.start).unwrap();
    Some(Rig {
        engine,
        toy: None,
        targets,
    })
}

fn gpu() -> Option<Rig> {
    gpu_part(0..TARGETS)
}

/// The GPU engine for `targets` of the whole batch, numbered as in the whole.
fn gpu_part(targets: Range<usize>) -> Option<Rig> {
    let ctx = common::gpu_context("engine seam on the GPU")?;
    let mut toy = ToyGaussianLikelihood::new(&ctx, targets.len(), &SIGMA).unwrap();
    let config = config_for(targets.len());
    let mut engine = FilterEngine::gpu(ctx, &config, &start_of(&targets)).unwrap();
    engine.number_targets_from(targets.start).unwrap();
    let (ctx, inputs) = engine.likelihood_inputs().unwrap();
    toy.prepare(ctx, &inputs).unwrap();
    Some(Rig {
        engine,
        toy: Some(toy),
        targets,
    })
}

impl Rig {
    /// One step against the observations of `step`, the same likelihood on either engine.
    fn step(&mut self, step: usize) -> EngineReport {
        let observed: Vec<f32> = (self.targets.clone())
            .flat_map(|t| observation(t, step))
            .collect();
        if let (Some(toy), Some(ctx)) = (&self.toy, self.engine.context()) {
            toy.upload_observations(ctx, &observed).unwrap();
        }
        let on_gpu: &dyn GpuLikelihood = match &self.toy {
            Some(toy) => toy,
            None => &pf_gpu::NoLikelihood,
        };
        let measure = |shape: &BatchShape, states: &[f32], out: &mut [f32]| {
            for t in 0..shape.targets {
                for m in 0..shape.particles {
                    let mut sum = 0.0;
                    for d in 0..D {
                        let mut diff = states[shape.state_index(t, d, m)] - observed[t * D + d];
                        if ANGLES[d] {
                            diff = pf_core::batch::wrap_angle_floor(diff);
                        }
                        sum += (diff / SIGMA[d]).powi(2);
                    }
                    out[t * shape.particles + m] = -0.5 * sum;
                }
            }
            Ok::<(), GpuError>(())
        };
        self.engine.step(measure, on_gpu).unwrap()
    }
}

fn follows_its_observations(rig: Option<Rig>) {
    let Some(mut rig) = rig else { return };
    let mut report = rig.step(0);
    for step in 1..=20 {
        report = rig.step(step);
    }
    assert_eq!(report.status.len(), TARGETS);
    assert!(report.status.iter().all(|s| s.is_ok()));
    for t in 0..TARGETS {
        let x = report.point_estimates()[t * D];
        let expected = observation(t, 20)[0];
        assert!((x - expected).abs() < 2.0, "target {t}: {x} vs {expected}");
        assert!(report.ess[t] >= 1.0 && report.ess[t] <= PARTICLES as f64 + 1e-3);
    }
}

fn resets_one_target_and_reads_the_particles(rig: Option<Rig>) {
    let Some(mut rig) = rig else { return };
    rig.step(0);
    let cloud: Vec<f32> = (0..D * PARTICLES).map(|i| i as f32 * 1e-3).collect();
    rig.engine.reset_target(2, &cloud).unwrap();
    let (shape, states, log_weights) = rig.engine.particles().unwrap();
    assert_eq!(shape, config().shape);
    for d in 0..D {
        for m in 0..PARTICLES {
            assert_eq!(states[shape.state_index(2, d, m)], cloud[d * PARTICLES + m]);
        }
    }
    let uniform = -(PARTICLES as f32).ln();
    let slot = &log_weights[2 * PARTICLES..3 * PARTICLES];
    assert!(slot.iter().all(|w| (w - uniform).abs() < 1e-5));
    assert!(rig.engine.reset_target(TARGETS, &cloud).is_err());
    assert!(rig.engine.reset_target(0, &cloud[1..]).is_err());
}

/// A batch split in two engines, each numbering its targets from its first: every target steps
/// as in the whole batch, bit for bit (the engine's several-GPU split, and its CPU twin).
fn a_split_batch_steps_as_the_whole(part: fn(Range<usize>) -> Option<Rig>) {
    let (Some(mut whole), Some(mut first), Some(mut second)) =
        (part(0..TARGETS), part(0..1), part(1..TARGETS))
    else {
        return;
    };
    for step in 0..5 {
        let want = whole.step(step);
        let (a, b) = (first.step(step), second.step(step));
        let got: Vec<u32> = [a.estimates, b.estimates]
            .concat()
            .iter()
            .map(|x| x.to_bits())
            .collect();
        let want: Vec<u32> = want.estimates.iter().map(|x| x.to_bits()).collect();
        assert_eq!(got, want, "step {step}");
    }
}

/// One test per (check, engine).
macro_rules! every_engine {
    ($($check:ident),*) => {
        mod on_cpu { $(#[test] fn $check() { super::$check(super::cpu()) })* }
        mod on_gpu { $(#[test] fn $check() { super::$check(super::gpu()) })* }
    };
}

every_engine!(
    follows_its_observations,
    resets_one_target_and_reads_the_particles
);

mod on_cpu_split {
    #[test]
    fn a_split_batch_steps_as_the_whole() {
        super::a_split_batch_steps_as_the_whole(super::cpu_part)
    }
}

mod on_gpu_split {
    #[test]
    fn a_split_batch_steps_as_the_whole() {
        super::a_split_batch_steps_as_the_whole(super::gpu_part)
    }
}

#[test]
fn the_engines_agree_on_the_same_seed() {
    let (Some(mut cpu), Some(mut gpu)) = (cpu(), gpu()) else {
        return;
    };
    let (a, b) = (cpu.step(0), gpu.step(0));
    for (x, y) in a.estimates.iter().zip(&b.estimates) {
        assert!((x - y).abs() <= 1e-3 * x.abs().max(1.0), "{x} vs {y}");
    }
}
