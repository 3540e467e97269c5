//! The engine seam (`pf_gpu::engine::Filter` over a `Model` with a CPU twin and a GPU side):
//! one set of checks written once and run on every engine (cubecl's `testgen` style) — a step that follows its observations, a target
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
use pf_core::resample::ResamplerKind;
use pf_gpu::engine::{EngineReport, Filter, Model};
use pf_gpu::toy::ToyGaussianLikelihood;
use pf_gpu::{GpuContext, GpuError, GpuLikelihood, GpuResampler, LikelihoodInputs};

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

/// The toy Gaussian likelihood as a model: its CPU twin below, its GPU side the toy's
/// hand-written kernel. A frame is each target's observation, `[t·D + d]`.
struct Toy {
    gpu: Option<ToyGaussianLikelihood>,
}

impl Model for Toy {
    type Frame<'f> = [f32];
    type Error = GpuError;

    fn prepare_gpu(
        &mut self,
        ctx: &GpuContext,
        inputs: &LikelihoodInputs<'_>,
    ) -> Result<(), GpuError> {
        match &mut self.gpu {
            Some(toy) => toy.prepare(ctx, inputs),
            None => Ok(()),
        }
    }

    fn upload_frame(
        &mut self,
        ctx: &GpuContext,
        observed: &[f32],
    ) -> Result<&dyn GpuLikelihood, GpuError> {
        let toy = (self.gpu.as_ref()).ok_or(GpuError::InvalidConfig("no GPU side".into()))?;
        toy.upload_observations(ctx, observed)?;
        Ok(toy)
    }

    fn measure_on_cpu(
        &self,
        observed: &[f32],
        shape: &BatchShape,
        states: &[f32],
        out: &mut [f32],
    ) -> Result<(), GpuError> {
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
        Ok(())
    }
}

/// The toy model's filter on one engine, for the targets `targets` of the whole batch of
/// [`TARGETS`].
struct Rig {
    filter: Filter<Toy>,
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
    let config = config_for(targets.len());
    let toy = Toy { gpu: None };
    let mut filter =
        Filter::on_cpu(&config, ResamplerKind::Systematic, start_of(&targets), toy).unwrap();
    filter.number_targets_from(targets.start).unwrap();
    Some(Rig { filter, targets })
}

fn gpu() -> Option<Rig> {
    gpu_part(0..TARGETS)
}

/// The GPU engine for `targets` of the whole batch, numbered as in the whole.
fn gpu_part(targets: Range<usize>) -> Option<Rig> {
    let ctx = common::gpu_context("engine seam on the GPU")?;
    let toy = Toy {
        gpu: Some(ToyGaussianLikelihood::new(&ctx, targets.len(), &SIGMA).unwrap()),
    };
    let config = config_for(targets.len());
    let start = start_of(&targets);
    let mut filter = Filter::on_gpu(ctx, &config, GpuResampler::Systematic, &start, toy).unwrap();
    filter.number_targets_from(targets.start).unwrap();
    Some(Rig { filter, targets })
}

impl Rig {
    /// One step against the observations of `step`, the same model on either engine.
    fn step(&mut self, step: usize) -> EngineReport {
        let observed: Vec<f32> = (self.targets.clone())
            .flat_map(|t| observation(t, step))
            .collect();
        self.filter.step(&observed).unwrap()
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
    rig.filter.reset_target(2, &cloud).unwrap();
    let shape = rig.filter.shape();
    let (states, log_weights) = rig.filter.particles().unwrap();
    assert_eq!(shape, config().shape);
    for d in 0..D {
        for m in 0..PARTICLES {
            assert_eq!(states[shape.state_index(2, d, m)], cloud[d * PARTICLES + m]);
        }
    }
    let uniform = -(PARTICLES as f32).ln();
    let slot = &log_weights[2 * PARTICLES..3 * PARTICLES];
    assert!(slot.iter().all(|w| (w - uniform).abs() < 1e-5));
    assert!(rig.filter.reset_target(TARGETS, &cloud).is_err());
    assert!(rig.filter.reset_target(0, &cloud[1..]).is_err());
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
