//! A batch's shape and configuration (`BatchShape`, `BatchConfig`, `Motion`), and the
//! per-target random keys every stage draws from (`stage_keys`, `stage_keys_from`).

use crate::anneal::Annealing;
use crate::error::PfError;
use crate::random::{RandomStreams, Stage, key_words};

/// The shape of a batch.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BatchShape {
    /// Targets T, each an independent filter.
    pub targets: usize,
    /// Particles per target M.
    pub particles: usize,
    /// State dimensions D.
    pub dims: usize,
}

impl BatchShape {
    /// A shape of `targets` × `particles` × `dims` (each at least 1, the total within `u32`).
    pub fn new(targets: usize, particles: usize, dims: usize) -> Result<Self, PfError> {
        if targets == 0 || particles == 0 || dims == 0 {
            return Err(PfError::InvalidConfig(format!(
                "a batch needs at least one target, particle and dimension (got {targets} x {particles} x {dims})"
            )));
        }
        if targets
            .checked_mul(particles)
            .and_then(|n| n.checked_mul(dims))
            .is_none_or(|n| n > u32::MAX as usize)
        {
            return Err(PfError::InvalidConfig(format!(
                "{targets} x {particles} x {dims} values do not fit 32-bit indices"
            )));
        }
        Ok(Self {
            targets,
            particles,
            dims,
        })
    }

    /// Where component `d` of particle `m` of target `t` lives: `(t·D + d)·M + m`.
    pub fn state_index(&self, t: usize, d: usize, m: usize) -> usize {
        (t * self.dims + d) * self.particles + m
    }

    /// Values in the state buffer, T·D·M.
    pub fn state_len(&self) -> usize {
        self.targets * self.dims * self.particles
    }

    /// Values in a per-particle buffer (log-weights, log-likelihoods), T·M.
    pub fn particle_len(&self) -> usize {
        self.targets * self.particles
    }
}

/// The per-target keys of one stage.
pub fn stage_keys(seed: u64, targets: usize, stage: Stage) -> Vec<[u32; 2]> {
    stage_keys_from(seed, 0, targets, stage)
}

/// The keys of one stage for targets `first .. first + targets` of a batch: a part of a batch
/// (one GPU's share of the targets) draws exactly the numbers those targets draw in the whole.
pub fn stage_keys_from(seed: u64, first: usize, targets: usize, stage: Stage) -> Vec<[u32; 2]> {
    let streams = RandomStreams::new(seed);
    (first..first + targets)
        .map(|t| key_words(streams.key(t as u32, stage)))
        .collect()
}

/// The filter's settings shared by the CPU twin and the GPU driver.
#[derive(Debug, Clone, PartialEq)]
pub struct BatchConfig {
    /// Targets × particles × dimensions.
    pub shape: BatchShape,
    /// The seed every random stream derives from (with the target index).
    pub seed: u64,
    /// Diffusion σ per dimension.
    pub sigma: Vec<f32>,
    /// Clamp diffused states to `(lower, upper)` per dimension.
    pub bounds: Option<(Vec<f32>, Vec<f32>)>,
    /// Which dimensions are angles (wrapped, averaged on the circle); only the first 32 may be.
    pub angular: Vec<bool>,
    /// Resample a target when its ESS is below this × M (`f64::INFINITY`: every step).
    pub ess_threshold: f64,
    /// M′ of the best-M′ weighted mean (eq. 14 of the face paper); 0: not computed.
    pub best: usize,
    /// Annealing layers per frame ([`Annealing::none`]: plain Condensation).
    pub annealing: Annealing,
    /// The dynamics' deterministic part ([`Motion::RandomWalk`]: none).
    pub motion: Motion,
}

/// What moves the particles before the random walk's noise (in the first annealing layer; a
/// model plug-in's own `propagate` replaces both).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum Motion {
    /// x ← x + σ·n: no drift.
    #[default]
    RandomWalk,
    /// x ← x + g·(x̂_{t−1} − x̂_{t−2}) + σ·n: each target's particles drift by the share `gain`
    /// (in (0, 1]) of its estimate's last motion (angles wrapped), then diffuse. A new or reset
    /// target drifts only once it has two estimates.
    ConstantVelocity {
        /// The share of the last motion carried into the prediction.
        gain: f32,
    },
}

impl Motion {
    /// The drift's gain, 0 for the random walk.
    pub fn gain(&self) -> f32 {
        match self {
            Self::RandomWalk => 0.0,
            Self::ConstantVelocity { gain } => *gain,
        }
    }
}

impl BatchConfig {
    /// The plain configuration: diffusion σ per dimension (the length must be `shape.dims`,
    /// checked by [`BatchConfig::validate`]), no bounds, no angles, resampling every step, no
    /// best-M′ mean. Change a field for anything else.
    ///
    /// ```
    /// use pf_core::batch::{BatchConfig, BatchShape};
    /// let config = BatchConfig::new(BatchShape::new(8, 1000, 4).unwrap(), 3, vec![0.1; 4]);
    /// assert!(config.validate().is_ok());
    /// assert!(BatchConfig::new(config.shape, 3, vec![0.1; 3]).validate().is_err());
    /// ```
    pub fn new(shape: BatchShape, seed: u64, sigma: Vec<f32>) -> Self {
        Self {
            shape,
            seed,
            sigma,
            bounds: None,
            angular: vec![false; shape.dims],
            ess_threshold: f64::INFINITY,
            best: 0,
            annealing: Annealing::none(),
            motion: Motion::RandomWalk,
        }
    }

    /// Checks lengths, finiteness and ranges; the error says which value is wrong.
    pub fn validate(&self) -> Result<(), PfError> {
        let d = self.shape.dims;
        let check = |what: &str, len: usize| {
            if len == d {
                Ok(())
            } else {
                Err(PfError::InvalidConfig(format!(
                    "{what} has {len} entries for {d} dimensions"
                )))
            }
        };
        check("sigma", self.sigma.len())?;
        self.annealing.validate_for(d)?;
        if let Motion::ConstantVelocity { gain } = self.motion
            && !(gain > 0.0 && gain <= 1.0)
        {
            return Err(PfError::InvalidConfig(format!(
                "the constant-velocity gain must be in (0, 1], got {gain}"
            )));
        }
        check("angular", self.angular.len())?;
        if let Some((lo, hi)) = &self.bounds {
            check("lower bounds", lo.len())?;
            check("upper bounds", hi.len())?;
            if (0..d).any(|i| lo[i].is_nan() || hi[i].is_nan() || lo[i] > hi[i]) {
                return Err(PfError::InvalidConfig(
                    "a lower bound exceeds its upper bound".into(),
                ));
            }
        }
        if self.sigma.iter().any(|s| !(s.is_finite() && *s >= 0.0)) {
            return Err(PfError::InvalidConfig(
                "every sigma must be finite and >= 0".into(),
            ));
        }
        if self.ess_threshold.is_nan() || self.ess_threshold <= 0.0 {
            return Err(PfError::InvalidConfig(format!(
                "the ESS threshold must be > 0 (infinity: every step), got {}",
                self.ess_threshold
            )));
        }
        if self.best > self.shape.particles {
            return Err(PfError::InvalidConfig(format!(
                "best-M' of {} exceeds the {} particles per target",
                self.best, self.shape.particles
            )));
        }
        // The GPU keeps the angle flags in one 32-bit mask; later dimensions are plain values.
        if let Some(d) = self.angular.iter().skip(32).position(|&a| a) {
            return Err(PfError::InvalidConfig(format!(
                "dimension {} is marked as an angle; only the first 32 dimensions can be angles",
                d + 32
            )));
        }
        Ok(())
    }
}

/// Refuses a motion for a target outside the batch, of the wrong length, or not finite (an
/// estimate may hold NaN: no earlier estimate of that value), for the CPU and GPU engines'
/// `set_target_motion`.
pub fn check_target_motion(
    shape: &BatchShape,
    t: usize,
    estimate: &[f32],
    motion: &[f32],
) -> Result<(), PfError> {
    if t >= shape.targets {
        return Err(PfError::InvalidConfig(format!(
            "target {t} of a batch of {}",
            shape.targets
        )));
    }
    for (what, values) in [
        ("a target's estimate", estimate),
        ("a target's motion", motion),
    ] {
        if values.len() != shape.dims {
            return Err(PfError::LengthMismatch {
                what,
                expected: shape.dims,
                got: values.len(),
            });
        }
    }
    if estimate.iter().any(|v| v.is_infinite()) || motion.iter().any(|v| !v.is_finite()) {
        return Err(PfError::InvalidConfig(format!(
            "a target's estimate must be finite or NaN (none yet) and its motion finite, got {estimate:?} and {motion:?}"
        )));
    }
    Ok(())
}

/// The drift a motion gives with the constant-velocity `gain`: `gain · motion`, angles wrapped
/// into [−π, π) first, as `update_velocity` makes it from two estimates (both engines'
/// `set_target_motion`).
pub fn motion_drift(gain: f32, angular: &[bool], motion: &[f32]) -> Vec<f32> {
    (motion.iter().zip(angular))
        .map(|(&m, &angle)| gain * if angle { super::wrap_angle_floor(m) } else { m })
        .collect()
}
