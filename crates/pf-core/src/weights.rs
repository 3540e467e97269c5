//! Log-domain weights: log-sum-exp normalisation and the effective sample size.
//!
//! Weights are kept as log-weights (f32, the GPU's type) and normalised in f64: subtracting the
//! maximum before exponentiating means no weight underflows to a zero sum and none overflows,
//! whatever the scale of the log-likelihood (−1e30 included).

use crate::error::PfError;

/// The maximum log-weight and `log Σ exp(lw)`, accumulated in f64.
///
/// Kept as `max` and `log Σ exp(lw − max)` separately: at log-weights near −1e30 the sum
/// `max + ln(n)` is rounded back to `max`, so normalising must subtract the two in turn.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LogSumExp {
    /// The largest value.
    pub max: f64,
    /// `log Σ exp(lw − max)`, in [0, ln N].
    pub log_sum_shifted: f64,
    /// `max + log_sum_shifted`: the log of the sum of the weights.
    pub log_sum: f64,
}

impl LogSumExp {
    /// The normalised log-weight `lw − log Σ exp(lw)`, computed without cancellation.
    pub fn normalised_log(&self, log_weight: f32) -> f64 {
        (f64::from(log_weight) - self.max) - self.log_sum_shifted
    }
}

/// Checks the log-weights and returns their log-sum-exp.
///
/// Errors: a NaN, a +∞, or every entry −∞ (nothing to normalise). An empty slice is
/// [`PfError::EmptyParticleSet`].
pub fn log_sum_exp(log_weights: &[f32]) -> Result<LogSumExp, PfError> {
    if log_weights.is_empty() {
        return Err(PfError::EmptyParticleSet);
    }
    let mut max = f64::NEG_INFINITY;
    for (i, &lw) in log_weights.iter().enumerate() {
        if lw.is_nan() {
            return Err(PfError::NanLogWeight { particle: i });
        }
        if lw == f32::INFINITY {
            return Err(PfError::InfiniteLogWeight { particle: i });
        }
        max = max.max(f64::from(lw));
    }
    if max == f64::NEG_INFINITY {
        return Err(PfError::AllWeightsZero {
            particles: log_weights.len(),
        });
    }
    // Every term is exp(≤ 0) ≤ 1 and the max contributes exactly 1, so the sum is in [1, N].
    let sum: f64 = log_weights
        .iter()
        .map(|&lw| (f64::from(lw) - max).exp())
        .sum();
    let log_sum_shifted = sum.ln();
    Ok(LogSumExp {
        max,
        log_sum_shifted,
        log_sum: max + log_sum_shifted,
    })
}

/// Writes the normalised weights `exp(lw - lse)` into `weights` and returns the log-sum-exp.
pub fn normalise(log_weights: &[f32], weights: &mut [f64]) -> Result<LogSumExp, PfError> {
    if weights.len() != log_weights.len() {
        return Err(PfError::LengthMismatch {
            what: "weight buffer",
            expected: log_weights.len(),
            got: weights.len(),
        });
    }
    let lse = log_sum_exp(log_weights)?;
    for (w, &lw) in weights.iter_mut().zip(log_weights) {
        *w = lse.normalised_log(lw).exp();
    }
    Ok(lse)
}

/// Effective sample size 1 / Σ w², for normalised weights; in [1, N].
pub fn effective_sample_size(weights: &[f64]) -> f64 {
    let sum_sq: f64 = weights.iter().map(|w| w * w).sum();
    if sum_sq > 0.0 { 1.0 / sum_sq } else { 0.0 }
}

/// Checks that `weights` are normalised: finite, non-negative, summing to 1 (to 1e-6).
/// Returns their sum (which the resamplers use to scale their search points).
pub fn check_normalised(weights: &[f64]) -> Result<f64, PfError> {
    if weights.is_empty() {
        return Err(PfError::EmptyParticleSet);
    }
    if weights.len() > u32::MAX as usize {
        return Err(PfError::InvalidWeights {
            reason: format!("{} weights do not fit 32-bit indices", weights.len()),
        });
    }
    let mut sum = 0.0;
    for (i, &w) in weights.iter().enumerate() {
        if !(w.is_finite() && w >= 0.0) {
            return Err(PfError::InvalidWeights {
                reason: format!("weight {i} is {w}"),
            });
        }
        sum += w;
    }
    if (sum - 1.0).abs() > 1e-6 {
        return Err(PfError::InvalidWeights {
            reason: format!("weights sum to {sum}, not 1"),
        });
    }
    Ok(sum)
}
