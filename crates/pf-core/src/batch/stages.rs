// Index loops mirror the GPU kernels (t, d, m) and read clearer than zipped iterators here.
#![allow(clippy::needless_range_loop)]

//! The CPU twins of pf-gpu's filter stages, one function per kernel (same inputs, same random
//! numbers, f64 accumulation): diffusion and the constant-velocity drift (`diffuse.wgsl`), the
//! tempered normalisation (`normalise.wgsl`), the weighted means, spreads and velocity update
//! (`estimate.wgsl`) and the best-M′ mean.

use rayon::prelude::*;

use super::{BatchShape, wrap_angle_floor};
use crate::anneal::{Annealing, Tempering, survival_beta, tempered};
use crate::error::PfError;
use crate::random::counter_gaussian_pair;
use crate::weights;

/// Twin of `diffuse.wgsl`: x += (σ_d·s)·n with n = counter_gaussian(key_t, m, d, step) and s the
/// annealing layer's scale (1 for plain Condensation), then clamp and angle wrap.
#[allow(clippy::too_many_arguments)]
pub fn diffuse(
    shape: &BatchShape,
    states: &mut [f32],
    sigma: &[f32],
    sigma_scale: f32,
    bounds: Option<(&[f32], &[f32])>,
    angular: &[bool],
    keys: &[[u32; 2]],
    step: u64,
) {
    // One task per (target, pair of dimensions) rows of M values: both draws of a pair come from
    // one Philox block, and each value is a pure function of its indices, so the tasks run on
    // all cores with the same result.
    let m_count = shape.particles;
    states
        .par_chunks_mut(shape.dims * m_count)
        .enumerate()
        .flat_map(|(t, target)| {
            (target.par_chunks_mut(2 * m_count).enumerate())
                .map(move |(pair, rows)| (t, pair, rows))
        })
        .for_each(|(t, pair, rows)| {
            let (first, second) = rows.split_at_mut(m_count);
            let d = 2 * pair;
            let step_one = |value: &mut f32, d: usize, z: f64| {
                let mut x = (f64::from(*value) + f64::from(sigma[d] * sigma_scale) * z) as f32;
                if let Some((lo, hi)) = bounds {
                    x = x.clamp(lo[d], hi[d]);
                }
                if angular[d] {
                    x = wrap_angle_floor(x);
                }
                *value = x;
            };
            for m in 0..m_count {
                let (z0, z1) = counter_gaussian_pair(keys[t], m as u32, pair as u32, step);
                step_one(&mut first[m], d, z0);
                if let Some(value) = second.get_mut(m) {
                    step_one(value, d + 1, z1);
                }
            }
        });
}

/// How one layer's exponent β is set (see [`crate::anneal`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LayerBeta {
    /// This β (1: the plain likelihood).
    Fixed(f32),
    /// The survival rule: ESS = `rate`·M, β at most `max_beta`.
    Survival {
        /// α.
        rate: f32,
        /// The cap on β.
        max_beta: f32,
    },
}

impl LayerBeta {
    /// Layer `layer`'s rule under `annealing`.
    pub fn of_layer(annealing: &Annealing, layer: usize) -> Self {
        match &annealing.tempering {
            Tempering::Fixed(betas) => Self::Fixed(betas.get(layer).copied().unwrap_or(1.0)),
            Tempering::Survival { rate, max_beta } => Self::Survival {
                rate: *rate,
                max_beta: *max_beta,
            },
        }
    }
}

/// One target's normalisation: its effective sample size and the β it weighed with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Normalised {
    /// 1 / Σw².
    pub ess: f64,
    /// The exponent applied to the log-likelihood.
    pub beta: f32,
}

/// Twin of `normalise.wgsl` for one target: adds β·log-likelihood (β from `beta`), normalises
/// (f64), writes the weights and returns the ESS and β; on a degenerate target it leaves uniform
/// weights and returns the error. A NaN, +∞ or all-zero weight is one at every β > 0, so the
/// failure does not depend on β.
pub fn normalise_target(
    log_weights: &mut [f32],
    log_likelihood: &[f32],
    weights_out: &mut [f64],
    beta: LayerBeta,
) -> Result<Normalised, PfError> {
    let beta = match beta {
        LayerBeta::Fixed(b) => b,
        LayerBeta::Survival { rate, max_beta } => {
            survival_beta(log_weights, log_likelihood, rate, max_beta)
        }
    };
    for (lw, &ll) in log_weights.iter_mut().zip(log_likelihood) {
        *lw = tempered(*lw, ll, beta);
    }
    match weights::normalise(log_weights, weights_out) {
        Ok(lse) => {
            for lw in log_weights.iter_mut() {
                *lw = lse.normalised_log(*lw) as f32;
            }
            Ok(Normalised {
                ess: weights::effective_sample_size(weights_out),
                beta,
            })
        }
        Err(err) => {
            let n = log_weights.len();
            log_weights.fill(-(n as f32).ln());
            weights_out.fill(1.0 / n as f64);
            Err(err)
        }
    }
}

/// A frame's log evidence for one target, `log Σ_m exp(lw_m + ℓ_m)` in f64, from the normalised
/// log-weights the frame starts with (`prior`, uniform after resampling) and the log-likelihoods
/// of the predicted particles: the bootstrap filter's estimate of log p(z_t | z_1:t−1), up to the
/// likelihood's constant. The filter takes it in the first annealing layer at β = 1, before any
/// tempering: the later layers reweigh particles that the annealing diffusion moved, a search
/// whose normalisers estimate no evidence. NaN when a term is NaN, +∞ when one is +∞, −∞ when
/// every term is zero. Twin of the `log_evidence` of `normalise.wgsl`.
pub fn frame_log_evidence(prior: &[f32], log_likelihood: &[f32]) -> f64 {
    let terms = || prior.iter().zip(log_likelihood).map(|(&p, &l)| p + l);
    if terms().any(f32::is_nan) {
        return f64::NAN;
    }
    let max = terms().fold(f32::NEG_INFINITY, f32::max);
    if !max.is_finite() {
        return f64::from(max);
    }
    let max = f64::from(max);
    let sum: f64 = terms().map(|x| (f64::from(x) - max).exp()).sum();
    max + sum.ln()
}

/// Twin of the weighted-mean kernel: per target and dimension, angles on the circle.
pub fn weighted_means(
    shape: &BatchShape,
    states: &[f32],
    weights: &[f64],
    angular: &[bool],
) -> Vec<f32> {
    let rows = (0..shape.targets * shape.dims).into_par_iter();
    rows.map(|row| row_moments(shape, states, weights, angular, row, false).0)
        .collect()
}

/// Twin of the whole weighted-mean kernel: per target and dimension the weighted mean and the
/// posterior's spread about it — the weighted standard deviation, or for an angle the circular
/// standard deviation √(−2 ln R), R the length of the weighted mean unit vector (0 for one
/// direction; it grows without bound as the directions fill the circle). An angle's sums of
/// sines and cosines give both its mean and its spread in one pass.
pub fn weighted_means_and_spreads(
    shape: &BatchShape,
    states: &[f32],
    weights: &[f64],
    angular: &[bool],
) -> (Vec<f32>, Vec<f32>) {
    let rows = (0..shape.targets * shape.dims).into_par_iter();
    let moments: Vec<(f32, f32)> = rows
        .map(|row| row_moments(shape, states, weights, angular, row, true))
        .collect();
    moments.into_iter().unzip()
}

/// One (target, dimension) row's weighted mean and, when `with_spread`, its spread (else 0),
/// summed in index order as on one core (rows run on all cores with the same result).
fn row_moments(
    shape: &BatchShape,
    states: &[f32],
    weights: &[f64],
    angular: &[bool],
    row: usize,
    with_spread: bool,
) -> (f32, f32) {
    let (t, d) = (row / shape.dims, row % shape.dims);
    let w = &weights[t * shape.particles..(t + 1) * shape.particles];
    let xs = &states[row * shape.particles..(row + 1) * shape.particles];
    if angular[d] {
        let (s, c) = (xs.iter().zip(w)).fold((0.0f64, 0.0f64), |(s, c), (&x, &wi)| {
            let x = f64::from(x);
            (s + wi * x.sin(), c + wi * x.cos())
        });
        let spread = if with_spread {
            circular_spread(s.hypot(c)) as f32
        } else {
            0.0
        };
        return (s.atan2(c) as f32, spread);
    }
    let (a, b) = (xs.iter().zip(w)).fold((0.0f64, 0.0f64), |(a, b), (&x, &wi)| {
        (a + wi * f64::from(x), b + wi)
    });
    if b <= 0.0 {
        return (0.0, 0.0);
    }
    let mean = (a / b) as f32;
    if !with_spread {
        return (mean, 0.0);
    }
    let m64 = f64::from(mean);
    let sq: f64 =
        (xs.iter().zip(w)).fold(0.0, |sq, (&x, &wi)| sq + wi * (f64::from(x) - m64).powi(2));
    (mean, (sq / b).sqrt() as f32)
}

/// √(−2 ln R) of a mean resultant length R in (0, 1] (clamped), the circular standard deviation.
pub fn circular_spread(r: f64) -> f64 {
    (-2.0 * r.clamp(1e-30, 1.0).ln()).sqrt()
}

/// Twin of the best-M′ kernel: per target, the weighted mean of the `best` heaviest particles,
/// ties to the lower index (the rule of [`crate::estimate::best_weighted_mean`]).
pub fn best_weighted_means(
    shape: &BatchShape,
    states: &[f32],
    weights: &[f64],
    angular: &[bool],
    best: usize,
) -> Vec<f32> {
    let m = shape.particles;
    let best = best.clamp(1, m);
    // Zero the weights of the particles left out, then take the plain weighted mean.
    let mut selected = vec![0.0f64; weights.len()];
    selected
        .par_chunks_mut(m)
        .zip(weights.par_chunks(m))
        .for_each(|(kept, w)| {
            for i in crate::estimate::heaviest(w, best) {
                kept[i] = w[i];
            }
        });
    weighted_means(shape, states, &selected, angular)
}

/// Twin of the drift in `diffuse.wgsl`: x += v_{t,d} (the constant-velocity prediction).
pub fn add_drift(shape: &BatchShape, states: &mut [f32], velocity: &[f32]) {
    for t in 0..shape.targets {
        for d in 0..shape.dims {
            let v = velocity[t * shape.dims + d];
            let start = shape.state_index(t, d, 0);
            for x in &mut states[start..start + shape.particles] {
                *x += v;
            }
        }
    }
}

/// Twin of the velocity update in `estimate.wgsl`: v = gain·(x̂ − x̂_previous) (angles wrapped),
/// 0 where there is no previous estimate yet; then x̂ becomes the previous estimate. Nothing
/// changes when `gain` is 0 (the random walk).
pub fn update_velocity(
    gain: f32,
    angular: &[bool],
    estimates: &[f32],
    previous: &mut [f32],
    velocity: &mut [f32],
) {
    if gain <= 0.0 {
        return;
    }
    let dims = angular.len();
    for (k, (&x, prev)) in estimates.iter().zip(previous.iter_mut()).enumerate() {
        velocity[k] = if prev.is_nan() {
            0.0
        } else if angular[k % dims] {
            gain * wrap_angle_floor(x - *prev)
        } else {
            gain * (x - *prev)
        };
        *prev = x;
    }
}
