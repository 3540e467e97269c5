//! The smoother's motion chosen by the evidence (`--smooth-motion auto`, `smooth_motion="auto"`).
//!
//! A tracker's diffusion is a search's reach: wide enough to find a head that turns fast, far
//! wider than a head that sits still moves. Smoothing with it leaves a still head's jitter;
//! smoothing with less lags a head that turns. Which is right is a question about the dynamics,
//! and the filter's particles answer it: for each value and each candidate motion scale s (the
//! tracker's σ × 1, ½, ¼ … 1/64), the filter is re-weighted as if it had run with motion s
//! (the marginal particle filter's weights, Klaas, de Freitas & Doucet 2005):
//!
//! w_s,t^i ∝ w_t^i · p_s(x_t^i | z_1:t−1) / p_1(x_t^i | z_1:t−1),
//! p_s(x | z_1:t−1) = Σ_k w_s,t−1^k N(x; x_t−1^k + drift, (s σ)²),
//!
//! and Σ_t log Σ_i w_t^i · p_s(x_t^i) / p_1(x_t^i) is log p_s(z_1:T) − log p_1(z_1:T), the
//! evidence of motion s against the tracker's own. The motion with the most evidence, among
//! those whose re-weighted filter keeps enough of the filter's effective sample size
//! ([`MIN_KEPT_SAMPLE_SIZE`]), smooths the value (the marginal smoother of [`super`], with the
//! re-weighted filter's weights, which are the filter's own at s = 1); its 95 % intervals are
//! widened to take in the tracker's motion's ([`smooth_values_by_evidence`] says why). Each value is its own block, as in [`super::smooth_values`], and
//! both passes are one-dimensional Gauss transforms ([`super::gauss`]): O(M) a frame, value and
//! candidate, on the CPU's cores wherever the tracker ran.
//!
//! A frame the tracker's own motion cannot reach from the one before (a restart elsewhere: every
//! predictive density 0) starts the chain afresh: its filtered weights, no evidence either way.

mod online;
pub use online::OnlineMotion;

use rayon::prelude::*;

use super::gauss::gauss_transform;
use super::summary::value_summary;
use super::{Cloud, GaussianTransition, Summary, ValueSmoother};
use crate::batch::wrap_angle_floor;
use crate::error::PfError;
use crate::weights::effective_sample_size;

/// The motion scales the evidence chooses among: the tracker's σ times 1, ½, ¼ … 1/64.
pub const CANDIDATE_SCALES: [f32; 7] = [1.0, 0.5, 0.25, 0.125, 0.0625, 0.031_25, 0.015_625];

/// The least share of the filter's effective sample size (the median over frames of the
/// re-weighted filter's against the filter's own) a candidate must keep to be trusted: its
/// evidence is an importance-sampling estimate, and from a few particles it is noise. On the
/// synthetic body (a partitioned tracker, whose clouds hold many copies of each value) motions
/// keeping 3-5 % of it claimed gains of 60-77 and smoothed worse than the tracker's motion.
pub const MIN_KEPT_SAMPLE_SIZE: f64 = 0.1;

/// One value's motion as the evidence chose it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionChoice {
    /// The chosen scale of the tracker's σ (1 for a value that does not move).
    pub scale: f32,
    /// log p(z_1:T | scale) − log p(z_1:T | the tracker's motion): 0 at scale 1.
    pub log_evidence_gain: f64,
}

/// One value of one track's frames, laid out for the transforms: each frame's filtered weights,
/// and each pair of frames' particles as the transforms take them (computed once: every
/// candidate and both passes read them).
struct ValueFrames {
    weights: Vec<Vec<f64>>,
    /// `[t]`: frame t's particles moved by the drift into frame t + 1 (the transforms' sources)
    /// and frame t + 1's particles (their targets), an angle's both taken within π of the
    /// sources' first value, so that a difference across ±π is the short way round.
    pairs: Vec<(Vec<f64>, Vec<f64>)>,
}

impl ValueFrames {
    fn new(frames: &[Cloud], d: usize, angular: bool) -> Self {
        let values: Vec<Vec<f64>> = (frames.iter())
            .map(|c| {
                let m = c.particles();
                c.states[d * m..(d + 1) * m]
                    .iter()
                    .map(|&x| f64::from(x))
                    .collect()
            })
            .collect();
        let pairs = (frames.windows(2).zip(values.windows(2)))
            .map(|(clouds, values)| {
                let drift = f64::from(clouds[0].drift[d]);
                let from: Vec<f64> = values[0].iter().map(|x| x + drift).collect();
                value_pair(&from, &values[1], angular)
            })
            .collect();
        Self {
            weights: frames.iter().map(|c| c.weights.clone()).collect(),
            pairs,
        }
    }
}

/// A pair of frames' values as the transforms take them: `from` (the earlier frame's, moved by
/// its drift) and `to`, an angle's both taken within π of `from`'s first value, so that a
/// difference across ±π is the short way round.
fn value_pair(from: &[f64], to: &[f64], angular: bool) -> (Vec<f64>, Vec<f64>) {
    if !angular {
        return (from.to_vec(), to.to_vec());
    }
    let reference = from.first().copied().unwrap_or(0.0);
    let near = |x: f64| reference + f64::from(wrap_angle_floor((x - reference) as f32));
    (
        from.iter().map(|&x| near(x)).collect(),
        to.iter().map(|&x| near(x)).collect(),
    )
}

/// Divides `values` by their sum; `None` when the sum is not positive and finite.
fn normalised(mut values: Vec<f64>) -> Option<(Vec<f64>, f64)> {
    let total: f64 = values.iter().sum();
    if !(total.is_finite() && total > 0.0) {
        return None;
    }
    for v in &mut values {
        *v /= total;
    }
    Some((values, total))
}

/// The filter re-weighted as if its motion were `sigma` (σ_tracker · scale): every frame's
/// weights and the log-evidence gain against the tracker's motion; `None` when the motion cannot
/// explain some frame the tracker's can (its evidence −∞).
fn reweighted(
    frames: &ValueFrames,
    (tracker_sigma, tracker_predictive): (f64, &[Vec<f64>]),
    sigma: f64,
) -> Option<(Vec<Vec<f64>>, f64)> {
    let mut weights = vec![frames.weights[0].clone()];
    let mut gain = 0.0;
    for (t, tracker) in tracker_predictive.iter().enumerate() {
        let filtered = &frames.weights[t + 1];
        if tracker.iter().all(|p| *p == 0.0) {
            weights.push(filtered.clone());
            continue;
        }
        let (next, frame_gain) = reweigh_frame(
            &frames.pairs[t],
            &weights[t],
            filtered,
            tracker,
            (tracker_sigma, sigma),
        )?;
        gain += frame_gain;
        weights.push(next);
    }
    Some((weights, gain))
}

/// One frame of [`reweighted`]: `filtered` (the frame's weights) re-weighted as if the motion
/// from the frame before (`pair`, its re-weighted weights `previous`) were `sigma` where the
/// tracker's is `tracker_sigma` (whose predictive density at the frame's particles is
/// `tracker`), and the frame's log-evidence gain; `None` when the motion cannot explain it.
fn reweigh_frame(
    (from, to): &(Vec<f64>, Vec<f64>),
    previous: &[f64],
    filtered: &[f64],
    tracker: &[f64],
    (tracker_sigma, sigma): (f64, f64),
) -> Option<(Vec<f64>, f64)> {
    let ours = gauss_transform(from, previous, to, sigma);
    // Each density's 1/σ: the ratio of N(·; ·, sigma²) to N(·; ·, tracker_sigma²).
    let scale = tracker_sigma / sigma;
    let moved: Vec<f64> = (filtered.iter().zip(&ours).zip(tracker))
        .map(|((w, p), q)| if *q > 0.0 { w * scale * p / q } else { 0.0 })
        .collect();
    let (next, total) = normalised(moved)?;
    Some((next, total.ln()))
}

/// The marginal smoother's backward pass over one value under `sigma`, from the filter's
/// `weights` (re-weighted to that motion): every frame's smoothed weights.
fn smoothed(frames: &ValueFrames, weights: &[Vec<f64>], sigma: f64) -> Vec<Vec<f64>> {
    let last = weights.len() - 1;
    let mut out = vec![Vec::new(); weights.len()];
    out[last] = weights[last].clone();
    for t in (0..last).rev() {
        let (from, to) = &frames.pairs[t];
        let predictive = gauss_transform(from, &weights[t], to, sigma);
        let share: Vec<f64> = (out[t + 1].iter().zip(&predictive))
            .map(|(s, p)| if *p > 0.0 { s / p } else { 0.0 })
            .collect();
        let back = gauss_transform(to, &share, from, sigma);
        let mine: Vec<f64> = weights[t].iter().zip(&back).map(|(w, b)| w * b).collect();
        // Nothing after reaches this frame (a restart): the future says nothing about it.
        out[t] = normalised(mine).map_or_else(|| weights[t].clone(), |(w, _)| w);
    }
    out
}

/// A candidate motion's re-weighted filter: its scale, every frame's weights and its evidence
/// gain.
struct Reweighted {
    scale: f32,
    weights: Vec<Vec<f64>>,
    gain: f64,
}

/// The median over frames of the re-weighted filter's effective sample size against the
/// filter's own.
fn kept_sample_size(weights: &[Vec<f64>], filtered: &[Vec<f64>]) -> f64 {
    let kept: Vec<f64> = (weights.iter().zip(filtered))
        .map(|(w, f)| effective_sample_size(w) / effective_sample_size(f))
        .collect();
    median_kept(&kept)
}

/// The median of each frame's kept share of the effective sample size (0 for none).
fn median_kept(kept: &[f64]) -> f64 {
    let mut kept = kept.to_vec();
    kept.sort_by(f64::total_cmp);
    kept.get(kept.len() / 2).copied().unwrap_or(0.0)
}

/// The motion with the most evidence for one value's `frames` among those that keep at least
/// [`MIN_KEPT_SAMPLE_SIZE`] of the filter's effective sample size (ties to the larger: the
/// candidates come largest first) and the filter's weights re-weighted to it. Scale 1 always
/// has an outcome, the filter's own weights.
fn choose(frames: &ValueFrames, tracker_sigma: f64) -> (MotionChoice, Vec<Vec<f64>>) {
    // The filter's own predictive density at each frame's particles, which every candidate
    // divides by.
    let tracker_predictive: Vec<Vec<f64>> = (frames.pairs.par_iter().zip(&frames.weights))
        .map(|((from, to), weights)| gauss_transform(from, weights, to, tracker_sigma))
        .collect();
    let tracker = (tracker_sigma, tracker_predictive.as_slice());
    let tried: Vec<Reweighted> = (CANDIDATE_SCALES.par_iter())
        .filter_map(|&scale| {
            let (weights, gain) = if scale == 1.0 {
                (frames.weights.clone(), 0.0)
            } else {
                let (weights, gain) =
                    reweighted(frames, tracker, tracker_sigma * f64::from(scale))?;
                if kept_sample_size(&weights, &frames.weights) < MIN_KEPT_SAMPLE_SIZE {
                    return None;
                }
                (weights, gain)
            };
            Some(Reweighted {
                scale,
                weights,
                gain,
            })
        })
        .collect();
    let best =
        (tried.into_iter()).reduce(|best, next| if next.gain > best.gain { next } else { best });
    match best {
        Some(Reweighted {
            scale,
            weights,
            gain,
        }) => (
            MotionChoice {
                scale,
                log_evidence_gain: gain,
            },
            weights,
        ),
        None => (
            MotionChoice {
                scale: 1.0,
                log_evidence_gain: 0.0,
            },
            frames.weights.clone(),
        ),
    }
}

/// `chosen`'s mean with its interval widened to take in `own`'s (an angle's moved by whole turns
/// to lie nearest `chosen`'s mean first).
fn widened(chosen: Summary, own: Summary, angular: bool) -> Summary {
    let shift = if angular {
        let middle = 0.5 * (own.lower + own.upper);
        std::f32::consts::TAU * ((chosen.mean - middle) / std::f32::consts::TAU).round()
    } else {
        0.0
    };
    Summary {
        mean: chosen.mean,
        lower: chosen.lower.min(own.lower + shift),
        upper: chosen.upper.max(own.upper + shift),
    }
}

/// Every frame's smoothed summary (`[frame][value]`) with each value's motion chosen by the
/// evidence among [`CANDIDATE_SCALES`] of `transition`'s σ, and the choices (`[value]`).
///
/// The mean is the chosen motion's smoothed mean. The 95 % interval takes in both the chosen
/// motion's and the tracker's own motion's smoothed intervals: the evidence weighs each frame's
/// error as its own, and a tracker's errors persist from frame to frame (a template's misfit),
/// which it cannot see. On the synthetic faces the chosen motion's own intervals held the truth
/// 77-96 % of the time, the tracker's motion's 93-98 % (docs/POSTERIOR.md).
pub fn smooth_values_by_evidence(
    frames: &[Cloud],
    transition: &GaussianTransition,
) -> Result<(Vec<Vec<Summary>>, Vec<MotionChoice>), PfError> {
    for cloud in frames {
        transition.validate(cloud)?;
    }
    if frames.is_empty() {
        return Ok((Vec::new(), Vec::new()));
    }
    let dims = transition.sigma.len();
    let per_value: Vec<(MotionChoice, Vec<Summary>)> = (0..dims)
        .into_par_iter()
        .map(|d| {
            let sigma = f64::from(transition.sigma[d]);
            let angular = transition.angular[d];
            if sigma <= 0.0 {
                let still = MotionChoice {
                    scale: 1.0,
                    log_evidence_gain: 0.0,
                };
                let summaries = (frames.iter())
                    .map(|cloud| value_summary(cloud, &cloud.weights, &transition.angular, d))
                    .collect();
                return (still, summaries);
            }
            let values = ValueFrames::new(frames, d, angular);
            let (choice, forward) = choose(&values, sigma);
            let chosen = smoothed(&values, &forward, sigma * f64::from(choice.scale));
            // The tracker's own motion's smoothing, whose intervals each chosen one is widened
            // to take in (below); the same weights when the evidence chose it.
            let own = if choice.scale == 1.0 {
                None
            } else {
                Some(smoothed(&values, &values.weights, sigma))
            };
            let summaries = (0..frames.len())
                .map(|t| {
                    let mine = value_summary(&frames[t], &chosen[t], &transition.angular, d);
                    match &own {
                        Some(own) => {
                            let wide = value_summary(&frames[t], &own[t], &transition.angular, d);
                            widened(mine, wide, angular)
                        }
                        None => mine,
                    }
                })
                .collect();
            (choice, summaries)
        })
        .collect();
    let mut rows: Vec<Vec<Summary>> = vec![Vec::with_capacity(dims); frames.len()];
    let mut choices = Vec::with_capacity(dims);
    for (choice, summaries) in per_value {
        choices.push(choice);
        for (row, s) in rows.iter_mut().zip(summaries) {
            row.push(s);
        }
    }
    Ok((rows, choices))
}

/// A [`ValueSmoother`] whose motion the evidence chooses, value by value and track by track
/// ([`smooth_values_by_evidence`], on the CPU's cores), keeping every choice it made for the
/// run's report ([`EvidenceMotion::choices`]).
#[derive(Debug, Default)]
pub struct EvidenceMotion {
    choices: std::sync::Mutex<Vec<Vec<MotionChoice>>>,
}

impl EvidenceMotion {
    /// Every track's choices so far (`[track smoothed][value]`, in the order they were smoothed).
    pub fn choices(&self) -> Vec<Vec<MotionChoice>> {
        self.choices.lock().map(|c| c.clone()).unwrap_or_default()
    }

    /// Keeps one track's `choices` for the report (a lag smoother's, made as its frames came:
    /// [`OnlineMotion`]).
    pub fn record(&self, choices: Vec<MotionChoice>) {
        if let Ok(mut all) = self.choices.lock() {
            all.push(choices);
        }
    }

    /// The median chosen scale of each of `dims` values over the tracks smoothed (`None` before
    /// any): the run's one-line report.
    pub fn median_scales(&self, dims: usize) -> Option<Vec<f32>> {
        let all = self.choices();
        if all.is_empty() {
            return None;
        }
        Some(
            (0..dims)
                .map(|d| {
                    let mut s: Vec<f32> = all
                        .iter()
                        .filter_map(|c| c.get(d))
                        .map(|c| c.scale)
                        .collect();
                    s.sort_by(f32::total_cmp);
                    s.get(s.len() / 2).copied().unwrap_or(1.0)
                })
                .collect(),
        )
    }
}

impl ValueSmoother for EvidenceMotion {
    fn smooth_values(
        &self,
        frames: &[Cloud],
        transition: &GaussianTransition,
    ) -> Result<Vec<Vec<Summary>>, PfError> {
        let (rows, choices) = smooth_values_by_evidence(frames, transition)?;
        if let Ok(mut all) = self.choices.lock() {
            all.push(choices);
        }
        Ok(rows)
    }

    /// Each window's first frame at the motion the window's own evidence chooses. Few frames
    /// choose poorly (the synthetic faces at a lag of 10 smoothed worse than the filter), so
    /// `--smooth-lag L --smooth-motion auto` chooses by the evidence of the track's frames so
    /// far instead ([`OnlineMotion`], which `TrackSmoother::choosing_motion_by_evidence` keeps
    /// per track); this stays for a caller that has windows alone.
    fn smooth_first_many(
        &self,
        tracks: &[&[Cloud]],
        transition: &GaussianTransition,
    ) -> Result<Vec<Vec<Summary>>, PfError> {
        (tracks.iter())
            .map(|frames| {
                let (mut rows, _) = smooth_values_by_evidence(frames, transition)?;
                if rows.is_empty() {
                    return Err(PfError::InvalidConfig("smoothing an empty window".into()));
                }
                Ok(rows.swap_remove(0))
            })
            .collect()
    }
}

/// How far a smoother lets a value move between frames: a fixed share of the tracker's σ
/// ([`GaussianTransition::with_motion`]) or each value's chosen by the evidence
/// ([`EvidenceMotion`]). What `--smooth-motion` and Python's `smooth_motion=` take.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SmoothMotion {
    /// The tracker's σ times this scale (within [`super::MOTION_SCALES`]).
    Scale(f32),
    /// Each value's scale chosen by the evidence among [`CANDIDATE_SCALES`].
    ByEvidence,
}

impl SmoothMotion {
    /// `auto`, or a scale within [`super::MOTION_SCALES`]; else an error that says which.
    pub fn parse(text: &str) -> Result<Self, PfError> {
        if text.trim().eq_ignore_ascii_case("auto") {
            return Ok(Self::ByEvidence);
        }
        let scale: f32 = text.trim().parse().map_err(|_| {
            PfError::InvalidConfig(format!(
                "the smoother's motion is `auto` or a scale of the tracker's, not `{text}`"
            ))
        })?;
        Ok(Self::Scale(super::checked_motion_scale(scale)?))
    }

    /// `transition` with this motion's scale applied (the evidence's choices are made per value
    /// when the tracks are smoothed, so `ByEvidence` leaves it as it is).
    pub fn apply(self, transition: GaussianTransition) -> Result<GaussianTransition, PfError> {
        match self {
            Self::Scale(scale) => transition.with_motion(scale),
            Self::ByEvidence => Ok(transition),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_motion_is_auto_or_a_scale_in_range() {
        assert_eq!(
            SmoothMotion::parse("auto").unwrap(),
            SmoothMotion::ByEvidence
        );
        assert_eq!(
            SmoothMotion::parse(" AUTO ").unwrap(),
            SmoothMotion::ByEvidence
        );
        assert_eq!(
            SmoothMotion::parse("0.25").unwrap(),
            SmoothMotion::Scale(0.25)
        );
        for bad in ["", "fast", "0", "-1", "1e9", "nan", "inf"] {
            let e = SmoothMotion::parse(bad).unwrap_err().to_string();
            assert!(e.contains("auto") || e.contains("must lie"), "{bad}: {e}");
        }
    }

    /// Cut weights: a cloud that jumps where the tracker's motion cannot reach starts afresh
    /// (its filtered weights), and a value that does not move keeps its filtered weights.
    #[test]
    fn a_jump_out_of_reach_and_a_still_value_keep_their_filtered_weights() {
        let cloud = |x: f32| Cloud {
            states: vec![x, x + 0.1, x - 0.1, 5.0, 5.0, 5.0],
            weights: vec![0.5, 0.25, 0.25],
            drift: vec![0.0, 0.0],
        };
        let frames = vec![cloud(0.0), cloud(0.05), cloud(1e4), cloud(1e4 + 0.05)];
        let transition = GaussianTransition {
            sigma: vec![0.1, 0.0],
            angular: vec![false, false],
        };
        let (rows, choices) = smooth_values_by_evidence(&frames, &transition).unwrap();
        assert_eq!(rows.len(), 4);
        assert_eq!(choices[1].scale, 1.0);
        assert!(choices[0].log_evidence_gain.is_finite());
        for row in &rows {
            assert_eq!(row[1].mean, 5.0);
            assert!(row[0].mean.is_finite());
        }
        // Neither side of the jump is dragged toward the other.
        assert!(rows[1][0].mean.abs() < 1.0, "{:?}", rows[1][0]);
        assert!((rows[2][0].mean - 1e4).abs() < 0.2, "{:?}", rows[2][0]);
    }
}
