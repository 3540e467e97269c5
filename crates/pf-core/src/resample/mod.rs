//! Resamplers: from normalised weights to ancestor indices.
//!
//! Every resampler implements [`Resampler`]: it reads normalised weights (f64, summing to 1), takes
//! its uniform numbers from the caller through a [`UniformSource`] (so that runs are reproducible
//! and a GPU twin can be fed the very same numbers), and writes one ancestor index per offspring.
//! The number of offspring is `ancestors.len()`; it need not equal the number of weights.
//!
//! | resampler | uniforms read | collective op | offspring count of particle i |
//! |---|---|---|---|
//! | [`Multinomial`] | 1 per offspring | prefix sum | Binomial(M, w_i) |
//! | [`Stratified`] | 1 per offspring | prefix sum | within floor(M w_i) − 1 … ceil(M w_i) + 1 |
//! | [`Systematic`] | 1 in all | prefix sum | floor(M w_i) or ceil(M w_i) |
//! | [`Residual`] | 1 in all (systematic remainder) or 1 per offspring (multinomial) | prefix sum | floor(M w_i) + remainder |
//! | [`Metropolis`] | 2·B per offspring | none | ≈ M w_i in expectation (bias ≤ ε for B from [`Metropolis::steps_for`]) |
//! | [`Rejection`] | 2 per try, unbounded | max weight only | M w_i in expectation, exactly |

mod metropolis;
mod multinomial;
mod ordered;
mod rejection;
mod residual;

pub use metropolis::Metropolis;
pub use multinomial::Multinomial;
pub use ordered::{Stratified, Systematic};
pub use rejection::Rejection;
pub use residual::{Residual, ResidualRemainder};

use crate::error::PfError;
use crate::random::UniformSource;

/// A resampling scheme.
pub trait Resampler: Send + Sync {
    /// A short name for logs, benchmarks and the command line.
    fn name(&self) -> &'static str;

    /// Fills `ancestors` (one entry per offspring) with indices into `weights`.
    ///
    /// `weights` must be normalised (finite, ≥ 0, sum 1 within 1e-6); otherwise
    /// [`PfError::InvalidWeights`]. The output depends only on the weights and the uniforms.
    fn resample(
        &self,
        weights: &[f64],
        uniforms: &dyn UniformSource,
        ancestors: &mut [u32],
    ) -> Result<(), PfError>;
}

/// The resamplers by name, for configuration files and the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ResamplerKind {
    /// Independent draws from the weights (binary search in the CDF).
    Multinomial,
    /// One uniform per stratum of width 1/M.
    Stratified,
    /// One uniform, M evenly spaced points.
    Systematic,
    /// ⌊M·wᵢ⌋ copies, the remainder resampled.
    Residual,
    /// B-step Metropolis chains per offspring (no collective operation).
    Metropolis,
    /// Accept-reject against the largest weight.
    Rejection,
}

impl ResamplerKind {
    /// Every scheme, in the order the benchmarks and figures list them.
    pub const ALL: [ResamplerKind; 6] = [
        ResamplerKind::Multinomial,
        ResamplerKind::Stratified,
        ResamplerKind::Systematic,
        ResamplerKind::Residual,
        ResamplerKind::Metropolis,
        ResamplerKind::Rejection,
    ];

    /// The scheme's name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            ResamplerKind::Multinomial => "multinomial",
            ResamplerKind::Stratified => "stratified",
            ResamplerKind::Systematic => "systematic",
            ResamplerKind::Residual => "residual",
            ResamplerKind::Metropolis => "metropolis",
            ResamplerKind::Rejection => "rejection",
        }
    }

    /// The resampler with its default settings (Metropolis: 32 steps; see [`Metropolis::new`]).
    pub fn build(self) -> Box<dyn Resampler> {
        match self {
            ResamplerKind::Multinomial => Box::new(Multinomial),
            ResamplerKind::Stratified => Box::new(Stratified),
            ResamplerKind::Systematic => Box::new(Systematic),
            ResamplerKind::Residual => Box::new(Residual::default()),
            ResamplerKind::Metropolis => Box::new(Metropolis::new(Metropolis::DEFAULT_STEPS)),
            ResamplerKind::Rejection => Box::new(Rejection::default()),
        }
    }
}

impl std::str::FromStr for ResamplerKind {
    type Err = PfError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        ResamplerKind::ALL
            .into_iter()
            .find(|k| k.name().eq_ignore_ascii_case(s))
            .ok_or_else(|| {
                let names: Vec<_> = ResamplerKind::ALL.iter().map(|k| k.name()).collect();
                PfError::InvalidConfig(format!(
                    "unknown resampler {s:?}; expected one of {}",
                    names.join(", ")
                ))
            })
    }
}

impl std::fmt::Display for ResamplerKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl<R: Resampler + ?Sized> Resampler for Box<R> {
    fn name(&self) -> &'static str {
        (**self).name()
    }
    fn resample(
        &self,
        weights: &[f64],
        uniforms: &dyn UniformSource,
        ancestors: &mut [u32],
    ) -> Result<(), PfError> {
        (**self).resample(weights, uniforms, ancestors)
    }
}

/// Checks the common preconditions and returns the weights' sum.
fn check_inputs(weights: &[f64], ancestors: &[u32]) -> Result<f64, PfError> {
    if ancestors.is_empty() {
        return Err(PfError::EmptyParticleSet);
    }
    if ancestors.len() > u32::MAX as usize {
        return Err(PfError::InvalidConfig(format!(
            "{} offspring do not fit 32-bit indices",
            ancestors.len()
        )));
    }
    crate::weights::check_normalised(weights)
}

/// A uniform index in 0..n from a uniform in [0, 1).
fn uniform_index(u: f64, n: usize) -> usize {
    ((u * n as f64) as usize).min(n - 1)
}

/// Inverse-CDF search for a nondecreasing sequence of points in [0, 1): offspring `k` gets the
/// smallest `i` with `point(k)·total < C_i`, where `C_i` is the running sum of the weights. One
/// merge pass, O(N + M), and never a zero-weight particle (its `C_i` equals `C_{i-1}`).
fn inverse_cdf_sorted(
    weights: &[f64],
    total: f64,
    point: impl Fn(usize) -> f64,
    ancestors: &mut [u32],
) {
    let last = weights.len() - 1;
    let mut i = 0;
    let mut cumulative = weights[0];
    for (k, out) in ancestors.iter_mut().enumerate() {
        let target = point(k) * total;
        while cumulative <= target && i < last {
            i += 1;
            cumulative += weights[i];
        }
        *out = i as u32;
    }
}

/// The smallest `i` with `target < cdf[i]` (`cdf` nondecreasing, `target < cdf[last]`).
fn search_cdf(cdf: &[f64], target: f64) -> u32 {
    let i = cdf.partition_point(|&c| c <= target);
    i.min(cdf.len() - 1) as u32
}

/// The running sum of the weights.
fn cumulative_sum(weights: &[f64]) -> Vec<f64> {
    let mut acc = 0.0;
    weights
        .iter()
        .map(|w| {
            acc += w;
            acc
        })
        .collect()
}
