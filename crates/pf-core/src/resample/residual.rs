use super::{Multinomial, Resampler, Systematic, check_inputs};
use crate::error::PfError;
use crate::random::UniformSource;

/// How [`Residual`] draws the offspring left after the deterministic copies.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ResidualRemainder {
    /// Systematic over the residual weights: offspring counts stay within floor/ceil of M w_i.
    #[default]
    Systematic,
    /// Multinomial over the residual weights (Liu & Chen 1998).
    Multinomial,
}

/// Residual resampling: particle i first gets floor(M w_i) copies; the R offspring left are drawn
/// from the residual weights M w_i − floor(M w_i), normalised.
#[derive(Debug, Clone, Copy, Default)]
pub struct Residual {
    /// How the remainder is resampled.
    pub remainder: ResidualRemainder,
}

impl Residual {
    /// A residual resampler with the given remainder scheme.
    pub fn new(remainder: ResidualRemainder) -> Self {
        Self { remainder }
    }
}

impl Resampler for Residual {
    fn name(&self) -> &'static str {
        match self.remainder {
            ResidualRemainder::Systematic => "residual",
            ResidualRemainder::Multinomial => "residual-multinomial",
        }
    }

    fn resample(
        &self,
        weights: &[f64],
        uniforms: &dyn UniformSource,
        ancestors: &mut [u32],
    ) -> Result<(), PfError> {
        let total = check_inputs(weights, ancestors)?;
        let m = ancestors.len() as f64;
        let mut residual = Vec::with_capacity(weights.len());
        let mut filled = 0usize;
        for (i, &w) in weights.iter().enumerate() {
            let expected = m * w / total;
            // Rounding can push a product a hair above its true value; never exceed the slots.
            let copies = (expected.floor() as usize).min(ancestors.len() - filled);
            ancestors[filled..filled + copies].fill(i as u32);
            filled += copies;
            residual.push((expected - copies as f64).max(0.0));
        }
        let remaining = ancestors.len() - filled;
        if remaining == 0 {
            return Ok(());
        }
        let residual_total: f64 = residual.iter().sum();
        if residual_total <= 0.0 {
            // Only possible through rounding: give the slots to the heaviest particle.
            let heaviest = weights
                .iter()
                .enumerate()
                .fold(0, |best, (i, &w)| if w > weights[best] { i } else { best });
            ancestors[filled..].fill(heaviest as u32);
            return Ok(());
        }
        for r in &mut residual {
            *r /= residual_total;
        }
        let tail = &mut ancestors[filled..];
        match self.remainder {
            ResidualRemainder::Systematic => Systematic.resample(&residual, uniforms, tail),
            ResidualRemainder::Multinomial => Multinomial.resample(&residual, uniforms, tail),
        }
    }
}
