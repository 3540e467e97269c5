//! Smoothing tracks as they are filtered ([`TrackSmoother`]): each track's filtered clouds and
//! the drift of its dynamics kept as frames arrive, smoothed by [`crate::smooth`]'s marginal
//! smoother when the track ends (or the run does) or, with a lag of L frames, L frames behind;
//! and how often intervals hold the truth ([`Coverage`]). The command line's `--smooth` writes
//! these rows to smoothed.csv; Python's trackers return them.

use std::collections::{BTreeMap, VecDeque};
use std::sync::Arc;

use crate::error::PfError;
use crate::smooth::{
    Cloud, CpuSmoother, GaussianTransition, Summary, TargetParticles, ValueSmoother, summarise,
};

/// One smoothed row: a track's values at a frame, smoothed and (to compare) as filtered.
#[derive(Debug, Clone)]
pub struct SmoothedRow {
    /// The frame it smooths.
    pub frame: usize,
    /// The track (target) it belongs to.
    pub track: usize,
    /// Each value's smoothed mean and 95 % interval.
    pub values: Vec<Summary>,
    /// The same particles under their filtered weights: the filter's weighted mean and interval.
    pub filtered: Vec<Summary>,
}

/// A track's frames waiting to be smoothed, and its last filtered mean (for the drift).
#[derive(Default, Clone)]
struct TrackFrames {
    frames: VecDeque<(usize, Cloud)>,
    last_mean: Option<Vec<f32>>,
}

/// The smoothing of tracks as they are filtered, without I/O (the CLI's `Smoother` writes its
/// rows to smoothed.csv; Python's trackers return them): each track's filtered clouds and their
/// drift, smoothed when the track ends (or the run does) or, with a lag, L frames behind.
#[derive(Clone)]
pub struct TrackSmoother {
    lag: Option<usize>,
    /// The dynamics' density. Each value is smoothed as its own block
    /// (`pf_core::smooth::smooth_values`): on the synthetic walk (400 samples, CPU) the 38 body
    /// values smoothed at once collapsed the backward weights onto a few samples (joint error
    /// 3.5 → 4.7 cm, the intervals holding the truth for 12 % of the values); value by value
    /// they do not (3.6 cm, 56 %), and the face gains a little too.
    transition: GaussianTransition,
    /// The constant-velocity gain: the drift into the next frame is this × the last motion.
    gain: f32,
    tracks: BTreeMap<usize, TrackFrames>,
    /// Where the smoothing runs: the CPU unless [`TrackSmoother::on`] says otherwise.
    backend: Arc<dyn ValueSmoother>,
}

impl TrackSmoother {
    /// Smoothing with `lag` (`None`: each track whole) under `transition`, the dynamics adding
    /// `gain` × each track's last motion.
    pub fn new(lag: Option<usize>, transition: GaussianTransition, gain: f32) -> Self {
        Self {
            lag,
            transition,
            gain,
            tracks: BTreeMap::new(),
            backend: Arc::new(CpuSmoother),
        }
    }

    /// The same smoother running its backward passes on `backend` (a GPU's, say).
    pub fn on(self, backend: Arc<dyn ValueSmoother>) -> Self {
        Self { backend, ..self }
    }

    /// The dynamics' density the smoother reweighs by.
    pub fn transition(&self) -> &GaussianTransition {
        &self.transition
    }

    /// Frame `frame`'s filtered clouds, `(track, states [d·M + m], log-weights [m])` of each
    /// tracked target; a track that is not among them has ended and is smoothed to its end.
    /// Returns the rows smoothed. The tracks' windows (and the ended tracks) go to the backend
    /// together, in one call each.
    pub fn add_frame(
        &mut self,
        frame: usize,
        clouds: Vec<TargetParticles>,
    ) -> Result<Vec<SmoothedRow>, PfError> {
        let seen: Vec<usize> = clouds.iter().map(|(track, ..)| *track).collect();
        let ended: Vec<usize> = (self.tracks.keys())
            .filter(|t| !seen.contains(t))
            .copied()
            .collect();
        let mut rows = self.flush_tracks(&ended)?;
        let mut due = Vec::new();
        for (track, states, log_weights) in clouds {
            if self.add_cloud(frame, track, &states, &log_weights)? {
                due.push(track);
            }
        }
        rows.extend(self.smooth_windows(&due)?);
        Ok(rows)
    }

    /// Smooths every track's frames still waiting (at the end of the run, however it ended).
    pub fn finish(&mut self) -> Result<Vec<SmoothedRow>, PfError> {
        let tracks: Vec<usize> = self.tracks.keys().copied().collect();
        self.flush_tracks(&tracks)
    }

    /// One track's cloud at `frame`, with its drift; whether its lag window is now full (its
    /// first frame is due).
    fn add_cloud(
        &mut self,
        frame: usize,
        track: usize,
        states: &[f32],
        log_weights: &[f32],
    ) -> Result<bool, PfError> {
        let dims = self.transition.sigma.len();
        let mut cloud = Cloud::of_target(
            dims,
            log_weights.len(),
            0,
            states,
            log_weights,
            vec![0.0; dims],
        )?;
        let mean: Vec<f32> = (summarise(&cloud, &cloud.weights, &self.transition.angular)?)
            .iter()
            .map(|s| s.mean)
            .collect();
        let entry = self.tracks.entry(track).or_default();
        cloud.drift = drift(
            self.gain,
            entry.last_mean.as_deref(),
            &mean,
            &self.transition.angular,
        );
        entry.last_mean = Some(mean);
        entry.frames.push_back((frame, cloud));
        Ok(self.lag.is_some_and(|lag| entry.frames.len() > lag))
    }

    /// The first frame of each of `tracks`' full lag windows, smoothed by the window (all
    /// windows in one call), and dropped from the window.
    fn smooth_windows(&mut self, tracks: &[usize]) -> Result<Vec<SmoothedRow>, PfError> {
        let windows: Vec<Vec<Cloud>> = (tracks.iter())
            .filter_map(|t| self.tracks.get(t))
            .map(|w| w.frames.iter().map(|(_, c)| c.clone()).collect())
            .collect();
        let views: Vec<&[Cloud]> = windows.iter().map(Vec::as_slice).collect();
        let values = self.backend.smooth_first_many(&views, &self.transition)?;
        let lag_window = || PfError::InvalidConfig("an empty lag window".into());
        let mut rows = Vec::with_capacity(tracks.len());
        for (&track, first_values) in tracks.iter().zip(values) {
            let entry = self.tracks.get_mut(&track).ok_or_else(lag_window)?;
            let (first_frame, first) = entry.frames.pop_front().ok_or_else(lag_window)?;
            rows.push(self.row(first_frame, track, &first, first_values)?);
        }
        Ok(rows)
    }

    /// Every frame `tracks` still hold, smoothed (all of them in one call), the tracks ended.
    fn flush_tracks(&mut self, tracks: &[usize]) -> Result<Vec<SmoothedRow>, PfError> {
        let waiting: Vec<(usize, TrackFrames)> = (tracks.iter())
            .filter_map(|t| self.tracks.remove(t).map(|w| (*t, w)))
            .collect();
        let clouds: Vec<Vec<Cloud>> = (waiting.iter())
            .map(|(_, w)| w.frames.iter().map(|(_, c)| c.clone()).collect())
            .collect();
        let views: Vec<&[Cloud]> = clouds.iter().map(Vec::as_slice).collect();
        let values = self.backend.smooth_many(&views, &self.transition)?;
        let mut rows = Vec::new();
        for ((track, w), track_values) in waiting.iter().zip(values) {
            for ((frame, cloud), v) in w.frames.iter().zip(track_values) {
                rows.push(self.row(*frame, *track, cloud, v)?);
            }
        }
        Ok(rows)
    }

    /// A row of smoothed `values`, the same particles' filtered summary beside them.
    fn row(
        &self,
        frame: usize,
        track: usize,
        cloud: &Cloud,
        values: Vec<Summary>,
    ) -> Result<SmoothedRow, PfError> {
        Ok(SmoothedRow {
            frame,
            track,
            values,
            filtered: summarise(cloud, &cloud.weights, &self.transition.angular)?,
        })
    }
}

/// The drift the dynamics add on the way to the next frame: `gain` × the last motion of the
/// filtered mean (angles the short way round); none for a track's first frame.
fn drift(gain: f32, previous: Option<&[f32]>, mean: &[f32], angular: &[bool]) -> Vec<f32> {
    match previous {
        Some(previous) if gain > 0.0 => (mean.iter().zip(previous).zip(angular))
            .map(|((&now, &before), &angle)| {
                let motion = now - before;
                gain * if angle {
                    crate::batch::wrap_angle_floor(motion)
                } else {
                    motion
                }
            })
            .collect(),
        _ => vec![0.0; mean.len()],
    }
}

/// How often the truth lay within the smoothed 95 % interval, per value (angles wrapped), and
/// the count of rows compared.
#[derive(Default)]
pub struct Coverage {
    /// Per value, the rows whose interval held the truth.
    pub within: Vec<usize>,
    /// The rows compared.
    pub rows: usize,
}

impl Coverage {
    /// Adds one row against its true values.
    pub fn add(&mut self, values: &[Summary], truth: &[f32], angular: &[bool]) {
        if self.within.len() != values.len() {
            self.within = vec![0; values.len()];
        }
        for (d, (s, &t)) in values.iter().zip(truth).enumerate() {
            let offset = |x: f32| {
                let e = t - x;
                if angular.get(d).copied().unwrap_or(false) {
                    crate::batch::wrap_angle_floor(e)
                } else {
                    e
                }
            };
            // The truth from the mean, within the interval's reach on each side.
            let from_mean = offset(s.mean);
            if from_mean >= s.lower - s.mean && from_mean <= s.upper - s.mean {
                self.within[d] += 1;
            }
        }
        self.rows += 1;
    }

    /// Each value's share within its interval, in percent.
    pub fn percent(&self) -> Vec<f64> {
        (self.within.iter())
            .map(|&w| 100.0 * w as f64 / self.rows.max(1) as f64)
            .collect()
    }
}
