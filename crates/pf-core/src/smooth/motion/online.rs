//! The smoother's motion chosen by the evidence as frames arrive, for a fixed-lag smoother
//! (`--smooth-lag L --smooth-motion auto`).
//!
//! The forward half of [`super::smooth_values_by_evidence`] (each candidate motion's re-weighted
//! filter and the evidence it gains) runs frame by frame, so a fixed-lag smoother can choose each
//! value's motion by the evidence of every frame of the track so far, not of its window alone: a
//! window's L frames chose poorly (the synthetic faces at a lag of 10 smoothed worse than the
//! filter). [`OnlineMotion`] keeps one track's evidence, and each candidate's re-weighted weights
//! for the frames of the window still to be smoothed; a window's first frame is smoothed by the
//! marginal smoother under the motion chosen so far, with the candidate's re-weighted weights as
//! its forward filter, its interval widened to take in the tracker's motion's, as the whole-track
//! choice does. Fed a whole track and asked at its end, it chooses what
//! [`super::smooth_values_by_evidence`] chooses (the same arithmetic in the same order).

use std::collections::VecDeque;

use rayon::prelude::*;

use super::value_summary;
use super::{
    CANDIDATE_SCALES, MIN_KEPT_SAMPLE_SIZE, MotionChoice, ValueFrames, median_kept, reweigh_frame,
    smoothed, value_pair, widened,
};
use crate::error::PfError;
use crate::smooth::{Cloud, GaussianTransition, Summary};
use crate::weights::effective_sample_size;

/// One candidate motion of one value: the evidence it gained, the share of the filter's
/// effective sample size it kept at each frame, its re-weighted weights at each frame still in
/// the window (the front: the window's first) and at the last frame (the next frame's chain
/// goes on from them, whether or not the window still holds it).
#[derive(Debug, Clone)]
struct Candidate {
    gain: f64,
    kept: Vec<f64>,
    window: VecDeque<Vec<f64>>,
    last: Option<Vec<f64>>,
}

/// One value's evidence so far.
#[derive(Debug, Clone, Default)]
struct ValueEvidence {
    /// The last frame's values moved by its drift (the next pair's sources) and its filtered
    /// weights; `None` before the first frame.
    last: Option<(Vec<f64>, Vec<f64>)>,
    /// One per [`CANDIDATE_SCALES`] (the tracker's own motion first, whose weights are the
    /// filter's); `None` once the motion cannot explain some frame the tracker's can.
    candidates: Vec<Option<Candidate>>,
}

/// One track's evidence for each candidate motion of each value, frame by frame.
#[derive(Debug, Clone)]
pub struct OnlineMotion {
    transition: GaussianTransition,
    values: Vec<ValueEvidence>,
}

impl OnlineMotion {
    /// No frames yet, for values moving by `transition` (the tracker's).
    pub fn new(transition: GaussianTransition) -> Self {
        let fresh = ValueEvidence {
            last: None,
            candidates: vec![
                Some(Candidate {
                    gain: 0.0,
                    kept: Vec::new(),
                    window: VecDeque::new(),
                    last: None,
                });
                CANDIDATE_SCALES.len()
            ],
        };
        let values = vec![fresh; transition.sigma.len()];
        Self { transition, values }
    }

    /// The frames in the window (pushed and not yet smoothed).
    pub fn waiting(&self) -> usize {
        (self.values.first())
            .and_then(|v| v.candidates[0].as_ref())
            .map_or(0, |c| c.window.len())
    }

    /// The track's next filtered frame: every candidate re-weighted to it.
    pub fn push(&mut self, cloud: &Cloud) -> Result<(), PfError> {
        self.transition.validate(cloud)?;
        let transition = &self.transition;
        (self.values.par_iter_mut().enumerate()).for_each(|(d, value)| {
            let sigma = f64::from(transition.sigma[d]);
            value.push(cloud, d, sigma, transition.angular[d]);
        });
        Ok(())
    }

    /// Each value's motion as the evidence of the frames so far chooses it.
    pub fn choices(&self) -> Vec<MotionChoice> {
        self.values.iter().map(ValueEvidence::choice).collect()
    }

    /// The window's first frame smoothed by the frames after it in `window` (the frames pushed
    /// and not yet smoothed, in order), each value under the motion chosen so far; the frame is
    /// then dropped from the window.
    pub fn smooth_first(&mut self, window: &[Cloud]) -> Result<Vec<Summary>, PfError> {
        let rows = self.smooth_window(window, true)?;
        for value in &mut self.values {
            for candidate in value.candidates.iter_mut().flatten() {
                candidate.window.pop_front();
            }
        }
        rows.into_iter()
            .next()
            .ok_or_else(|| PfError::InvalidConfig("smoothing an empty window".into()))
    }

    /// Every frame of `window` (the frames pushed and not yet smoothed) smoothed under the
    /// motion chosen so far, `[frame][value]`: the end of a track.
    pub fn smooth_all(&self, window: &[Cloud]) -> Result<Vec<Vec<Summary>>, PfError> {
        self.smooth_window(window, false)
    }

    fn smooth_window(
        &self,
        window: &[Cloud],
        first_only: bool,
    ) -> Result<Vec<Vec<Summary>>, PfError> {
        if window.is_empty() || window.len() != self.waiting() {
            return Err(PfError::InvalidConfig(format!(
                "a window of {} frames, where the evidence holds {}",
                window.len(),
                self.waiting()
            )));
        }
        for cloud in window {
            self.transition.validate(cloud)?;
        }
        let frames = if first_only { 1 } else { window.len() };
        let per_value: Vec<Vec<Summary>> = (self.values.par_iter().enumerate())
            .map(|(d, value)| value.smooth(window, d, &self.transition, frames))
            .collect();
        Ok((0..frames)
            .map(|t| per_value.iter().map(|v| v[t]).collect())
            .collect())
    }
}

impl ValueEvidence {
    /// Frame `cloud`'s value `d`: each living candidate re-weighted to it and its evidence added
    /// (a frame the tracker's motion cannot reach starts every chain afresh, no evidence either
    /// way, as the whole-track choice does).
    fn push(&mut self, cloud: &Cloud, d: usize, sigma: f64, angular: bool) {
        let m = cloud.particles();
        let values: Vec<f64> = (cloud.states[d * m..(d + 1) * m].iter())
            .map(|&x| f64::from(x))
            .collect();
        let filtered = &cloud.weights;
        let pair = (self.last.as_ref()).map(|(from, _)| value_pair(from, &values, angular));
        let tracker = match (&pair, &self.last) {
            (Some(pair), Some((_, previous))) if sigma > 0.0 => {
                Some(super::gauss_transform(&pair.0, previous, &pair.1, sigma))
            }
            _ => None,
        };
        let reachable = tracker
            .as_ref()
            .is_some_and(|t| t.iter().any(|p| *p != 0.0));
        for (k, slot) in self.candidates.iter_mut().enumerate() {
            let Some(candidate) = slot else { continue };
            let scale = CANDIDATE_SCALES[k];
            let next = match (&pair, &tracker, &candidate.last) {
                (Some(pair), Some(tracker), Some(previous)) if reachable && scale != 1.0 => {
                    let Some((next, gain)) = reweigh_frame(
                        pair,
                        previous,
                        filtered,
                        tracker,
                        (sigma, sigma * f64::from(scale)),
                    ) else {
                        *slot = None;
                        continue;
                    };
                    candidate.gain += gain;
                    next
                }
                _ => filtered.clone(),
            };
            candidate
                .kept
                .push(effective_sample_size(&next) / effective_sample_size(filtered));
            candidate.window.push_back(next.clone());
            candidate.last = Some(next);
        }
        let drift = f64::from(cloud.drift[d]);
        self.last = Some((values.iter().map(|x| x + drift).collect(), filtered.clone()));
    }

    /// The motion with the most evidence so far among those that keep at least
    /// [`MIN_KEPT_SAMPLE_SIZE`] of the filter's effective sample size (ties to the larger).
    fn choice(&self) -> MotionChoice {
        let own = MotionChoice {
            scale: 1.0,
            log_evidence_gain: 0.0,
        };
        (self.candidates.iter().enumerate())
            .skip(1)
            .filter_map(|(k, c)| c.as_ref().map(|c| (CANDIDATE_SCALES[k], c)))
            .filter(|(_, c)| median_kept(&c.kept) >= MIN_KEPT_SAMPLE_SIZE)
            .map(|(scale, c)| MotionChoice {
                scale,
                log_evidence_gain: c.gain,
            })
            .fold(own, |best, next| {
                if next.log_evidence_gain > best.log_evidence_gain {
                    next
                } else {
                    best
                }
            })
    }

    /// The first `frames` frames of `window` smoothed for value `d` under the chosen motion.
    fn smooth(
        &self,
        window: &[Cloud],
        d: usize,
        transition: &GaussianTransition,
        frames: usize,
    ) -> Vec<Summary> {
        let sigma = f64::from(transition.sigma[d]);
        let angular = &transition.angular;
        if sigma <= 0.0 {
            return (window.iter().take(frames))
                .map(|cloud| value_summary(cloud, &cloud.weights, angular, d))
                .collect();
        }
        let choice = self.choice();
        let index = (CANDIDATE_SCALES.iter())
            .position(|&s| s == choice.scale)
            .unwrap_or(0);
        let values = ValueFrames::new(window, d, angular[d]);
        let forward: Vec<Vec<f64>> = match &self.candidates[index] {
            Some(c) => c.window.iter().cloned().collect(),
            None => values.weights.clone(),
        };
        let chosen = smoothed(&values, &forward, sigma * f64::from(choice.scale));
        let own = (choice.scale != 1.0).then(|| smoothed(&values, &values.weights, sigma));
        (0..frames)
            .map(|t| {
                let mine = value_summary(&window[t], &chosen[t], angular, d);
                match &own {
                    Some(own) => widened(
                        mine,
                        value_summary(&window[t], &own[t], angular, d),
                        angular[d],
                    ),
                    None => mine,
                }
            })
            .collect()
    }
}
