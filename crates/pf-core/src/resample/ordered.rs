use super::{Resampler, check_inputs, inverse_cdf_sorted};
use crate::error::PfError;
use crate::random::UniformSource;

/// Stratified resampling (Kitagawa 1996): offspring `k` draws its point uniformly in the k-th of M
/// equal strata, `(k + U_k) / M`.
#[derive(Debug, Clone, Copy, Default)]
pub struct Stratified;

impl Resampler for Stratified {
    fn name(&self) -> &'static str {
        "stratified"
    }

    fn resample(
        &self,
        weights: &[f64],
        uniforms: &dyn UniformSource,
        ancestors: &mut [u32],
    ) -> Result<(), PfError> {
        let total = check_inputs(weights, ancestors)?;
        let m = ancestors.len() as f64;
        let point = |k: usize| (k as f64 + uniforms.uniform(k as u32, 0)) / m;
        inverse_cdf_sorted(weights, total, point, ancestors);
        Ok(())
    }
}

/// Systematic resampling (Carpenter, Clifford & Fearnhead 1999): one uniform shared by all
/// strata, `(k + U) / M`. Each particle gets floor(M w_i) or ceil(M w_i) offspring.
#[derive(Debug, Clone, Copy, Default)]
pub struct Systematic;

impl Resampler for Systematic {
    fn name(&self) -> &'static str {
        "systematic"
    }

    fn resample(
        &self,
        weights: &[f64],
        uniforms: &dyn UniformSource,
        ancestors: &mut [u32],
    ) -> Result<(), PfError> {
        let total = check_inputs(weights, ancestors)?;
        let m = ancestors.len() as f64;
        let offset = uniforms.uniform(0, 0);
        let point = |k: usize| (k as f64 + offset) / m;
        inverse_cdf_sorted(weights, total, point, ancestors);
        Ok(())
    }
}
