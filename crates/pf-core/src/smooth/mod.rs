//! Smoothing: each frame's posterior given the frames after it too, p(x_t | z_1:T), from the
//! filter's weighted particles of every frame (forward filtering, backward smoothing: the
//! marginal smoother of Doucet, Godsill & Andrieu 2000).
//!
//! Going backwards, frame t's particles are reweighed by how well each explains the smoothed
//! particles of frame t+1 under the dynamics:
//!
//! w_{t|T}^i = w_t^i · Σ_j w_{t+1|T}^j · f(x_{t+1}^j | x_t^i) / Σ_k w_t^k · f(x_{t+1}^j | x_t^k)
//!
//! O(M²) per frame and target. The particles stay where the filter put them; only their weights
//! change, so a smoothed frame is summarised like a filtered one: a weighted mean (on the circle
//! for angles) and a 95 % credible interval from the weighted 2.5 % and 97.5 % quantiles.
//!
//! The dynamics are the engine's: a Gaussian random walk with σ per dimension after a known
//! drift (the constant-velocity prediction; zero for the random walk), angles wrapped. A
//! dimension with σ = 0 does not move, so it does not enter the density. With annealing the
//! density is the first layer's (the model's dynamics); the later layers are a search.
//! [`fixed_lag`] smooths frame t − L once frame t is filtered: online, with a delay of L frames.
//! [`ancestry`] does it from the particles' lineage instead, O(M·L) where this is O(M²·L): what
//! the trackers' `--smooth-lag` runs. [`motion`] lets the evidence choose how far each value
//! moves between frames (`--smooth-motion auto`).

use rayon::prelude::*;

use crate::batch::wrap_angle_floor;
use crate::error::PfError;

pub mod ancestry;
mod gauss;
pub mod lag_window;
pub mod motion;
mod summary;
use summary::value_summary;
pub use summary::{Summary, summarise, summarise_value};

/// A target's number, its particles' states (`[d·M + m]`) and their normalised log-weights: what
/// a tracker hands a smoother each frame.
pub type TargetParticles = (usize, Vec<f32>, Vec<f32>);

/// One target's filtered particles at one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Cloud {
    /// The particles' states, `[d·M + m]` (a target's block of the batch layout).
    pub states: Vec<f32>,
    /// Their normalised weights, `[m]`.
    pub weights: Vec<f64>,
    /// What the dynamics add to every particle before the noise on the way to the next frame,
    /// `[d]` (the constant-velocity drift; zeros for the random walk).
    pub drift: Vec<f32>,
}

impl Cloud {
    /// The cloud of target `t` of a batch: its states (`[(t·D + d)·M + m]`), weights from the
    /// normalised log-weights (`[t·M + m]`) and its drift into the next frame.
    pub fn of_target(
        dims: usize,
        particles: usize,
        t: usize,
        states: &[f32],
        log_weights: &[f32],
        drift: Vec<f32>,
    ) -> Result<Self, PfError> {
        let block = dims * particles;
        let (states, log_weights) = match (
            states.get(t * block..(t + 1) * block),
            log_weights.get(t * particles..(t + 1) * particles),
        ) {
            (Some(s), Some(l)) => (s, l),
            _ => {
                return Err(PfError::InvalidConfig(format!(
                    "target {t} of {} states and {} log-weights of {dims} dimensions x {particles} particles",
                    states.len(),
                    log_weights.len()
                )));
            }
        };
        let mut weights = vec![0.0; particles];
        crate::weights::normalise(log_weights, &mut weights)?;
        Ok(Self {
            states: states.to_vec(),
            weights,
            drift,
        })
    }

    pub(crate) fn particles(&self) -> usize {
        self.weights.len()
    }
}

/// The scales [`GaussianTransition::with_motion`] takes (`--smooth-motion`, `smooth_motion=`).
pub const MOTION_SCALES: std::ops::RangeInclusive<f32> = 1e-3..=1e3;

/// `scale` when it lies in [`MOTION_SCALES`] (whose ends keep a σ from underflowing to 0, a value
/// left out, or overflowing), else an error naming the range: the one check behind
/// `--smooth-motion`, Python's `smooth_motion=` and [`GaussianTransition::with_motion`].
pub fn checked_motion_scale(scale: f32) -> Result<f32, PfError> {
    if MOTION_SCALES.contains(&scale) {
        Ok(scale)
    } else {
        Err(PfError::InvalidConfig(format!(
            "the smoother's motion scale must lie from {} to {}, not {scale}",
            MOTION_SCALES.start(),
            MOTION_SCALES.end()
        )))
    }
}

/// The dynamics' density up to a constant: x' ~ N(x + drift, diag σ²), angle differences taken
/// the short way round.
#[derive(Debug, Clone, PartialEq)]
pub struct GaussianTransition {
    /// σ per dimension (0: the dimension does not move and is left out of the density).
    pub sigma: Vec<f32>,
    /// Which dimensions are angles.
    pub angular: Vec<bool>,
}

impl GaussianTransition {
    /// An error unless `cloud` has one σ, angle flag and drift value per dimension.
    pub(crate) fn validate(&self, cloud: &Cloud) -> Result<(), PfError> {
        let dims = self.sigma.len();
        if self.angular.len() != dims
            || cloud.drift.len() != dims
            || cloud.states.len() != dims * cloud.particles()
        {
            return Err(PfError::InvalidConfig(format!(
                "smoothing {dims} dimensions ({} angle flags): a cloud of {} states, {} weights, {} drift values",
                self.angular.len(),
                cloud.states.len(),
                cloud.weights.len(),
                cloud.drift.len()
            )));
        }
        if self.sigma.iter().any(|s| !(s.is_finite() && *s >= 0.0)) {
            return Err(PfError::InvalidConfig(
                "smoothing needs every sigma finite and >= 0".into(),
            ));
        }
        Ok(())
    }

    /// The same density with every σ times `scale` (how far the smoother lets a value move
    /// between frames: below 1, slower motion): an error for a scale outside [`MOTION_SCALES`]
    /// ([`checked_motion_scale`]).
    pub fn with_motion(&self, scale: f32) -> Result<Self, PfError> {
        let scale = checked_motion_scale(scale)?;
        Ok(Self {
            sigma: self.sigma.iter().map(|s| s * scale).collect(),
            angular: self.angular.clone(),
        })
    }

    /// The density of the values `dims` alone (σ 0 for the others, which then do not enter it):
    /// one block of a blocked smoother (Finke & Singh 2017), which smooths groups of values
    /// apart so that the backward weights do not collapse onto a few particles in many
    /// dimensions.
    pub fn block(&self, dims: &[usize]) -> Self {
        let sigma = (self.sigma.iter().enumerate())
            .map(|(d, &s)| if dims.contains(&d) { s } else { 0.0 })
            .collect();
        Self {
            sigma,
            angular: self.angular.clone(),
        }
    }
}

/// The transition's density over the values that move (σ > 0), laid out for many pairs: the
/// O(M²) loops touch only those values.
struct Kernel {
    active: Vec<usize>,
    inv_sigma: Vec<f64>,
    angular: Vec<bool>,
}

impl Kernel {
    fn new(transition: &GaussianTransition) -> Self {
        let active: Vec<usize> = (0..transition.sigma.len())
            .filter(|&d| transition.sigma[d] > 0.0)
            .collect();
        Self {
            inv_sigma: active
                .iter()
                .map(|&d| 1.0 / f64::from(transition.sigma[d]))
                .collect(),
            angular: active.iter().map(|&d| transition.angular[d]).collect(),
            active,
        }
    }

    /// Every particle's moving values, `[m·A + a]`, with the drift added when `drift`.
    fn points(&self, cloud: &Cloud, drift: bool) -> Vec<f64> {
        let particles = cloud.particles();
        let mut out = Vec::with_capacity(particles * self.active.len());
        for m in 0..particles {
            for &d in &self.active {
                let x = f64::from(cloud.states[d * particles + m]);
                out.push(if drift {
                    x + f64::from(cloud.drift[d])
                } else {
                    x
                });
            }
        }
        out
    }

    /// log f(next | from), up to a constant (`from` with its drift).
    fn log_density(&self, from: &[f64], next: &[f64]) -> f64 {
        let mut sum = 0.0;
        for a in 0..from.len() {
            let mut e = next[a] - from[a];
            if self.angular[a] {
                e = f64::from(wrap_angle_floor(e as f32));
            }
            let z = e * self.inv_sigma[a];
            sum += z * z;
        }
        -0.5 * sum
    }
}

/// One backward step: the smoothed weights of `current` from its filtered weights and the
/// smoothed weights `next_smoothed` of the frame after it (`next`).
pub fn backward_step(
    current: &Cloud,
    next: &Cloud,
    next_smoothed: &[f64],
    transition: &GaussianTransition,
) -> Result<Vec<f64>, PfError> {
    transition.validate(current)?;
    transition.validate(next)?;
    if next_smoothed.len() != next.particles() {
        return Err(PfError::LengthMismatch {
            what: "the next frame's smoothed weights",
            expected: next.particles(),
            got: next_smoothed.len(),
        });
    }
    let kernel = Kernel::new(transition);
    if kernel.active.is_empty() {
        // No value moves: the density is the same for every pair, and the future says nothing
        // about which particle the present was.
        return Ok(current.weights.clone());
    }
    let width = kernel.active.len();
    let (from, to) = (kernel.points(current, true), kernel.points(next, false));
    let log_w: Vec<f64> = current.weights.iter().map(|w| w.ln()).collect();
    // log Σ_k w_t^k f(x_{t+1}^j | x_t^k) for each j (the predictive density at x_{t+1}^j).
    let log_predictive: Vec<f64> = (0..next.particles())
        .into_par_iter()
        .map(|j| {
            let x_next = &to[j * width..][..kernel.active.len()];
            let terms = (0..current.particles()).map(|i| {
                log_w[i] + kernel.log_density(&from[i * width..][..kernel.active.len()], x_next)
            });
            streaming_log_sum_exp(terms)
        })
        .collect();
    let mut smoothed: Vec<f64> = (0..current.particles())
        .into_par_iter()
        .map(|i| {
            if current.weights[i] == 0.0 {
                return 0.0;
            }
            let x = &from[i * width..][..kernel.active.len()];
            let share: f64 = (0..next.particles())
                .filter(|&j| next_smoothed[j] > 0.0 && log_predictive[j].is_finite())
                .map(|j| {
                    let x_next = &to[j * width..][..kernel.active.len()];
                    next_smoothed[j] * (kernel.log_density(x, x_next) - log_predictive[j]).exp()
                })
                .sum();
            current.weights[i] * share
        })
        .collect();
    let total: f64 = smoothed.iter().sum();
    if !(total.is_finite() && total > 0.0) {
        return Err(PfError::AllWeightsZero {
            particles: current.particles(),
        });
    }
    for w in &mut smoothed {
        *w /= total;
    }
    Ok(smoothed)
}

/// log Σ exp(v) in one pass (the sum rescaled whenever a larger value comes).
fn streaming_log_sum_exp(values: impl Iterator<Item = f64>) -> f64 {
    let (mut max, mut sum) = (f64::NEG_INFINITY, 0.0f64);
    for v in values {
        if v == f64::NEG_INFINITY {
            continue;
        }
        if v <= max {
            sum += (v - max).exp();
        } else if v.is_finite() {
            sum = sum * (max - v).exp() + 1.0;
            max = v;
        } else if v.is_nan() || v == f64::INFINITY {
            return v;
        }
    }
    if max == f64::NEG_INFINITY {
        return max;
    }
    max + sum.ln()
}

/// The smoothed weights of every frame of one target's run (the last frame's are its filtered
/// weights).
pub fn smooth_all(
    frames: &[Cloud],
    transition: &GaussianTransition,
) -> Result<Vec<Vec<f64>>, PfError> {
    let Some(last) = frames.last() else {
        return Ok(Vec::new());
    };
    let mut out = vec![Vec::new(); frames.len()];
    out[frames.len() - 1] = last.weights.clone();
    for t in (0..frames.len() - 1).rev() {
        out[t] = backward_step(&frames[t], &frames[t + 1], &out[t + 1], transition)?;
    }
    Ok(out)
}

/// The smoothed weights of the first frame of `window` given all of it (frames t − L … t): the
/// fixed-lag smoother's output for frame t − L once frame t is filtered.
pub fn fixed_lag(window: &[Cloud], transition: &GaussianTransition) -> Result<Vec<f64>, PfError> {
    let mut all = smooth_all(window, transition)?;
    if all.is_empty() {
        return Err(PfError::InvalidConfig(
            "fixed-lag smoothing of an empty window".into(),
        ));
    }
    Ok(all.swap_remove(0))
}

/// Every frame's smoothed summary (`[frame][value]`) with each value smoothed as its own block
/// ([`GaussianTransition::block`]): the blocked smoother the trackers' `--smooth` runs.
pub fn smooth_values(
    frames: &[Cloud],
    transition: &GaussianTransition,
) -> Result<Vec<Vec<Summary>>, PfError> {
    let dims = transition.sigma.len();
    for cloud in frames {
        transition.validate(cloud)?;
    }
    let mut out: Vec<Vec<Summary>> = frames.iter().map(|_| Vec::with_capacity(dims)).collect();
    for d in 0..dims {
        let weights = smooth_all(frames, &transition.block(&[d]))?;
        for ((summary, cloud), w) in out.iter_mut().zip(frames).zip(&weights) {
            summary.push(value_summary(cloud, w, &transition.angular, d));
        }
    }
    Ok(out)
}

/// What smooths one track's frames value by value (the work of [`smooth_values`]): the CPU
/// ([`CpuSmoother`]) or a GPU (`pf_gpu::smooth::GpuSmoother` behind `pf_gpu::smooth::OnGpu`).
pub trait ValueSmoother: Send + Sync {
    /// Every frame's smoothed summary, `[frame][value]`.
    fn smooth_values(
        &self,
        frames: &[Cloud],
        transition: &GaussianTransition,
    ) -> Result<Vec<Vec<Summary>>, PfError>;

    /// [`ValueSmoother::smooth_values`] of several tracks, `[track][frame][value]`: one call for
    /// all of them where the backend gains from it (a GPU's one submission).
    fn smooth_many(
        &self,
        tracks: &[&[Cloud]],
        transition: &GaussianTransition,
    ) -> Result<Vec<Vec<Vec<Summary>>>, PfError> {
        (tracks.iter())
            .map(|frames| self.smooth_values(frames, transition))
            .collect()
    }

    /// The smoothed summary of each track's first frame alone, `[track][value]`: what a
    /// fixed-lag smoother writes each frame (its window's first frame, given the window).
    fn smooth_first_many(
        &self,
        tracks: &[&[Cloud]],
        transition: &GaussianTransition,
    ) -> Result<Vec<Vec<Summary>>, PfError> {
        (tracks.iter())
            .map(|frames| smooth_first_values(frames, transition))
            .collect()
    }
}

/// The smoothed summary of `frames`' first frame given all of them, value by value (the first
/// row of [`smooth_values`], the other frames left unsummarised).
pub fn smooth_first_values(
    frames: &[Cloud],
    transition: &GaussianTransition,
) -> Result<Vec<Summary>, PfError> {
    let Some(first) = frames.first() else {
        return Err(PfError::InvalidConfig("smoothing an empty window".into()));
    };
    for cloud in frames {
        transition.validate(cloud)?;
    }
    (0..transition.sigma.len())
        .map(|d| {
            let weights = fixed_lag(frames, &transition.block(&[d]))?;
            Ok(value_summary(first, &weights, &transition.angular, d))
        })
        .collect()
}

/// [`smooth_values`] on the CPU's cores.
#[derive(Debug, Clone, Copy, Default)]
pub struct CpuSmoother;

impl ValueSmoother for CpuSmoother {
    fn smooth_values(
        &self,
        frames: &[Cloud],
        transition: &GaussianTransition,
    ) -> Result<Vec<Vec<Summary>>, PfError> {
        smooth_values(frames, transition)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cloud(states: Vec<f32>, weights: Vec<f64>, drift: Vec<f32>) -> Cloud {
        Cloud {
            states,
            weights,
            drift,
        }
    }

    proptest::proptest! {
        /// A motion scale in range scales every σ (a still value stays still); one outside it,
        /// or not a number, is refused.
        #[test]
        fn a_motion_scale_scales_every_sigma_or_is_refused(
            sigma in proptest::collection::vec(proptest::prop_oneof![proptest::strategy::Just(0.0f32), 1e-3f32..10.0], 1..9),
            scale in proptest::prop_oneof![1e-3f32..=1e3, proptest::num::f32::ANY],
        ) {
            let transition = GaussianTransition { angular: vec![false; sigma.len()], sigma };
            match transition.with_motion(scale) {
                Ok(moved) => {
                    proptest::prop_assert!(MOTION_SCALES.contains(&scale));
                    for (a, b) in transition.sigma.iter().zip(&moved.sigma) {
                        proptest::prop_assert_eq!(*b, a * scale);
                        proptest::prop_assert_eq!(*a == 0.0, *b == 0.0);
                        proptest::prop_assert!(b.is_finite());
                    }
                    proptest::prop_assert_eq!(&moved.angular, &transition.angular);
                }
                Err(_) => proptest::prop_assert!(!MOTION_SCALES.contains(&scale)),
            }
        }
    }

    #[test]
    fn a_weighted_quantile_and_an_angle_interval_across_pi() {
        let c = cloud(vec![3.1, -3.1, 3.0, -3.0], vec![0.25; 4], vec![0.0]);
        let s = summarise(&c, &c.weights, &[true]).unwrap()[0];
        // The mean is π (or −π), the interval about ±0.14 around it, not the whole circle.
        assert!((s.mean.abs() - std::f32::consts::PI).abs() < 1e-4, "{s:?}");
        assert!(s.upper - s.lower < 0.3, "{s:?}");
        let line = cloud(
            vec![0.0, 1.0, 2.0, 3.0],
            vec![0.1, 0.2, 0.3, 0.4],
            vec![0.0],
        );
        let s = summarise(&line, &line.weights, &[false]).unwrap()[0];
        assert!((s.mean - 2.0).abs() < 1e-6);
        assert_eq!((s.lower, s.upper), (0.0, 3.0));
    }

    #[test]
    fn bad_inputs_are_typed_errors() {
        let t = GaussianTransition {
            sigma: vec![1.0],
            angular: vec![false],
        };
        let a = cloud(vec![0.0, 1.0], vec![0.5, 0.5], vec![0.0]);
        assert!(backward_step(&a, &a, &[1.0], &t).is_err());
        let wrong_drift = cloud(vec![0.0, 1.0], vec![0.5, 0.5], vec![]);
        assert!(backward_step(&wrong_drift, &a, &[0.5, 0.5], &t).is_err());
        let bad_sigma = GaussianTransition {
            sigma: vec![f32::NAN],
            angular: vec![false],
        };
        assert!(backward_step(&a, &a, &[0.5, 0.5], &bad_sigma).is_err());
        assert!(smooth_all(&[], &t).unwrap().is_empty());
        assert!(fixed_lag(&[], &t).is_err());
    }

    #[test]
    fn a_block_weighs_by_its_own_values_alone() {
        // Two 2-D particles; the next frame's one particle matches the first in value 0 and
        // the second in value 1.
        let t = GaussianTransition {
            sigma: vec![1.0, 1.0],
            angular: vec![false, false],
        };
        let now = cloud(vec![0.0, 9.0, 0.0, 9.0], vec![0.5, 0.5], vec![0.0, 0.0]);
        let next = cloud(vec![0.0, 9.0], vec![1.0], vec![0.0, 0.0]);
        let by_first = backward_step(&now, &next, &[1.0], &t.block(&[0])).unwrap();
        let by_second = backward_step(&now, &next, &[1.0], &t.block(&[1])).unwrap();
        assert!(
            by_first[0] > 0.99 && by_second[1] > 0.99,
            "{by_first:?} {by_second:?}"
        );
        assert_eq!(t.block(&[1]).sigma, vec![0.0, 1.0]);
    }

    #[test]
    fn the_first_frame_alone_is_the_first_row_of_every_frame() {
        let frames: Vec<Cloud> = (0..4)
            .map(|f| {
                let f = f as f32;
                cloud(
                    vec![f, f + 0.5, f - 0.3, 1.0 - f, 0.2 * f, 0.1],
                    vec![0.2, 0.5, 0.3],
                    vec![0.1, -0.1],
                )
            })
            .collect();
        let transition = GaussianTransition {
            sigma: vec![0.7, 0.4],
            angular: vec![false, true],
        };
        let all = smooth_values(&frames, &transition).unwrap();
        assert_eq!(smooth_first_values(&frames, &transition).unwrap(), all[0]);
        assert!(smooth_first_values(&[], &transition).is_err());
        // One value alone: the same summary, and a value or weights the cloud lacks refused.
        let w = &frames[0].weights;
        assert_eq!(
            summarise_value(&frames[0], w, &transition.angular, 1).unwrap(),
            summarise(&frames[0], w, &transition.angular).unwrap()[1]
        );
        assert!(summarise_value(&frames[0], w, &transition.angular, 2).is_err());
        assert!(summarise_value(&frames[0], &w[..2], &transition.angular, 0).is_err());
        // A cloud whose states are not its drift's dimensions × its particles.
        let short = Cloud {
            drift: vec![0.0; 5],
            ..frames[0].clone()
        };
        assert!(summarise(&short, w, &transition.angular).is_err());
        assert!(summarise(&frames[0], &w[..2], &transition.angular).is_err());
    }

    #[test]
    fn values_that_do_not_move_keep_their_filtered_weights() {
        let current = cloud(vec![0.0, 1.0, 2.0], vec![0.2, 0.3, 0.5], vec![0.0]);
        let next = cloud(vec![5.0, 6.0, 7.0], vec![0.6, 0.2, 0.2], vec![0.0]);
        let still = GaussianTransition {
            sigma: vec![0.0],
            angular: vec![false],
        };
        let smoothed = backward_step(&current, &next, &next.weights, &still).unwrap();
        assert_eq!(smoothed, current.weights);
    }

    #[test]
    fn a_particle_no_future_particle_can_come_from_loses_its_weight() {
        // Two particles at 0 and 10, σ = 1; the next frame's only particle sits at 10.
        let t = GaussianTransition {
            sigma: vec![1.0],
            angular: vec![false],
        };
        let now = cloud(vec![0.0, 10.0], vec![0.5, 0.5], vec![0.0]);
        let next = cloud(vec![10.0], vec![1.0], vec![0.0]);
        let w = backward_step(&now, &next, &[1.0], &t).unwrap();
        assert!(w[1] > 1.0 - 1e-12 && w[0] < 1e-12, "{w:?}");
        // The drift moves the first particle onto the next frame's: now it explains it.
        let drifting = cloud(vec![0.0, 10.0], vec![0.5, 0.5], vec![10.0]);
        let next = cloud(vec![10.0], vec![1.0], vec![0.0]);
        let w = backward_step(&drifting, &next, &[1.0], &t).unwrap();
        assert!(w[0] > 1.0 - 1e-12, "{w:?}");
    }
}
