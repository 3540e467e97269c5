//! The Condensation loop: select, diffuse, measure.

use nalgebra::SVector;

use crate::error::PfError;
use crate::estimate::{self, StateSpace};
use crate::model::{Dynamics, Likelihood};
use crate::particles::ParticleSet;
use crate::random::{RandomStream, RandomStreams, Stage};
use crate::resample::Resampler;
use crate::weights;

/// When the filter resamples.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ResamplePolicy {
    /// Every step (classic Condensation / bootstrap filter).
    EveryStep,
    /// Only when ESS / N falls below the given fraction in (0, 1].
    EssBelow(f64),
}

/// Everything but the models that a filter needs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FilterConfig<const D: usize> {
    /// Particles N.
    pub particles: usize,
    /// When to resample.
    pub policy: ResamplePolicy,
    /// The run's seed: every random number of this filter derives from it and `target`.
    pub seed: u64,
    /// Which target this filter tracks; selects its own random streams.
    pub target: u32,
    /// Which state dimensions are angles.
    pub space: StateSpace<D>,
}

impl<const D: usize> FilterConfig<D> {
    /// `particles` particles, seed `seed`, resampling when the ESS falls under N/2, no angles.
    pub fn new(particles: usize, seed: u64) -> Self {
        Self {
            particles,
            policy: ResamplePolicy::EveryStep,
            seed,
            target: 0,
            space: StateSpace::euclidean(),
        }
    }

    fn validate(&self) -> Result<(), PfError> {
        if self.particles == 0 {
            return Err(PfError::EmptyParticleSet);
        }
        if let ResamplePolicy::EssBelow(f) = self.policy
            && !(f > 0.0 && f <= 1.0)
        {
            return Err(PfError::InvalidConfig(format!(
                "the ESS threshold must be a fraction in (0, 1], got {f}"
            )));
        }
        Ok(())
    }
}

/// What one step produced.
#[derive(Debug, Clone, PartialEq)]
pub struct StepReport<const D: usize> {
    /// 0 for the first step.
    pub step: u64,
    /// Weighted mean of the particles after measuring.
    pub estimate: SVector<f32, D>,
    /// Effective sample size after measuring, in [1, N].
    pub ess: f64,
    /// Whether this step began by resampling.
    pub resampled: bool,
    /// log Σ_i w_i·p(z | x_i): the log marginal likelihood of this observation, up to the
    /// likelihood's constant.
    pub log_evidence: f64,
}

/// A particle filter for one target.
pub struct ParticleFilter<const D: usize, M, R> {
    config: FilterConfig<D>,
    dynamics: M,
    resampler: R,
    particles: ParticleSet<D>,
    /// Normalised weights of the last measured step (uniform before the first).
    weights: Vec<f64>,
    log_likelihoods: Vec<f32>,
    ancestors: Vec<u32>,
    streams: RandomStreams,
    diffusion: RandomStream,
    recovery: RandomStream,
    step: u64,
    resample_due: bool,
    last_estimate: SVector<f32, D>,
}

impl<const D: usize, M: Dynamics<D>, R: Resampler> ParticleFilter<D, M, R> {
    /// A filter whose particles start as `mean + σ ⊙ n`, n standard normal (the target's init
    /// stream).
    pub fn new(
        config: FilterConfig<D>,
        dynamics: M,
        resampler: R,
        mean: &SVector<f32, D>,
        sigma: &SVector<f32, D>,
    ) -> Result<Self, PfError> {
        config.validate()?;
        check_sigma(sigma)?;
        let mut init = RandomStreams::new(config.seed).stream(config.target, Stage::Init);
        let particles = ParticleSet::from_fn(config.particles, |_| {
            gaussian_around(mean, sigma, &config.space, &mut init)
        })?;
        Self::from_particles(config, dynamics, resampler, particles)
    }

    /// A filter over a given particle set (its log-weights are kept; `config.particles` must match).
    pub fn from_particles(
        config: FilterConfig<D>,
        dynamics: M,
        resampler: R,
        particles: ParticleSet<D>,
    ) -> Result<Self, PfError> {
        config.validate()?;
        if particles.len() != config.particles {
            return Err(PfError::LengthMismatch {
                what: "initial particle set",
                expected: config.particles,
                got: particles.len(),
            });
        }
        let n = particles.len();
        let mut weights = vec![0.0; n];
        weights::normalise(particles.log_weights(), &mut weights)?;
        let streams = RandomStreams::new(config.seed);
        let last_estimate = estimate::weighted_mean(&particles, &weights, &config.space)?;
        Ok(Self {
            diffusion: streams.stream(config.target, Stage::Diffusion),
            recovery: streams.stream(config.target, Stage::Recovery),
            streams,
            config,
            dynamics,
            resampler,
            particles,
            weights,
            log_likelihoods: vec![0.0; n],
            ancestors: vec![0; n],
            step: 0,
            resample_due: false,
            last_estimate,
        })
    }

    /// One Condensation step: select (when due), diffuse, measure, normalise, estimate.
    ///
    /// On a degenerate measurement (every weight zero, a NaN or +∞ log-weight) it returns the
    /// error and leaves the particles diffused with equal weights; call [`Self::recover`] to
    /// re-initialise around the last good estimate, or step again.
    pub fn step(&mut self, likelihood: &impl Likelihood<D>) -> Result<StepReport<D>, PfError> {
        let step = self.step;
        self.step += 1;

        let resampled = self.resample_due;
        if resampled {
            let uniforms =
                self.streams
                    .counter_uniforms(self.config.target, Stage::Resampling, step);
            self.resampler
                .resample(&self.weights, &uniforms, &mut self.ancestors)?;
            self.particles.select(&self.ancestors)?;
        }

        for i in 0..self.particles.len() {
            let mut x = self.particles.state(i);
            self.dynamics.propagate(&mut x, &mut self.diffusion);
            self.config.space.wrap(&mut x);
            self.particles.set_state(i, &x);
        }

        self.likelihoods_into_log_weights(likelihood);
        let lse = match weights::normalise(self.particles.log_weights(), &mut self.weights) {
            Ok(lse) => lse,
            Err(err) => {
                self.particles.reset_weights();
                self.weights.fill(1.0 / self.particles.len() as f64);
                self.resample_due = false;
                return Err(err);
            }
        };
        // Keep the stored log-weights normalised so that they never drift toward ±∞.
        for lw in self.particles.log_weights_mut() {
            *lw = lse.normalised_log(*lw) as f32;
        }

        let ess = weights::effective_sample_size(&self.weights);
        let estimate = estimate::weighted_mean(&self.particles, &self.weights, &self.config.space)?;
        self.last_estimate = estimate;
        self.resample_due = match self.config.policy {
            ResamplePolicy::EveryStep => true,
            ResamplePolicy::EssBelow(fraction) => ess < fraction * self.particles.len() as f64,
        };
        Ok(StepReport {
            step,
            estimate,
            ess,
            resampled,
            log_evidence: lse.log_sum,
        })
    }

    fn likelihoods_into_log_weights(&mut self, likelihood: &impl Likelihood<D>) {
        likelihood.log_likelihoods(&self.particles, &mut self.log_likelihoods);
        for (lw, &ll) in self
            .particles
            .log_weights_mut()
            .iter_mut()
            .zip(&self.log_likelihoods)
        {
            *lw += ll;
        }
    }

    /// Re-initialises every particle around the last good estimate, `estimate + σ ⊙ n`, with equal
    /// weights (the recovery after a failed step).
    pub fn recover(&mut self, sigma: &SVector<f32, D>) -> Result<(), PfError> {
        check_sigma(sigma)?;
        let centre = self.last_estimate;
        for i in 0..self.particles.len() {
            let x = gaussian_around(&centre, sigma, &self.config.space, &mut self.recovery);
            self.particles.set_state(i, &x);
        }
        self.particles.reset_weights();
        self.weights.fill(1.0 / self.particles.len() as f64);
        self.resample_due = false;
        Ok(())
    }

    /// The current particles and log-weights.
    pub fn particles(&self) -> &ParticleSet<D> {
        &self.particles
    }

    /// The normalised weights of the last measured step.
    pub fn weights(&self) -> &[f64] {
        &self.weights
    }

    /// The configuration the filter was built with.
    pub fn config(&self) -> &FilterConfig<D> {
        &self.config
    }

    /// The number of steps taken so far.
    pub fn steps_taken(&self) -> u64 {
        self.step
    }

    /// The weighted mean of the last successful step (of the initial cloud before any).
    pub fn last_estimate(&self) -> &SVector<f32, D> {
        &self.last_estimate
    }

    /// The weighted mean of the `best` heaviest particles (eq. 14 of the face paper).
    pub fn best_estimate(&self, best: usize) -> Result<SVector<f32, D>, PfError> {
        estimate::best_weighted_mean(&self.particles, &self.weights, best, &self.config.space)
    }

    /// The heaviest particle.
    pub fn max_weight_estimate(&self) -> Result<SVector<f32, D>, PfError> {
        estimate::max_weight(&self.particles, &self.weights)
    }
}

fn check_sigma<const D: usize>(sigma: &SVector<f32, D>) -> Result<(), PfError> {
    match (0..D).find(|&d| !(sigma[d].is_finite() && sigma[d] >= 0.0)) {
        Some(d) => Err(PfError::InvalidConfig(format!(
            "spread of dimension {d} is {}, expected a finite value >= 0",
            sigma[d]
        ))),
        None => Ok(()),
    }
}

fn gaussian_around<const D: usize>(
    mean: &SVector<f32, D>,
    sigma: &SVector<f32, D>,
    space: &StateSpace<D>,
    stream: &mut RandomStream,
) -> SVector<f32, D> {
    let mut x = SVector::from_fn(|d, _| mean[d] + sigma[d] * stream.gaussian_f32());
    space.wrap(&mut x);
    x
}
