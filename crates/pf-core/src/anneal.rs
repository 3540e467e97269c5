//! Annealed particle filtering (Deutscher, Blake & Reid, CVPR 2000; Deutscher & Reid, IJCV 2005):
//! a frame runs L layers instead of one weighing. Layer l resamples, diffuses with the noise
//! shrunk by `sigma_decay^l` and weighs with the likelihood raised to β_l, so that the particles
//! are drawn step by step into the peaks of a sharp likelihood in many dimensions, where one
//! round of random-walk samples would be too thin to find them.
//!
//! Layer 0 is the ordinary step (the model's dynamics, the configured resampling policy);
//! layers 1.. always resample and diffuse with the random walk. β_l is either given per layer
//! ([`Tempering::Fixed`]) or chosen so that the layer keeps a target fraction α of effective
//! particles ([`Tempering::Survival`], Deutscher's survival rate), at most `max_beta`. With one
//! layer and β = 1 ([`Annealing::none`]) the filter is plain Condensation, bit for bit.
//!
//! The rule for β here and in `normalise.wgsl` is the same bisection, so the CPU twin and the GPU
//! driver pick the same β up to their float rounding.
//!
//! Partitioned sampling (MacCormick & Isard, ECCV 2000; the hierarchical search of Deutscher &
//! Reid, IJCV 2005) is a schedule of which dimensions each layer diffuses
//! ([`Annealing::diffused`]): for a tree-structured state the first layers move the root and
//! every later layer a limb, each weighed and resampled in turn, so that a limb is searched with
//! the root already in place instead of in the product of every part's noise.

use crate::error::PfError;

/// How each layer's exponent β is chosen.
#[derive(Debug, Clone, PartialEq)]
pub enum Tempering {
    /// β_l for each layer (one value per layer, each finite and > 0).
    Fixed(Vec<f32>),
    /// β_l such that the layer's effective sample size is `rate`·M (α in (0, 1)), capped at
    /// `max_beta`: the largest β (to the bisection's precision) that keeps that many.
    Survival {
        /// The target survival rate α = ESS / M.
        rate: f32,
        /// The largest β a layer may use.
        max_beta: f32,
    },
}

/// The annealing schedule of a frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Annealing {
    /// Layers per frame (1: plain Condensation).
    pub layers: usize,
    /// How β is chosen.
    pub tempering: Tempering,
    /// Layer l diffuses with σ·`sigma_decay`^l, in (0, 1].
    pub sigma_decay: f32,
    /// Partitioned sampling: the dimensions layer l diffuses, one list per layer (the others keep
    /// their values in that layer). Empty: every layer diffuses every dimension.
    pub diffused: Vec<Vec<usize>>,
}

/// The most layers a frame may run (each is a full resample, diffuse and measure).
pub const MAX_LAYERS: usize = 64;

/// Bisection steps of the survival rule: β to within `max_beta`·2⁻¹¹. Each step is a pass of
/// the ESS over a target's particles (the GPU weighs two steps' three midpoints in one pass of
/// its one workgroup per target and walks them as this bisection does). Ten put β within 0.7 %
/// of the smallest β a face layer took on the synthetic video (0.07 of its cap); twenty bought
/// precision that changed no error (docs/BENCHMARKS.md, "Fewer bisection steps").
/// `shaders/engine/normalise_target.wgsl` declares the same number.
pub const SURVIVAL_BISECTION_STEPS: u32 = 10;

impl Default for Annealing {
    fn default() -> Self {
        Self::none()
    }
}

impl Annealing {
    /// One layer with β = 1: plain Condensation.
    pub fn none() -> Self {
        Self {
            layers: 1,
            tempering: Tempering::Fixed(vec![1.0]),
            sigma_decay: 1.0,
            diffused: Vec::new(),
        }
    }

    /// `layers` layers with β chosen by the survival rate `rate` (at most 1), the diffusion
    /// shrinking by `sigma_decay` per layer.
    pub fn survival(layers: usize, rate: f32, sigma_decay: f32) -> Self {
        Self {
            layers,
            tempering: Tempering::Survival {
                rate,
                max_beta: 1.0,
            },
            sigma_decay,
            diffused: Vec::new(),
        }
    }

    /// The same schedule with layer l diffusing only the dimensions `diffused[l]` (partitioned
    /// sampling); checked against the state's dimensions by [`Self::validate_for`].
    pub fn partitioned(self, diffused: Vec<Vec<usize>>) -> Self {
        Self { diffused, ..self }
    }

    /// Checks the schedule; the error names the bad value.
    pub fn validate(&self) -> Result<(), PfError> {
        let bad = |msg: String| Err(PfError::InvalidConfig(msg));
        if self.layers == 0 || self.layers > MAX_LAYERS {
            return bad(format!(
                "annealing needs 1 to {MAX_LAYERS} layers, got {}",
                self.layers
            ));
        }
        if !(self.sigma_decay > 0.0 && self.sigma_decay <= 1.0) {
            return bad(format!(
                "the annealing sigma decay must be in (0, 1], got {}",
                self.sigma_decay
            ));
        }
        match &self.tempering {
            Tempering::Fixed(betas) => {
                if betas.len() != self.layers {
                    return bad(format!(
                        "{} fixed betas for {} annealing layers",
                        betas.len(),
                        self.layers
                    ));
                }
                if let Some(b) = betas.iter().find(|b| !(b.is_finite() && **b > 0.0)) {
                    return bad(format!("every beta must be finite and > 0, got {b}"));
                }
            }
            Tempering::Survival { rate, max_beta } => {
                if !(*rate > 0.0 && *rate < 1.0) {
                    return bad(format!("the survival rate must be in (0, 1), got {rate}"));
                }
                if !(max_beta.is_finite() && *max_beta > 0.0) {
                    return bad(format!(
                        "the largest beta must be finite and > 0, got {max_beta}"
                    ));
                }
            }
        }
        Ok(())
    }

    /// [`Self::validate`], and that the partitions name `dims`-dimensional states: one list of
    /// dimensions per layer, each dimension below `dims`, none repeated, none empty.
    pub fn validate_for(&self, dims: usize) -> Result<(), PfError> {
        self.validate()?;
        if self.diffused.is_empty() {
            return Ok(());
        }
        let bad = |msg: String| Err(PfError::InvalidConfig(msg));
        if self.diffused.len() != self.layers {
            return bad(format!(
                "{} partitions of diffused dimensions for {} annealing layers",
                self.diffused.len(),
                self.layers
            ));
        }
        for (layer, dims_of_layer) in self.diffused.iter().enumerate() {
            if dims_of_layer.is_empty() {
                return bad(format!("annealing layer {layer} diffuses no dimension"));
            }
            if let Some(d) = dims_of_layer.iter().find(|&&d| d >= dims) {
                return bad(format!(
                    "annealing layer {layer} diffuses dimension {d} of a {dims}-dimensional state"
                ));
            }
            let mut seen = vec![false; dims];
            for &d in dims_of_layer {
                if std::mem::replace(&mut seen[d], true) {
                    return bad(format!("annealing layer {layer} names dimension {d} twice"));
                }
            }
        }
        Ok(())
    }

    /// Layer `l`'s σ per dimension: `sigma`, with 0 for the dimensions the layer does not
    /// diffuse. The annealing scale ([`Self::sigma_scale`]) multiplies it after.
    pub fn layer_sigma(&self, layer: usize, sigma: &[f32]) -> Vec<f32> {
        match self.diffused.get(layer) {
            None => sigma.to_vec(),
            Some(dims) => {
                let mut out = vec![0.0; sigma.len()];
                for &d in dims {
                    if let Some(s) = sigma.get(d) {
                        out[d] = *s;
                    }
                }
                out
            }
        }
    }

    /// Layer `l`'s diffusion scale, `sigma_decay`^k (computed in f32 as the GPU's parameters
    /// are), k the layers since the schedule or, partitioned, since the layers began diffusing
    /// the dimensions layer l diffuses: each partition's search starts at the full σ.
    pub fn sigma_scale(&self, layer: usize) -> f32 {
        let first = match self.diffused.get(layer) {
            None => 0,
            Some(dims) => (0..layer)
                .rev()
                .take_while(|&l| &self.diffused[l] == dims)
                .last()
                .unwrap_or(layer),
        };
        (first..layer).fold(1.0f32, |s, _| s * self.sigma_decay)
    }

    /// The random walk a particle takes through a whole frame's layers, per dimension:
    /// √(Σ_l (σ_l·s_l)²) of each layer's σ ([`Self::layer_sigma`]) and scale
    /// ([`Self::sigma_scale`]). The smoother's transition density uses it: the annealing layers
    /// move the particles as well as the dynamics do.
    pub fn frame_sigma(&self, sigma: &[f32]) -> Vec<f32> {
        let mut variance = vec![0.0f64; sigma.len()];
        for layer in 0..self.layers {
            let scale = f64::from(self.sigma_scale(layer));
            for (v, s) in variance.iter_mut().zip(self.layer_sigma(layer, sigma)) {
                *v += (f64::from(s) * scale).powi(2);
            }
        }
        variance.iter().map(|v| v.sqrt() as f32).collect()
    }

    /// Layer `l`'s fixed β, or `None` when the survival rule chooses it.
    pub fn fixed_beta(&self, layer: usize) -> Option<f32> {
        match &self.tempering {
            Tempering::Fixed(betas) => betas.get(layer).copied(),
            Tempering::Survival { .. } => None,
        }
    }
}

/// `prior + β·ℓ`. β is always > 0 (the survival rule never returns 0), so a NaN, +∞ or zero
/// weight stays one whatever β: the failure policy does not depend on the schedule. Twin of
/// `tempered` in `normalise.wgsl`.
pub fn tempered(prior: f32, log_likelihood: f32, beta: f32) -> f32 {
    prior + beta * log_likelihood
}

/// The effective sample size of the weights `exp(prior + β·ℓ)` (unnormalised), in f64; 0 when
/// every weight is zero.
pub fn tempered_ess(prior: &[f32], log_likelihood: &[f32], beta: f32) -> f64 {
    let xs = prior
        .iter()
        .zip(log_likelihood)
        .map(|(&p, &l)| f64::from(tempered(p, l, beta)));
    let max = xs.clone().fold(f64::NEG_INFINITY, f64::max);
    if max == f64::NEG_INFINITY {
        return 0.0;
    }
    let (s1, s2) = xs.fold((0.0f64, 0.0f64), |(s1, s2), x| {
        let e = (x - max).exp();
        (s1 + e, s2 + e * e)
    });
    s1 * s1 / s2
}

/// Deutscher's rule: the β in (0, `max_beta`] at which the tempered weights keep `rate`·M
/// effective particles — `max_beta` when even it keeps that many, else the midpoint of a
/// [`SURVIVAL_BISECTION_STEPS`]-step bisection (always > 0). The ESS falls as β grows.
/// Twin of `survival_beta` in `normalise.wgsl`.
pub fn survival_beta(prior: &[f32], log_likelihood: &[f32], rate: f32, max_beta: f32) -> f32 {
    let wanted = f64::from(rate) * prior.len() as f64;
    if tempered_ess(prior, log_likelihood, max_beta) >= wanted {
        return max_beta;
    }
    let (mut lo, mut hi) = (0.0f32, max_beta);
    for _ in 0..SURVIVAL_BISECTION_STEPS {
        let mid = 0.5 * (lo + hi);
        if tempered_ess(prior, log_likelihood, mid) >= wanted {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn plain_schedule_is_one_layer_at_beta_one() {
        let a = Annealing::none();
        assert!(a.validate().is_ok());
        assert_eq!(
            (a.layers, a.fixed_beta(0), a.sigma_scale(0)),
            (1, Some(1.0), 1.0)
        );
    }

    #[test]
    fn bad_schedules_name_the_value() {
        let cases = [
            (
                Annealing {
                    layers: 0,
                    ..Annealing::none()
                },
                "layers",
            ),
            (
                Annealing {
                    sigma_decay: 0.0,
                    ..Annealing::none()
                },
                "decay",
            ),
            (
                Annealing {
                    sigma_decay: f32::NAN,
                    ..Annealing::none()
                },
                "decay",
            ),
            (
                Annealing {
                    layers: 2,
                    ..Annealing::none()
                },
                "1 fixed betas for 2",
            ),
            (
                Annealing {
                    tempering: Tempering::Fixed(vec![-1.0]),
                    ..Annealing::none()
                },
                "beta",
            ),
            (Annealing::survival(3, 1.0, 0.5), "survival rate"),
            (
                Annealing::survival(2, 0.5, 0.5).partitioned(vec![vec![0]]),
                "1 partitions of diffused dimensions for 2",
            ),
            (
                Annealing::survival(2, 0.5, 0.5).partitioned(vec![vec![0], vec![]]),
                "layer 1 diffuses no dimension",
            ),
            (
                Annealing::survival(2, 0.5, 0.5).partitioned(vec![vec![0], vec![3]]),
                "dimension 3 of a 3-dimensional",
            ),
            (
                Annealing::survival(2, 0.5, 0.5).partitioned(vec![vec![1, 1], vec![2]]),
                "dimension 1 twice",
            ),
            (Annealing::survival(3, f32::NAN, 0.5), "survival rate"),
            (
                Annealing {
                    tempering: Tempering::Survival {
                        rate: 0.5,
                        max_beta: f32::INFINITY,
                    },
                    ..Annealing::none()
                },
                "largest beta",
            ),
        ];
        for (schedule, words) in cases {
            let message = schedule.validate_for(3).unwrap_err().to_string();
            assert!(message.contains(words), "{message:?} lacks {words:?}");
        }
    }

    #[test]
    fn a_layer_diffuses_only_its_partition() {
        let schedule = Annealing::survival(2, 0.5, 0.5).partitioned(vec![vec![0, 2], vec![1]]);
        assert!(schedule.validate_for(3).is_ok());
        let sigma = [0.5, 0.25, 2.0];
        assert_eq!(schedule.layer_sigma(0, &sigma), vec![0.5, 0.0, 2.0]);
        assert_eq!(schedule.layer_sigma(1, &sigma), vec![0.0, 0.25, 0.0]);
        assert_eq!(Annealing::none().layer_sigma(0, &sigma), sigma.to_vec());
        // The decay restarts where the diffused dimensions change.
        let runs = Annealing::survival(5, 0.5, 0.5).partitioned(vec![
            vec![0],
            vec![0],
            vec![1, 2],
            vec![1, 2],
            vec![1, 2],
        ]);
        let scales: Vec<f32> = (0..5).map(|l| runs.sigma_scale(l)).collect();
        assert_eq!(scales, vec![1.0, 0.5, 1.0, 0.5, 0.25]);
        let plain: Vec<f32> = (0..3)
            .map(|l| Annealing::survival(3, 0.5, 0.5).sigma_scale(l))
            .collect();
        assert_eq!(plain, vec![1.0, 0.5, 0.25]);
    }

    #[test]
    fn failures_are_the_same_at_every_positive_beta() {
        let tiny = 1.0 / (1u32 << (SURVIVAL_BISECTION_STEPS + 1)) as f32;
        for beta in [tiny, 0.5, 1.0, 3.0] {
            assert_eq!(tempered(-1.0, f32::NEG_INFINITY, beta), f32::NEG_INFINITY);
            assert!(tempered(f32::INFINITY, f32::NEG_INFINITY, beta).is_nan());
            assert_eq!(tempered(-1.0, f32::INFINITY, beta), f32::INFINITY);
        }
        assert_eq!(tempered(-1.0, -4.0, 0.5), -3.0);
    }

    proptest! {
        #[test]
        fn survival_beta_keeps_the_target_fraction(
            lls in proptest::collection::vec(-200.0f32..0.0, 2..300),
            rate in 0.05f32..0.95,
            max_beta in 0.1f32..4.0,
        ) {
            let prior = vec![-(lls.len() as f32).ln(); lls.len()];
            let beta = survival_beta(&prior, &lls, rate, max_beta);
            prop_assert!(beta > 0.0 && beta <= max_beta);
            let wanted = f64::from(rate) * lls.len() as f64;
            if beta < max_beta {
                // Within one bisection step of the crossing: just below keeps enough, just above
                // does not.
                let step = max_beta / (1u32 << SURVIVAL_BISECTION_STEPS) as f32;
                prop_assert!(tempered_ess(&prior, &lls, (beta - step).max(0.0)) >= wanted * 0.999);
                prop_assert!(tempered_ess(&prior, &lls, beta + step) <= wanted * 1.001);
            } else {
                prop_assert!(tempered_ess(&prior, &lls, max_beta) >= wanted);
            }
        }
    }
}
