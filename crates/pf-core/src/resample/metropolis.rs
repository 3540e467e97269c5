use rayon::prelude::*;

use super::{Resampler, check_inputs, uniform_index};
use crate::error::PfError;
use crate::random::UniformSource;

/// Metropolis resampling (Murray, Lee & Jacob 2016): offspring k runs a B-step Metropolis chain
/// over particle indices, started at k, proposing a uniform index and accepting with probability
/// min(1, w_j / w_current). No collective operation (no prefix sum, no normalising constant), so
/// it parallelises perfectly; the price is a bias that vanishes as B grows.
#[derive(Debug, Clone, Copy)]
pub struct Metropolis {
    steps: u32,
}

impl Metropolis {
    /// Used by [`super::ResamplerKind::build`].
    pub const DEFAULT_STEPS: u32 = 32;

    /// A Metropolis resampler with `steps` steps per offspring.
    pub fn new(steps: u32) -> Self {
        Self { steps }
    }

    /// Steps per offspring B.
    pub fn steps(&self) -> u32 {
        self.steps
    }

    /// The number of steps after which the chain's bias is at most `epsilon` (Murray et al. eq. 5):
    /// B = ⌈log ε / log(1 − β)⌉ with β = mean(w) / max(w).
    pub fn steps_for(weights: &[f64], epsilon: f64) -> u32 {
        let max = weights.iter().copied().fold(0.0, f64::max);
        if weights.is_empty() || max <= 0.0 || !(epsilon > 0.0 && epsilon < 1.0) {
            return 1;
        }
        let mean = weights.iter().sum::<f64>() / weights.len() as f64;
        let beta = (mean / max).clamp(f64::MIN_POSITIVE, 1.0);
        if beta >= 1.0 {
            return 1;
        }
        let b = (epsilon.ln() / (-beta).ln_1p()).ceil();
        if b >= f64::from(u32::MAX) {
            u32::MAX
        } else {
            (b as u32).max(1)
        }
    }
}

impl Resampler for Metropolis {
    fn name(&self) -> &'static str {
        "metropolis"
    }

    fn resample(
        &self,
        weights: &[f64],
        uniforms: &dyn UniformSource,
        ancestors: &mut [u32],
    ) -> Result<(), PfError> {
        check_inputs(weights, ancestors)?;
        let n = weights.len();
        ancestors
            .par_iter_mut()
            .with_min_len(1024)
            .enumerate()
            .for_each(|(k, out)| {
                // Step b reads draws 2b (proposal) and 2b + 1 (acceptance): two steps per block.
                let mut current = k % n;
                let mut block = [0.0; 4];
                for b in 0..self.steps {
                    if b % 2 == 0 {
                        block = uniforms.uniform4(k as u32, b / 2);
                    }
                    let lane = 2 * (b % 2) as usize;
                    let proposal = uniform_index(block[lane], n);
                    let u = block[lane + 1];
                    // u < w_j / w_cur, written without a division (w_cur may be 0).
                    if u * weights[current] < weights[proposal] {
                        current = proposal;
                    }
                }
                *out = current as u32;
            });
        Ok(())
    }
}
