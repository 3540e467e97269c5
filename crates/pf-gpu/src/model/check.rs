//! The test a model's author runs: the GPU model against its CPU twin on given particles, with
//! the tolerance of the project's own property tests (relative 1e-4, or absolute 1e-5 near zero).

use std::fmt;

use bytemuck::Pod;
use pf_core::Stage;
use pf_core::batch::{BatchConfig, BatchShape, stage_keys, wrap_angle_floor};
use pf_core::plugin::CpuModel;
use pf_core::random::counter_gaussian;

use super::{ModelFilter, ModelSource};
use crate::context::GpuContext;
use crate::error::GpuError;
use crate::filter::{GpuResampler, GpuStage};

/// Relative tolerance of a GPU value against its CPU twin.
pub const RELATIVE_TOLERANCE: f64 = 1e-4;
/// Absolute tolerance near zero.
pub const ABSOLUTE_TOLERANCE: f64 = 1e-5;

/// How far a GPU value may be from its CPU twin `cpu` before anything else a test allows for
/// (the project's tolerance policy: [`RELATIVE_TOLERANCE`] of the value, or [`ABSOLUTE_TOLERANCE`]
/// near zero). A test that bounds a sum adds what its inputs' rounding can move it by.
pub fn tolerance(cpu: f64) -> f64 {
    (RELATIVE_TOLERANCE * cpu.abs()).max(ABSOLUTE_TOLERANCE)
}

/// Whether `gpu` agrees with `cpu` within the tolerance (NaN agrees only with NaN).
pub fn agrees(gpu: f64, cpu: f64) -> bool {
    if gpu.is_nan() || cpu.is_nan() {
        return gpu.is_nan() && cpu.is_nan();
    }
    if gpu.is_infinite() || cpu.is_infinite() {
        return gpu == cpu;
    }
    (gpu - cpu).abs() <= tolerance(cpu)
}

/// One value that disagrees.
#[derive(Debug, Clone, PartialEq)]
pub struct Mismatch {
    /// "log_likelihood" or "propagate, dimension d".
    pub what: String,
    /// The target.
    pub target: usize,
    /// The particle.
    pub particle: usize,
    /// The GPU's value.
    pub gpu: f64,
    /// The CPU twin's value.
    pub cpu: f64,
}

/// What [`check_against_cpu`] compared.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelCheck {
    /// Particles compared (all targets).
    pub particles: usize,
    /// Whether the dynamics were compared too (both sides define them).
    pub checked_propagate: bool,
    /// Every value out of tolerance.
    pub mismatches: Vec<Mismatch>,
}

impl ModelCheck {
    /// Whether every value agreed.
    pub fn passed(&self) -> bool {
        self.mismatches.is_empty()
    }
}

impl fmt::Display for ModelCheck {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} particles{}: {} mismatches",
            self.particles,
            if self.checked_propagate {
                ", log-likelihood and dynamics"
            } else {
                ", log-likelihood"
            },
            self.mismatches.len()
        )?;
        for m in self.mismatches.iter().take(5) {
            write!(
                f,
                "\n  {} of target {} particle {}: GPU {} vs CPU {}",
                m.what, m.target, m.particle, m.gpu, m.cpu
            )?;
        }
        Ok(())
    }
}

/// The particles, observations and constants of one check.
pub struct CheckInputs<'a, O, C> {
    /// Targets × particles × dimensions.
    pub shape: BatchShape,
    /// `[(t·D + d)·M + m]`.
    pub states: &'a [f32],
    /// One observation per target.
    pub observations: &'a [O],
    /// The model's constants.
    pub constants: &'a C,
    /// Which dimensions are angles (wrapped after `propagate`).
    pub angular: &'a [bool],
    /// The seed of the filter's streams (the propagation noise).
    pub seed: u64,
}

/// Runs the model's measure kernel (and its `propagate`, when both sides define one) on the
/// given particles and compares every value with the CPU twin's, drawing the same noise.
pub fn check_against_cpu<O: Pod, C: Pod, M: CpuModel<O, C>>(
    ctx: &GpuContext,
    source: ModelSource<'_>,
    cpu: &M,
    inputs: &CheckInputs<'_, O, C>,
) -> Result<ModelCheck, GpuError> {
    let shape = inputs.shape;
    let config = BatchConfig {
        shape,
        seed: inputs.seed,
        sigma: vec![0.0; shape.dims],
        bounds: None,
        angular: inputs.angular.to_vec(),
        ess_threshold: f64::INFINITY,
        best: 0,
        annealing: Default::default(),
        motion: Default::default(),
    };
    let mut filter = ModelFilter::new(
        ctx,
        &config,
        GpuResampler::Systematic,
        inputs.states,
        source,
        inputs.constants,
    )?;
    if filter.model().propagates() != M::PROPAGATES {
        return Err(GpuError::InvalidConfig(format!(
            "model {}: the WGSL {} propagate but the CPU twin's PROPAGATES is {}",
            source.name,
            if filter.model().propagates() {
                "defines"
            } else {
                "does not define"
            },
            M::PROPAGATES
        )));
    }
    filter.model().set_observations(ctx, inputs.observations)?;
    let mut mismatches = compare_log_likelihoods(&mut filter, cpu, inputs)?;
    if M::PROPAGATES {
        mismatches.extend(compare_propagation(&mut filter, cpu, inputs)?);
    }
    Ok(ModelCheck {
        particles: shape.targets * shape.particles,
        checked_propagate: M::PROPAGATES,
        mismatches,
    })
}

/// The GPU driver of a model's filter, to run one stage at a time.
fn on_gpu<O: Pod, C: Pod>(
    filter: &mut ModelFilter<O, C>,
) -> Result<(&GpuContext, &mut crate::GpuFilter, &super::WgslModel<O, C>), GpuError> {
    filter
        .gpu_parts()
        .ok_or_else(|| GpuError::InvalidConfig("a model check runs on the GPU engine".into()))
}

/// One particle's state from the batch layout.
fn particle(shape: &BatchShape, states: &[f32], t: usize, m: usize) -> Vec<f32> {
    (0..shape.dims)
        .map(|d| states[shape.state_index(t, d, m)])
        .collect()
}

/// The measure kernel on the given particles against the twin's `log_likelihood`.
fn compare_log_likelihoods<O: Pod, C: Pod, M: CpuModel<O, C>>(
    filter: &mut ModelFilter<O, C>,
    cpu: &M,
    inputs: &CheckInputs<'_, O, C>,
) -> Result<Vec<Mismatch>, GpuError> {
    let shape = inputs.shape;
    let gpu = {
        let (ctx, gpu_filter, model) = on_gpu(filter)?;
        gpu_filter.run_stages(ctx, &[GpuStage::Likelihood], model)?;
        gpu_filter.download_log_likelihood(ctx)?
    };
    let mut mismatches = Vec::new();
    for t in 0..shape.targets {
        for m in 0..shape.particles {
            let x = particle(&shape, inputs.states, t, m);
            let cpu_value =
                f64::from(cpu.log_likelihood(&x, &inputs.observations[t], inputs.constants));
            let gpu_value = f64::from(gpu[t * shape.particles + m]);
            if !agrees(gpu_value, cpu_value) {
                mismatches.push(Mismatch {
                    what: "log_likelihood".into(),
                    target: t,
                    particle: m,
                    gpu: gpu_value,
                    cpu: cpu_value,
                });
            }
        }
    }
    Ok(mismatches)
}

/// The propagate kernel at one step against the twin's `propagate` fed the same draws.
fn compare_propagation<O: Pod, C: Pod, M: CpuModel<O, C>>(
    filter: &mut ModelFilter<O, C>,
    cpu: &M,
    inputs: &CheckInputs<'_, O, C>,
) -> Result<Vec<Mismatch>, GpuError> {
    let shape = inputs.shape;
    let step = 7;
    let moved = {
        let (ctx, gpu_filter, model) = on_gpu(filter)?;
        gpu_filter.set_step(step);
        gpu_filter.run_stages(ctx, &[GpuStage::Diffuse], model)?;
        gpu_filter.download_states(ctx)?
    };
    let keys = stage_keys(inputs.seed, shape.targets, Stage::Diffusion);
    let mut next = vec![0.0f32; shape.dims];
    let mut mismatches = Vec::new();
    for t in 0..shape.targets {
        for m in 0..shape.particles {
            let x = particle(&shape, inputs.states, t, m);
            let noise: Vec<f32> = (0..shape.dims)
                .map(|d| counter_gaussian(keys[t], m as u32, d as u32, step) as f32)
                .collect();
            cpu.propagate(&x, &noise, inputs.constants, &mut next);
            for d in 0..shape.dims {
                let cpu_value = if inputs.angular.get(d) == Some(&true) {
                    wrap_angle_floor(next[d])
                } else {
                    next[d]
                };
                let gpu_value = moved[shape.state_index(t, d, m)];
                if !agrees(f64::from(gpu_value), f64::from(cpu_value)) {
                    mismatches.push(Mismatch {
                        what: format!("propagate, dimension {d}"),
                        target: t,
                        particle: m,
                        gpu: f64::from(gpu_value),
                        cpu: f64::from(cpu_value),
                    });
                }
            }
        }
    }
    Ok(mismatches)
}
