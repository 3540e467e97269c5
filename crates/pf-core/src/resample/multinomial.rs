use rayon::prelude::*;

use super::{Resampler, check_inputs, cumulative_sum, search_cdf};
use crate::error::PfError;
use crate::random::UniformSource;

/// Multinomial resampling: every offspring is an independent draw from the weights (a binary
/// search of the cumulative sum per offspring, in parallel).
#[derive(Debug, Clone, Copy, Default)]
pub struct Multinomial;

impl Resampler for Multinomial {
    fn name(&self) -> &'static str {
        "multinomial"
    }

    fn resample(
        &self,
        weights: &[f64],
        uniforms: &dyn UniformSource,
        ancestors: &mut [u32],
    ) -> Result<(), PfError> {
        check_inputs(weights, ancestors)?;
        let cdf = cumulative_sum(weights);
        // The last running sum, not 1: scaling by it keeps every search point below the end.
        let total = cdf[cdf.len() - 1];
        ancestors
            .par_iter_mut()
            .with_min_len(4096)
            .enumerate()
            .for_each(|(k, out)| {
                *out = search_cdf(&cdf, uniforms.uniform(k as u32, 0) * total);
            });
        Ok(())
    }
}
