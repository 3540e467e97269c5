use rayon::prelude::*;

use super::{Resampler, check_inputs, uniform_index};
use crate::error::PfError;
use crate::random::UniformSource;

/// Rejection resampling (Murray, Lee & Jacob 2016): offspring k first proposes particle k, then
/// uniform indices, accepting index j with probability w_j / max(w). Unbiased, and its only
/// collective operation is the maximum. The expected number of tries per offspring is
/// N·max(w), so [`Rejection::max_tries`] bounds the work on degenerate weights.
#[derive(Debug, Clone, Copy)]
pub struct Rejection {
    /// Tries per offspring before [`crate::PfError::RejectionGaveUp`].
    pub max_tries: u32,
}

impl Default for Rejection {
    fn default() -> Self {
        Self { max_tries: 1 << 20 }
    }
}

impl Resampler for Rejection {
    fn name(&self) -> &'static str {
        "rejection"
    }

    fn resample(
        &self,
        weights: &[f64],
        uniforms: &dyn UniformSource,
        ancestors: &mut [u32],
    ) -> Result<(), PfError> {
        check_inputs(weights, ancestors)?;
        let n = weights.len();
        let max = weights.iter().copied().fold(0.0, f64::max);
        let max_tries = self.max_tries.max(1);
        ancestors
            .par_iter_mut()
            .with_min_len(1024)
            .enumerate()
            .try_for_each(|(k, out)| {
                let mut candidate = k % n;
                let mut u = uniforms.uniform(k as u32, 0);
                let mut draw = 1u32;
                for _ in 0..max_tries {
                    // Accept with probability w_j / max(w).
                    if u * max < weights[candidate] {
                        *out = candidate as u32;
                        return Ok(());
                    }
                    candidate = uniform_index(uniforms.uniform(k as u32, draw), n);
                    u = uniforms.uniform(k as u32, draw + 1);
                    draw = draw.wrapping_add(2);
                }
                Err(PfError::RejectionGaveUp {
                    particle: k,
                    tries: max_tries,
                })
            })
    }
}
