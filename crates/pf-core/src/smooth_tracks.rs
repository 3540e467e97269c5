//! Smoothing tracks as they are filtered ([`TrackSmoother`]): each track's filtered clouds and
//! the drift of its dynamics kept as frames arrive, smoothed by [`crate::smooth`]'s marginal
//! smoother when the track ends (or the run does), or, with a lag of L frames, L frames behind
//! from the particles' ancestry ([`crate::smooth::ancestry`]: the engine's lineage of each
//! frame); and how often intervals hold the truth ([`Coverage`]). The command line's `--smooth` writes
//! these rows to smoothed.csv; Python's trackers return them.

use std::collections::{BTreeMap, VecDeque};
use std::sync::Arc;

use crate::error::PfError;
use crate::smooth::ancestry::{trace_back, traceable};
use crate::smooth::{
    Cloud, CpuSmoother, GaussianTransition, Summary, TargetParticles, ValueSmoother, summarise,
};

/// One tracked target's particles at a frame, as a tracker hands them to [`TrackSmoother`].
#[derive(Debug, Clone)]
pub struct TrackCloud {
    /// The track (target) they belong to.
    pub track: usize,
    /// The states, `[d·M + m]`.
    pub states: Vec<f32>,
    /// The normalised log-weights, `[m]`.
    pub log_weights: Vec<f32>,
    /// Each particle's ancestor among the track's particles of the frame before (the engine's
    /// lineage, `pf_gpu::FilterEngine::lineage`); `None` where the engine did not keep it. A
    /// lagged smoother needs it.
    pub lineage: Option<Vec<u32>>,
}

impl From<TargetParticles> for TrackCloud {
    fn from((track, states, log_weights): TargetParticles) -> Self {
        Self {
            track,
            states,
            log_weights,
            lineage: None,
        }
    }
}

/// A frame waiting in a track's window: its number, its cloud and its lineage.
#[derive(Clone)]
struct WaitingFrame {
    frame: usize,
    cloud: Cloud,
    lineage: Option<Vec<u32>>,
}

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
    frames: VecDeque<WaitingFrame>,
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

    /// Frame `frame`'s filtered clouds, one for each tracked target; a track that is not among
    /// them has ended and is smoothed to its end. Returns the rows smoothed. Whole tracks go to
    /// the backend together, in one call. With a lag, each cloud needs its lineage: a track whose
    /// lineage names no ancestors (restarted from new particles) is smoothed up to the restart
    /// and starts a new window.
    pub fn add_frame(
        &mut self,
        frame: usize,
        clouds: Vec<TrackCloud>,
    ) -> Result<Vec<SmoothedRow>, PfError> {
        let seen: Vec<usize> = clouds.iter().map(|c| c.track).collect();
        let ended: Vec<usize> = (self.tracks.keys())
            .filter(|t| !seen.contains(t))
            .copied()
            .collect();
        let mut rows = self.flush_tracks(&ended)?;
        for cloud in clouds {
            rows.extend(self.add_cloud(frame, cloud)?);
        }
        Ok(rows)
    }

    /// Smooths every track's frames still waiting (at the end of the run, however it ended).
    pub fn finish(&mut self) -> Result<Vec<SmoothedRow>, PfError> {
        let tracks: Vec<usize> = self.tracks.keys().copied().collect();
        self.flush_tracks(&tracks)
    }

    /// One track's cloud at `frame`, with its drift; the rows it makes due (with a lag: the
    /// window's first frame once the window is full, or the whole window cut at a restart).
    fn add_cloud(
        &mut self,
        frame: usize,
        TrackCloud {
            track,
            states,
            log_weights,
            lineage,
        }: TrackCloud,
    ) -> Result<Vec<SmoothedRow>, PfError> {
        let dims = self.transition.sigma.len();
        let mut rows = Vec::new();
        if self.lag.is_some()
            && self
                .tracks
                .get(&track)
                .is_some_and(|w| !w.frames.is_empty())
        {
            let lineage = lineage.as_deref().ok_or_else(|| {
                PfError::InvalidConfig(format!(
                    "smoothing with a lag traces each frame's lineage; track {track}'s frame {frame} came without it (keep the engine's lineage)"
                ))
            })?;
            if !traceable(lineage) {
                rows = self.flush_tracks(&[track])?;
            }
        }
        let mut cloud = Cloud::of_target(
            dims,
            log_weights.len(),
            0,
            &states,
            &log_weights,
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
        entry.frames.push_back(WaitingFrame {
            frame,
            cloud,
            lineage,
        });
        if self.lag.is_some_and(|lag| entry.frames.len() > lag) {
            rows.push(self.smooth_first_by_ancestry(track)?);
        }
        Ok(rows)
    }

    /// The first frame of `track`'s full lag window, smoothed by its descendants' weights in the
    /// window's last frame (traced back through the lineages), and dropped from the window.
    fn smooth_first_by_ancestry(&mut self, track: usize) -> Result<SmoothedRow, PfError> {
        let lag_window = || PfError::InvalidConfig(format!("track {track}: an empty lag window"));
        let window = self.tracks.get(&track).ok_or_else(lag_window)?;
        let weights = ancestry_weights(&window.frames)?;
        let first_weights = weights.into_iter().next().ok_or_else(lag_window)?;
        let entry = self.tracks.get_mut(&track).ok_or_else(lag_window)?;
        let first = entry.frames.pop_front().ok_or_else(lag_window)?;
        self.row(first.frame, track, &first.cloud, &first_weights)
    }

    /// Every frame `tracks` still hold, smoothed, the tracks ended: by the marginal smoother
    /// (all tracks in one backend call), or with a lag by each track's ancestry.
    fn flush_tracks(&mut self, tracks: &[usize]) -> Result<Vec<SmoothedRow>, PfError> {
        let waiting: Vec<(usize, TrackFrames)> = (tracks.iter())
            .filter_map(|t| self.tracks.remove(t).map(|w| (*t, w)))
            .collect();
        let mut rows = Vec::new();
        if self.lag.is_some() {
            for (track, w) in &waiting {
                let weights = ancestry_weights(&w.frames)?;
                for (f, weights) in w.frames.iter().zip(&weights) {
                    rows.push(self.row(f.frame, *track, &f.cloud, weights)?);
                }
            }
            return Ok(rows);
        }
        let clouds: Vec<Vec<Cloud>> = (waiting.iter())
            .map(|(_, w)| w.frames.iter().map(|f| f.cloud.clone()).collect())
            .collect();
        let views: Vec<&[Cloud]> = clouds.iter().map(Vec::as_slice).collect();
        let values = self.backend.smooth_many(&views, &self.transition)?;
        for ((track, w), track_values) in waiting.iter().zip(values) {
            for (f, v) in w.frames.iter().zip(track_values) {
                rows.push(self.summarised_row(f.frame, *track, &f.cloud, v)?);
            }
        }
        Ok(rows)
    }

    /// A row of `cloud` smoothed by `weights`, its filtered summary beside them.
    fn row(
        &self,
        frame: usize,
        track: usize,
        cloud: &Cloud,
        weights: &[f64],
    ) -> Result<SmoothedRow, PfError> {
        let values = summarise(cloud, weights, &self.transition.angular)?;
        self.summarised_row(frame, track, cloud, values)
    }

    /// A row of smoothed `values`, the same particles' filtered summary beside them.
    fn summarised_row(
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

/// Each waiting frame's weights smoothed by the last frame's, traced back through the frames'
/// lineages (the first frame's lineage, into the frame before the window, is not used).
fn ancestry_weights(frames: &VecDeque<WaitingFrame>) -> Result<Vec<Vec<f64>>, PfError> {
    let Some(last) = frames.back() else {
        return Ok(Vec::new());
    };
    let lineages = (frames.iter().skip(1))
        .map(|f| {
            f.lineage.as_deref().ok_or_else(|| {
                PfError::InvalidConfig(format!("frame {}: no lineage to trace", f.frame))
            })
        })
        .collect::<Result<Vec<&[u32]>, PfError>>()?;
    trace_back(&last.cloud.weights, &lineages)
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::smooth::ancestry::NO_ANCESTOR;

    const M: usize = 4;

    fn transition() -> GaussianTransition {
        GaussianTransition {
            sigma: vec![0.1],
            angular: vec![false],
        }
    }

    fn cloud(track: usize, lineage: Option<Vec<u32>>) -> TrackCloud {
        TrackCloud {
            track,
            states: vec![0.0, 1.0, 2.0, 3.0],
            log_weights: vec![0.1f32.ln(), 0.2f32.ln(), 0.3f32.ln(), 0.4f32.ln()],
            lineage,
        }
    }

    #[test]
    fn a_lag_writes_each_frame_lag_frames_late_and_the_rest_at_the_end() {
        let mut smoother = TrackSmoother::new(Some(2), transition(), 0.0);
        let mut due = Vec::new();
        for frame in 0..5 {
            let rows = smoother.add_frame(frame, vec![cloud(7, Some(vec![3, 3, 0, 1]))]);
            due.push(rows.unwrap().iter().map(|r| r.frame).collect::<Vec<_>>());
        }
        assert_eq!(due, [vec![], vec![], vec![0], vec![1], vec![2]]);
        let rest: Vec<usize> = smoother.finish().unwrap().iter().map(|r| r.frame).collect();
        assert_eq!(rest, [3, 4]);
    }

    #[test]
    fn lagged_weights_are_the_descendants_weights() {
        let mut smoother = TrackSmoother::new(Some(1), transition(), 0.0);
        smoother.add_frame(0, vec![cloud(0, None)]).unwrap();
        // Frame 1's particles 0 and 1 descend from frame 0's 3, 2 and 3 from its 0: frame 0 is
        // smoothed to weights (0.7, 0, 0, 0.3), its mean 0.9.
        let rows = smoother
            .add_frame(1, vec![cloud(0, Some(vec![3, 3, 0, 0]))])
            .unwrap();
        assert!((rows[0].values[0].mean - 0.9).abs() < 1e-5, "{rows:?}");
        assert!((rows[0].filtered[0].mean - 2.0).abs() < 1e-5);
    }

    #[test]
    fn a_restart_ends_the_window_and_a_missing_lineage_is_an_error() {
        let mut smoother = TrackSmoother::new(Some(3), transition(), 0.0);
        smoother.add_frame(0, vec![cloud(0, None)]).unwrap();
        smoother
            .add_frame(1, vec![cloud(0, Some(vec![0, 1, 2, 3]))])
            .unwrap();
        let rows = smoother
            .add_frame(2, vec![cloud(0, Some(vec![NO_ANCESTOR; M]))])
            .unwrap();
        assert_eq!(rows.iter().map(|r| r.frame).collect::<Vec<_>>(), [0, 1]);
        let error = smoother.add_frame(3, vec![cloud(0, None)]).unwrap_err();
        assert!(error.to_string().contains("lineage"), "{error}");
        // The whole-track smoother does not need it.
        let mut whole = TrackSmoother::new(None, transition(), 0.0);
        whole.add_frame(0, vec![cloud(0, None)]).unwrap();
        whole.add_frame(1, vec![cloud(0, None)]).unwrap();
        assert_eq!(whole.finish().unwrap().len(), 2);
    }
}
