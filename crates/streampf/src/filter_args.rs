//! The filter options shared by `face track` and `body track` — the annealing schedule
//! (`pf_core::anneal`) and the dynamics' drift (`pf_core::batch::Motion`): each overrides one part
//! of the tracker's own default.

use anyhow::bail;
use clap::Args;
use pf_core::anneal::{Annealing, MAX_LAYERS, Tempering};
use pf_core::batch::Motion;

#[derive(Debug, Clone, Default, Args)]
pub struct FilterArgs {
    /// Annealing layers per frame (1: plain Condensation). Each layer resamples, diffuses with
    /// the noise shrunk by --sigma-decay per layer and weighs with the likelihood raised to β.
    /// Default: the tracker's own schedule.
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=MAX_LAYERS as i64))]
    pub layers: Option<u32>,
    /// β of each layer chosen so that this fraction of the particles stays effective
    /// (Deutscher's survival rate α, in (0, 1)); β is at most 1.
    #[arg(long, conflicts_with = "betas")]
    pub survival_rate: Option<f32>,
    /// A fixed β per layer instead of the survival rule, comma-separated (as many as --layers).
    #[arg(long, value_delimiter = ',')]
    pub betas: Option<Vec<f32>>,
    /// Layer l diffuses with σ × decay^l, in (0, 1].
    #[arg(long)]
    pub sigma_decay: Option<f32>,
    /// Predict with a constant-velocity drift: each frame the particles move by this share
    /// (in (0, 1]) of the estimate's last motion before the random walk; 0: the random walk
    /// alone. Default: the tracker's own.
    #[arg(long, value_name = "GAIN")]
    pub constant_velocity: Option<f32>,
}

impl FilterArgs {
    /// The tracker's `default` drift with `--constant-velocity` applied, checked.
    pub fn motion(&self, default: Motion) -> anyhow::Result<Motion> {
        match self.constant_velocity {
            None => Ok(default),
            Some(0.0) => Ok(Motion::RandomWalk),
            Some(gain) if gain > 0.0 && gain <= 1.0 => Ok(Motion::ConstantVelocity { gain }),
            Some(gain) => {
                bail!("--constant-velocity must be in [0, 1] (0: the random walk), got {gain}")
            }
        }
    }

    /// The tracker's `default` schedule with the given options applied, checked.
    pub fn apply(&self, default: &Annealing) -> anyhow::Result<Annealing> {
        let mut annealing = default.clone();
        if let Some(layers) = self.layers {
            annealing.layers = layers as usize;
        }
        if let Some(decay) = self.sigma_decay {
            annealing.sigma_decay = decay;
        }
        match (&self.betas, self.survival_rate) {
            (Some(betas), _) => {
                if self.layers.is_none() {
                    annealing.layers = betas.len();
                }
                annealing.tempering = Tempering::Fixed(betas.clone());
            }
            (None, Some(rate)) => {
                annealing.tempering = Tempering::Survival {
                    rate,
                    max_beta: 1.0,
                };
            }
            // `--layers 1` alone is plain Condensation (β = 1), whatever the default tempers.
            (None, None) if annealing.layers == 1 => {
                annealing.tempering = Tempering::Fixed(vec![1.0]);
            }
            (None, None) => {
                // A fixed schedule of the default's length cannot serve another number of
                // layers: more take the survival rule at 0.5.
                if let Tempering::Fixed(betas) = &annealing.tempering
                    && betas.len() != annealing.layers
                {
                    annealing.tempering = Tempering::Survival {
                        rate: 0.5,
                        max_beta: 1.0,
                    };
                }
            }
        }
        if let Err(e) = annealing.validate() {
            bail!("{e} (--layers, --survival-rate, --betas, --sigma-decay)");
        }
        Ok(annealing)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn options_override_the_default_and_bad_ones_are_named() {
        let none = FilterArgs::default();
        assert_eq!(none.apply(&Annealing::none()).unwrap(), Annealing::none());
        let layers = FilterArgs {
            layers: Some(4),
            ..FilterArgs::default()
        };
        let four = layers.apply(&Annealing::none()).unwrap();
        assert_eq!(four.layers, 4);
        assert!(matches!(four.tempering, Tempering::Survival { rate, .. } if rate == 0.5));
        let plain = FilterArgs {
            layers: Some(1),
            ..FilterArgs::default()
        };
        let tempered_default = Annealing::survival(8, 0.5, 0.7);
        let one = plain.apply(&tempered_default).unwrap();
        assert_eq!((one.layers, one.fixed_beta(0)), (1, Some(1.0)));
        let betas = FilterArgs {
            betas: Some(vec![0.1, 0.5]),
            ..FilterArgs::default()
        };
        assert_eq!(betas.apply(&Annealing::none()).unwrap().layers, 2);
        let bad = FilterArgs {
            survival_rate: Some(1.5),
            ..FilterArgs::default()
        };
        let message = bad.apply(&Annealing::none()).unwrap_err().to_string();
        assert!(message.contains("survival rate") && message.contains("--survival-rate"));
        let mismatch = FilterArgs {
            layers: Some(3),
            betas: Some(vec![0.1, 0.5]),
            ..FilterArgs::default()
        };
        assert!(mismatch.apply(&Annealing::none()).is_err());
        let drift = |gain| FilterArgs {
            constant_velocity: Some(gain),
            ..FilterArgs::default()
        };
        let walk = Motion::RandomWalk;
        assert_eq!(none.motion(walk).unwrap(), walk);
        assert_eq!(
            drift(0.0)
                .motion(Motion::ConstantVelocity { gain: 1.0 })
                .unwrap(),
            walk
        );
        assert_eq!(
            drift(0.5).motion(walk).unwrap(),
            Motion::ConstantVelocity { gain: 0.5 }
        );
        for bad in [1.5, -0.1, f32::NAN] {
            assert!(
                drift(bad)
                    .motion(walk)
                    .unwrap_err()
                    .to_string()
                    .contains("--constant-velocity")
            );
        }
    }
}
