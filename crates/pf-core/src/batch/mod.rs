// Index loops mirror the GPU kernels (t, d, m) and read clearer than zipped iterators here.
#![allow(clippy::needless_range_loop)]

//! Batched filtering: T independent targets × M particles in one set of buffers, the layout of
//! the GPU runtime. [`BatchFilter`] is the twin of pf-gpu's filter driver; `stages.rs` holds the
//! twins of its stages (same inputs, same random numbers, f64 accumulation).
//!
//! Layout: states `[(t·D + d)·M + m]`, per-particle values `[t·M + m]`.

use rayon::prelude::*;

use crate::anneal::Annealing;
use crate::error::PfError;
use crate::plugin::CpuModel;
use crate::random::{CounterUniforms, RandomStreams, Stage, counter_gaussian_pair};
use crate::resample::Resampler;

mod config;
mod stages;

pub use config::{
    BatchConfig, BatchShape, Motion, check_target_motion, motion_drift, stage_keys, stage_keys_from,
};

pub use stages::{
    LayerBeta, Normalised, add_drift, best_weighted_means, circular_spread, diffuse,
    frame_log_evidence, normalise_target, update_velocity, weighted_means,
    weighted_means_and_spreads,
};

/// The GPU's wrap into [−π, π): `x − 2π·floor((x + π) / 2π)`. (pf-core's scalar
/// [`crate::estimate::wrap_angle`] gives (−π, π]; the two differ only at −π ≡ π.)
pub fn wrap_angle_floor(x: f32) -> f32 {
    let pi = std::f32::consts::PI;
    x - std::f32::consts::TAU * ((x + pi) / std::f32::consts::TAU).floor()
}

/// A model's dynamics on one particle: `(previous state, standard Gaussian draws, next state)`.
/// A model's own dynamics on the host: one particle's next state (`next`) from its state and `D`
/// standard Gaussian draws (those the GPU's `propagate` gets).
pub type Propagate<'a> = dyn Fn(&[f32], &[f32], &mut [f32]) + Sync + 'a;

/// What one batched step produced, per target.
#[derive(Debug, Clone, PartialEq)]
pub struct BatchReport {
    /// `[t·D + d]`.
    pub estimates: Vec<f32>,
    /// The best-M′ weighted means, `[t·D + d]` (empty when `best` is 0).
    pub best_estimates: Vec<f32>,
    /// The posterior's spread about the weighted means, `[t·D + d]` ([`weighted_means_and_spreads`]).
    pub spreads: Vec<f32>,
    /// Each target's effective sample size after weighing.
    pub ess: Vec<f64>,
    /// Whether each target resampled at the start of the step (of its last annealing layer).
    pub resampled: Vec<bool>,
    /// The exponent each target's last layer weighed with (1 without annealing).
    pub beta: Vec<f32>,
    /// Each target's log evidence of this frame, log p̂(z_t | z_1:t−1) up to the likelihood's
    /// constant ([`frame_log_evidence`]); −∞ when every weight was zero, NaN for a NaN weight.
    pub log_evidence: Vec<f64>,
    /// `Err` for a target whose measurement was degenerate (its weights were left uniform).
    pub status: Vec<Result<(), PfError>>,
}

/// The CPU twin of pf-gpu's filter driver: T targets stepped together, with counter-based random
/// numbers so that it draws exactly what the GPU draws.
pub struct BatchFilter<R> {
    shape: BatchShape,
    resampler: R,
    sigma: Vec<f32>,
    bounds: Option<(Vec<f32>, Vec<f32>)>,
    angular: Vec<bool>,
    /// Resample a target when ESS < threshold·M (`f64::INFINITY`: every step).
    ess_threshold: f64,
    best: usize,
    annealing: Annealing,
    motion: Motion,
    /// Each target's drift `[t·D + d]` (zero until it has two estimates).
    velocity: Vec<f32>,
    /// Each target's last weighted-mean estimate (NaN before its first).
    previous_estimates: Vec<f32>,
    diffusion_keys: Vec<[u32; 2]>,
    resampling_keys: Vec<[u32; 2]>,
    /// The configuration's seed (the targets' random keys derive from it).
    seed: u64,
    /// The states, `[(t·D + d)·M + m]`.
    pub states: Vec<f32>,
    /// The normalised log-weights, `[t·M + m]`.
    pub log_weights: Vec<f32>,
    /// The normalised weights, `[t·M + m]`.
    pub weights: Vec<f64>,
    ess: Vec<f64>,
    /// Each target's log evidence of the frame being stepped (set in layer 0).
    log_evidence: Vec<f64>,
    ancestors: Vec<u32>,
    /// Each particle's ancestor among the previous frame's particles, `[t·M + m]` (every
    /// layer's resampling composed; `smooth::ancestry::NO_ANCESTOR` after a restart).
    lineage: Vec<u32>,
    lineage_scratch: Vec<u32>,
    /// The targets restarted since the last frame (their particles have no ancestors there).
    restarted: Vec<bool>,
    scratch: Vec<f32>,
    log_likelihood: Vec<f32>,
    step: u64,
}
impl<R: Resampler> BatchFilter<R> {
    /// A filter over `initial_states` (layout `[(t·D + d)·M + m]`) with equal weights.
    pub fn new(
        config: &BatchConfig,
        resampler: R,
        initial_states: Vec<f32>,
    ) -> Result<Self, PfError> {
        config.validate()?;
        let shape = config.shape;
        if initial_states.len() != shape.state_len() {
            return Err(PfError::LengthMismatch {
                what: "initial states",
                expected: shape.state_len(),
                got: initial_states.len(),
            });
        }
        let n = shape.particle_len();
        Ok(Self {
            shape,
            resampler,
            sigma: config.sigma.clone(),
            bounds: config.bounds.clone(),
            angular: config.angular.clone(),
            ess_threshold: config.ess_threshold,
            best: config.best,
            annealing: config.annealing.clone(),
            motion: config.motion,
            velocity: vec![0.0; shape.targets * shape.dims],
            previous_estimates: vec![f32::NAN; shape.targets * shape.dims],
            diffusion_keys: stage_keys(config.seed, shape.targets, Stage::Diffusion),
            resampling_keys: stage_keys(config.seed, shape.targets, Stage::Resampling),
            seed: config.seed,
            scratch: vec![0.0; initial_states.len()],
            states: initial_states,
            log_weights: vec![-(shape.particles as f32).ln(); n],
            weights: vec![1.0 / shape.particles as f64; n],
            ess: vec![shape.particles as f64; shape.targets],
            log_evidence: vec![0.0; shape.targets],
            ancestors: vec![0; n],
            lineage: vec![crate::smooth::ancestry::NO_ANCESTOR; n],
            lineage_scratch: vec![0; n],
            restarted: vec![false; shape.targets],
            log_likelihood: vec![0.0; n],
            step: 0,
        })
    }

    /// The batch's shape.
    pub fn shape(&self) -> &BatchShape {
        &self.shape
    }

    /// Makes this batch's targets targets `first ..` of a larger batch split over several
    /// filters: each then draws the random numbers it draws in the whole batch (the twin of
    /// `pf_gpu::GpuFilter::number_targets_from`).
    pub fn number_targets_from(&mut self, first: usize) -> Result<(), PfError> {
        let targets = self.shape.targets;
        if first
            .checked_add(targets)
            .is_none_or(|end| end > u32::MAX as usize)
        {
            return Err(PfError::InvalidConfig(format!(
                "targets {first} and on of a batch: the index of a target is 32 bits"
            )));
        }
        self.diffusion_keys = stage_keys_from(self.seed, first, targets, Stage::Diffusion);
        self.resampling_keys = stage_keys_from(self.seed, first, targets, Stage::Resampling);
        Ok(())
    }

    /// Restarts target `t` from `states` (its `D·M` values, `[d·M + m]`) with equal weights:
    /// a new track in a slot that another target left. The other targets are untouched.
    pub fn reset_target(&mut self, t: usize, states: &[f32]) -> Result<(), PfError> {
        let shape = self.shape;
        if t >= shape.targets {
            return Err(PfError::InvalidConfig(format!(
                "target {t} of a batch of {}",
                shape.targets
            )));
        }
        let block = shape.dims * shape.particles;
        if states.len() != block {
            return Err(PfError::LengthMismatch {
                what: "a target's states",
                expected: block,
                got: states.len(),
            });
        }
        self.states[t * block..(t + 1) * block].copy_from_slice(states);
        let own = t * shape.dims..(t + 1) * shape.dims;
        self.velocity[own.clone()].fill(0.0);
        self.previous_estimates[own].fill(f32::NAN);
        let m = shape.particles;
        let range = t * m..(t + 1) * m;
        self.log_weights[range.clone()].fill(-(m as f32).ln());
        self.weights[range].fill(1.0 / m as f64);
        self.ess[t] = m as f64;
        self.restarted[t] = true;
        Ok(())
    }

    /// Sets target `t` moving, as if its last two estimates had been `estimate − motion` and
    /// `estimate` (`D` values each; angles wrapped, as the drift wraps them): with the
    /// constant-velocity drift its particles drift by `gain · motion` in the next step, and by
    /// the share of the motion estimated after that. A NaN in `estimate` is a value with no
    /// earlier estimate: it drifts by its motion in the next step, then only once it has two
    /// estimates again, as after `reset_target`. For a target started (`reset_target`) on
    /// something already seen to move, such as a face found by two detections apart. The
    /// random walk (no drift) ignores it.
    pub fn set_target_motion(
        &mut self,
        t: usize,
        estimate: &[f32],
        motion: &[f32],
    ) -> Result<(), PfError> {
        check_target_motion(&self.shape, t, estimate, motion)?;
        let gain = self.motion.gain();
        if gain <= 0.0 {
            return Ok(());
        }
        let own = t * self.shape.dims..(t + 1) * self.shape.dims;
        self.velocity[own.clone()].copy_from_slice(&motion_drift(gain, &self.angular, motion));
        self.previous_estimates[own].copy_from_slice(estimate);
        Ok(())
    }

    /// Each particle's ancestor among the previous frame's particles after the last step,
    /// `[t·M + m]`: every annealing layer's resampling composed
    /// (`smooth::ancestry::NO_ANCESTOR` for a target restarted before that step, and before the
    /// first step). What smoothing from the ancestry traces back (`smooth::ancestry`).
    pub fn lineage(&self) -> &[u32] {
        &self.lineage
    }

    /// One step: resample the targets whose ESS is below the threshold, gather, diffuse, measure
    /// with `log_likelihood(t, m, state)`, normalise, estimate.
    pub fn step(
        &mut self,
        log_likelihood: impl Fn(usize, usize, &[f32]) -> f32,
    ) -> Result<BatchReport, PfError> {
        self.step_batched(|shape, states, out| {
            let mut state = vec![0.0f32; shape.dims];
            for t in 0..shape.targets {
                for m in 0..shape.particles {
                    for (d, x) in state.iter_mut().enumerate() {
                        *x = states[shape.state_index(t, d, m)];
                    }
                    out[t * shape.particles + m] = log_likelihood(t, m, &state);
                }
            }
            Ok(())
        })
    }

    /// The same step with the whole measurement in one call: `measure(shape, states, out)` fills
    /// the log-likelihood of every particle, `out[t·M + m]`, from the diffused states (batch
    /// layout). This is the form for likelihoods that evaluate many particles at once (on all
    /// cores, or on GPUs). With annealing it is called once per layer. An error from it is returned
    /// as is: the particles have then been moved but not reweighted.
    pub fn step_batched(
        &mut self,
        measure: impl FnMut(&BatchShape, &[f32], &mut [f32]) -> Result<(), PfError>,
    ) -> Result<BatchReport, PfError> {
        self.step_with(None, measure)
    }

    /// One step of a model plug-in's CPU twin: its own dynamics when `M::PROPAGATES` (fed the
    /// Gaussian draws the GPU's `propagate` gets), else the Gaussian random walk; then its
    /// likelihood against `observations` (one per target), on all cores.
    pub fn step_model<O: Sync, C: Sync, M: CpuModel<O, C>>(
        &mut self,
        model: &M,
        observations: &[O],
        constants: &C,
    ) -> Result<BatchReport, PfError> {
        if observations.len() != self.shape.targets {
            return Err(PfError::InvalidConfig(format!(
                "one observation per target: {} targets, {} observations",
                self.shape.targets,
                observations.len()
            )));
        }
        let propagate =
            |x: &[f32], noise: &[f32], next: &mut [f32]| model.propagate(x, noise, constants, next);
        let dynamics: Option<&Propagate<'_>> = if M::PROPAGATES {
            Some(&propagate)
        } else {
            None
        };
        self.step_with(dynamics, |shape, states, out| {
            measure_plugin(model, observations, constants, shape, states, out);
            Ok(())
        })
    }

    /// Moves every particle with `propagate(x, noise, next)`, noise from the diffusion stream
    /// (the draws of the GPU's `model_propagate`), angles wrapped.
    fn propagate_all(&mut self, propagate: &Propagate<'_>, step: u64) {
        let shape = self.shape;
        let (keys, angular) = (&self.diffusion_keys, &self.angular);
        // One task per target (its D·M block); each particle moved as on one core.
        self.states
            .par_chunks_mut(shape.dims * shape.particles)
            .enumerate()
            .for_each(|(t, block)| {
                let (mut x, mut noise, mut next) = (
                    vec![0.0f32; shape.dims],
                    vec![0.0f32; shape.dims],
                    vec![0.0f32; shape.dims],
                );
                for m in 0..shape.particles {
                    for d in 0..shape.dims {
                        x[d] = block[d * shape.particles + m];
                    }
                    for (pair, draws) in noise.chunks_mut(2).enumerate() {
                        let (z0, z1) = counter_gaussian_pair(keys[t], m as u32, pair as u32, step);
                        draws[0] = z0 as f32;
                        if let Some(second) = draws.get_mut(1) {
                            *second = z1 as f32;
                        }
                    }
                    propagate(&x, &noise, &mut next);
                    for d in 0..shape.dims {
                        block[d * shape.particles + m] = if angular[d] {
                            wrap_angle_floor(next[d])
                        } else {
                            next[d]
                        };
                    }
                }
            });
    }

    /// One step with the model's own dynamics when `propagate` is given (else the Gaussian
    /// random walk) and the whole measurement in one call, as [`Self::step_batched`]: the general
    /// form the other steps and pf-gpu's `Filter` on the CPU engine use.
    pub fn step_with(
        &mut self,
        propagate: Option<&Propagate<'_>>,
        mut measure: impl FnMut(&BatchShape, &[f32], &mut [f32]) -> Result<(), PfError>,
    ) -> Result<BatchReport, PfError> {
        let shape = self.shape;
        let mut last = None;
        for layer in 0..self.annealing.layers {
            last = Some(self.step_layer(layer, propagate, &mut measure)?);
        }
        let (resampled, beta, status) = last
            .ok_or_else(|| PfError::InvalidConfig("annealing needs at least one layer".into()))?;
        let best_estimates = if self.best > 0 {
            best_weighted_means(
                &shape,
                &self.states,
                &self.weights,
                &self.angular,
                self.best,
            )
        } else {
            Vec::new()
        };
        let (estimates, spreads) =
            weighted_means_and_spreads(&shape, &self.states, &self.weights, &self.angular);
        update_velocity(
            self.motion.gain(),
            &self.angular,
            &estimates,
            &mut self.previous_estimates,
            &mut self.velocity,
        );
        Ok(BatchReport {
            spreads,
            estimates,
            best_estimates,
            ess: self.ess.clone(),
            resampled,
            beta,
            log_evidence: self.log_evidence.clone(),
            status,
        })
    }

    /// One layer of a frame (the whole frame without annealing): resample, gather, move, measure,
    /// weigh. Layer 0 resamples by the ESS policy and moves with the dynamics; later layers always
    /// resample and take the random walk scaled by the schedule. Each layer draws with its own
    /// step index. Returns each target's resampled flag, β and status.
    #[allow(clippy::type_complexity)]
    fn step_layer(
        &mut self,
        layer: usize,
        propagate: Option<&Propagate<'_>>,
        measure: &mut impl FnMut(&BatchShape, &[f32], &mut [f32]) -> Result<(), PfError>,
    ) -> Result<(Vec<bool>, Vec<f32>, Vec<Result<(), PfError>>), PfError> {
        let step = self.step;
        self.step += 1;
        // Targets are independent: each stage runs them (or their rows) on all cores, each
        // value computed as on one core.
        let resampled = self.resample_and_gather(layer, step)?;
        self.move_particles(layer, propagate, step);
        measure(&self.shape, &self.states, &mut self.log_likelihood)?;
        let (betas, status) = self.normalise_all(layer);
        Ok((resampled, betas, status))
    }

    /// Resamples the targets due (in layer 0, those whose ESS is below the threshold; in later
    /// layers every target) and gathers their particles by ancestor; which targets resampled.
    fn resample_and_gather(&mut self, layer: usize, step: u64) -> Result<Vec<bool>, PfError> {
        let (m_count, dims) = (self.shape.particles, self.shape.dims);
        let ess_threshold = if layer == 0 {
            self.ess_threshold
        } else {
            f64::INFINITY
        };
        let (resampler, keys, ess) = (&self.resampler, &self.resampling_keys, &self.ess);
        let resampled = (self.ancestors.par_chunks_mut(m_count))
            .zip(self.log_weights.par_chunks_mut(m_count))
            .zip(self.weights.par_chunks(m_count))
            .enumerate()
            .map(|(t, ((ancestors, log_weights), weights))| {
                if ess[t] < ess_threshold * m_count as f64 {
                    let uniforms = CounterUniforms::new(keys[t], step);
                    resampler.resample(weights, &uniforms, ancestors)?;
                    log_weights.fill(-(m_count as f32).ln());
                    Ok(true)
                } else {
                    for (k, a) in ancestors.iter_mut().enumerate() {
                        *a = k as u32;
                    }
                    Ok(false)
                }
            })
            .collect::<Result<Vec<bool>, PfError>>()?;
        // Gather, one (target, dimension) row at a time.
        let (states, ancestors) = (&self.states, &self.ancestors);
        self.scratch
            .par_chunks_mut(m_count)
            .enumerate()
            .for_each(|(row, values)| {
                let t = row / dims;
                let from = &states[row * m_count..(row + 1) * m_count];
                for (value, &a) in values
                    .iter_mut()
                    .zip(&ancestors[t * m_count..(t + 1) * m_count])
                {
                    *value = from[a as usize];
                }
            });
        std::mem::swap(&mut self.states, &mut self.scratch);
        self.compose_lineage(layer);
        Ok(resampled)
    }

    /// The lineage through this layer's resampling: layer 0 starts it from the ancestors (none
    /// for a restarted target), later layers compose theirs into it. Twin of `lineage.wgsl`.
    fn compose_lineage(&mut self, layer: usize) {
        use crate::smooth::ancestry::{NO_ANCESTOR, compose};
        let m = self.shape.particles;
        if layer == 0 {
            for (t, (lineage, ancestors)) in (self.lineage.chunks_mut(m))
                .zip(self.ancestors.chunks(m))
                .enumerate()
            {
                if self.restarted[t] {
                    lineage.fill(NO_ANCESTOR);
                } else {
                    lineage.copy_from_slice(ancestors);
                }
            }
            self.restarted.fill(false);
            return;
        }
        for ((out, lineage), ancestors) in (self.lineage_scratch.chunks_mut(m))
            .zip(self.lineage.chunks(m))
            .zip(self.ancestors.chunks(m))
        {
            compose(lineage, ancestors, out);
        }
        std::mem::swap(&mut self.lineage, &mut self.lineage_scratch);
    }

    /// Moves the particles: the model's dynamics in layer 0 when it has them, else (layer 0's
    /// drift, then) the layer's Gaussian random walk, clamped to the bounds.
    fn move_particles(&mut self, layer: usize, propagate: Option<&Propagate<'_>>, step: u64) {
        let shape = self.shape;
        match propagate {
            Some(propagate) if layer == 0 => self.propagate_all(propagate, step),
            _ => {
                if layer == 0 && self.motion.gain() > 0.0 {
                    add_drift(&shape, &mut self.states, &self.velocity);
                }
                let bounds = self
                    .bounds
                    .as_ref()
                    .map(|(lo, hi)| (lo.as_slice(), hi.as_slice()));
                diffuse(
                    &shape,
                    &mut self.states,
                    &self.annealing.layer_sigma(layer, &self.sigma),
                    self.annealing.sigma_scale(layer),
                    bounds,
                    &self.angular,
                    &self.diffusion_keys,
                    step,
                );
            }
        }
    }

    /// Weighs every target by the layer's β rule and normalises; each target's β and status.
    /// Layer 0 also takes each target's log evidence of the frame, before any tempering.
    fn normalise_all(&mut self, layer: usize) -> (Vec<f32>, Vec<Result<(), PfError>>) {
        let m_count = self.shape.particles;
        if layer == 0 {
            self.log_evidence = (self.log_weights.par_chunks(m_count))
                .zip(self.log_likelihood.par_chunks(m_count))
                .map(|(prior, log_likelihood)| frame_log_evidence(prior, log_likelihood))
                .collect();
        }
        let rule = LayerBeta::of_layer(&self.annealing, layer);
        let results: Vec<Result<Normalised, PfError>> = (self.log_weights.par_chunks_mut(m_count))
            .zip(self.log_likelihood.par_chunks(m_count))
            .zip(self.weights.par_chunks_mut(m_count))
            .map(|((log_weights, log_likelihood), weights)| {
                normalise_target(log_weights, log_likelihood, weights, rule)
            })
            .collect();
        let mut status = Vec::with_capacity(self.shape.targets);
        let mut betas = Vec::with_capacity(self.shape.targets);
        for (t, result) in results.into_iter().enumerate() {
            self.ess[t] = result.as_ref().map_or(m_count as f64, |n| n.ess);
            betas.push(result.as_ref().map_or(0.0, |n| n.beta));
            status.push(result.map(|_| ()));
        }
        (betas, status)
    }
}

/// Initial clouds `mean_t + σ ⊙ n` for every target (n from each target's init stream), in the
/// The twin's log-likelihood of every particle of `states` (`[(t·D + d)·M + m]`) against each
/// target's observation, into `out[t·M + m]`, targets on all cores: the CPU measure of a plug-in
/// (`BatchFilter::step_model`, and `pf_gpu::model::Plugin` on the CPU engine). `observations`
/// holds one observation per target (checked by the callers).
pub fn measure_plugin<O: Sync, C: Sync, M: CpuModel<O, C>>(
    model: &M,
    observations: &[O],
    constants: &C,
    shape: &BatchShape,
    states: &[f32],
    out: &mut [f32],
) {
    out.par_chunks_mut(shape.particles)
        .enumerate()
        .for_each(|(t, row)| {
            let mut x = vec![0.0f32; shape.dims];
            for (m, value) in row.iter_mut().enumerate() {
                for (d, v) in x.iter_mut().enumerate() {
                    *v = states[shape.state_index(t, d, m)];
                }
                *value = model.log_likelihood(&x, &observations[t], constants);
            }
        });
}

/// batch layout. `means` is `[t·D + d]`.
pub fn gaussian_clouds(shape: &BatchShape, seed: u64, means: &[f32], sigma: &[f32]) -> Vec<f32> {
    let streams = RandomStreams::new(seed);
    let mut states = vec![0.0; shape.state_len()];
    for t in 0..shape.targets {
        let mut rng = streams.stream(t as u32, Stage::Init);
        for m in 0..shape.particles {
            for d in 0..shape.dims {
                states[shape.state_index(t, d, m)] =
                    means[t * shape.dims + d] + sigma[d] * rng.gaussian_f32();
            }
        }
    }
    states
}
