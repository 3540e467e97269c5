//! Smoothing tracks as they are filtered ([`TrackSmoother`]): each track's filtered clouds and
//! the drift of its dynamics kept as frames arrive, smoothed by [`crate::smooth`]'s marginal
//! smoother when the track ends (or the run does), or, with a lag of L frames, L frames behind
//! from the particles' ancestry ([`crate::smooth::ancestry`]: the engine's lineage of each
//! frame); and how often intervals hold the truth ([`Coverage`]). The command line's `--smooth` writes
//! these rows to smoothed.csv; Python's trackers return them.

mod by_evidence;
mod coverage;
mod lagged;
pub use coverage::Coverage;
pub use lagged::{LaggedTracks, ReadFrames, SlotTrack, Unsmoothed};

use std::collections::{BTreeMap, VecDeque};

use rayon::prelude::*;
use std::sync::Arc;

use crate::batch::{BatchShape, weighted_means};
use crate::error::PfError;
use crate::smooth::ancestry::{trace_back, traceable};
use crate::smooth::motion::{EvidenceMotion, OnlineMotion};
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

/// How a lag window's first frame is smoothed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum LagSmoother {
    /// By its particles' descendants L frames on ([`crate::smooth::ancestry`]): O(M·L) a frame,
    /// on the host, no backward passes. The price is path degeneracy: every resampling on the
    /// way (an annealed step resamples once per layer) leaves fewer of the frame's particles
    /// with descendants; [`TrackSmoother::ancestry_health`] measures it.
    #[default]
    Ancestry,
    /// By the marginal smoother over the window ([`crate::smooth::smooth_first_values`] on the
    /// backend): L backward passes of M² a value, track and frame; no degeneracy.
    Marginal,
}

/// How much of a lagged frame's cloud smoothing from the ancestry kept: over the rows smoothed
/// a full lag back, the effective sample size (1 / Σ w²) of their traced weights against that of
/// the same particles' filtered weights.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct AncestryHealth {
    /// Rows smoothed a full lag back.
    pub rows: usize,
    /// Their mean ratio of traced to filtered effective sample size (0–1, rarely above).
    pub mean_kept: f64,
    /// How many kept under a tenth of their filtered effective sample size.
    pub below_a_tenth: usize,
}

impl AncestryHealth {
    fn add(&mut self, traced: &[f64], filtered: &[f64]) {
        let ess = crate::weights::effective_sample_size;
        let filtered = ess(filtered);
        let kept = if filtered > 0.0 {
            ess(traced) / filtered
        } else {
            0.0
        };
        self.add_share(kept);
    }

    /// One more row that kept `kept` of its filtered effective sample size.
    fn add_share(&mut self, kept: f64) {
        self.mean_kept += (kept - self.mean_kept) / (self.rows + 1) as f64;
        self.rows += 1;
        if kept < 0.1 {
            self.below_a_tenth += 1;
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
    /// The same particles under their filtered weights: the filter's weighted mean and interval
    /// (empty unless the smoother was asked for it, [`TrackSmoother::comparing_filtered`]: it
    /// costs a sort of every value's particles).
    pub filtered: Vec<Summary>,
}

/// A track's frames waiting to be smoothed, and its last filtered mean (for the drift).
#[derive(Default, Clone)]
struct TrackFrames {
    frames: VecDeque<WaitingFrame>,
    last_mean: Option<Vec<f32>>,
    /// The evidence of every frame so far for each candidate motion, when the lag windows are
    /// smoothed under the motion it chooses ([`TrackSmoother::choosing_motion_by_evidence`]).
    evidence: Option<OnlineMotion>,
}

/// The smoothing of tracks as they are filtered, without I/O (the CLI's `Smoother` writes its
/// rows to smoothed.csv; Python's trackers return them): each track's filtered clouds and their
/// drift, smoothed when the track ends (or the run does) or, with a lag, L frames behind.
#[derive(Clone)]
pub struct TrackSmoother {
    lag: Option<usize>,
    /// How a lag window is smoothed (with a lag).
    lag_smoother: LagSmoother,
    /// What smoothing from the ancestry kept of the lagged frames.
    health: AncestryHealth,
    /// Whether rows carry the filtered summary too.
    compare_filtered: bool,
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
    /// The evidence's choices of motion, when it chooses them
    /// ([`TrackSmoother::choosing_motion_by_evidence`]).
    evidence: Option<Arc<EvidenceMotion>>,
}

impl TrackSmoother {
    /// Smoothing with `lag` (`None`: each track whole) under `transition`, the dynamics adding
    /// `gain` × each track's last motion.
    pub fn new(lag: Option<usize>, transition: GaussianTransition, gain: f32) -> Self {
        Self {
            lag,
            lag_smoother: LagSmoother::default(),
            health: AncestryHealth::default(),
            compare_filtered: false,
            transition,
            gain,
            tracks: BTreeMap::new(),
            backend: Arc::new(CpuSmoother),
            evidence: None,
        }
    }

    /// The same smoother running its backward passes on `backend` (a GPU's, say).
    pub fn on(self, backend: Arc<dyn ValueSmoother>) -> Self {
        Self { backend, ..self }
    }

    /// The same smoother with its lag windows smoothed by `how` ([`LagSmoother::Ancestry`] by
    /// default).
    pub fn lagging_by(self, how: LagSmoother) -> Self {
        Self {
            lag_smoother: how,
            ..self
        }
    }

    /// The same smoother giving each row the filtered summary of its particles too
    /// ([`SmoothedRow::filtered`]), to compare smoothed and filtered against a truth.
    pub fn comparing_filtered(self) -> Self {
        Self {
            compare_filtered: true,
            ..self
        }
    }

    fn row_summary(&self) -> RowSummary<'_> {
        RowSummary {
            angular: &self.transition.angular,
            filtered: self.compare_filtered,
        }
    }

    /// What smoothing from the ancestry kept of the frames it smoothed a full lag back (`None`
    /// unless it smooths that way).
    pub fn ancestry_health(&self) -> Option<AncestryHealth> {
        self.traces_ancestry().then_some(self.health)
    }

    /// Whether lag windows are smoothed from the ancestry.
    fn traces_ancestry(&self) -> bool {
        self.lag.is_some() && self.lag_smoother == LagSmoother::Ancestry
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
        let mut due = Vec::new();
        for cloud in clouds {
            let track = cloud.track;
            if self.add_cloud(frame, cloud, &mut rows)? {
                due.push(track);
            }
        }
        if self.traces_ancestry() {
            rows.extend(self.smooth_first_by_ancestry(&due)?);
        } else if self.chooses_lag_motion() {
            rows.extend(self.smooth_windows_by_evidence(&due)?);
        } else {
            rows.extend(self.smooth_windows(&due)?);
        }
        Ok(rows)
    }

    /// Smooths every track's frames still waiting (at the end of the run, however it ended).
    pub fn finish(&mut self) -> Result<Vec<SmoothedRow>, PfError> {
        let tracks: Vec<usize> = self.tracks.keys().copied().collect();
        self.flush_tracks(&tracks)
    }

    /// One track's cloud at `frame`, with its drift; whether its lag window is now full (its
    /// first frame due). A restart (a lineage without ancestors) first smooths the window it
    /// ends into `rows`.
    fn add_cloud(
        &mut self,
        frame: usize,
        TrackCloud {
            track,
            states,
            log_weights,
            lineage,
        }: TrackCloud,
        rows: &mut Vec<SmoothedRow>,
    ) -> Result<bool, PfError> {
        let dims = self.transition.sigma.len();
        let continues = self
            .tracks
            .get(&track)
            .is_some_and(|w| !w.frames.is_empty());
        if continues && self.lag.is_some() {
            if self.traces_ancestry() && lineage.is_none() {
                return Err(PfError::InvalidConfig(format!(
                    "smoothing from the ancestry traces each frame's lineage; track {track}'s frame {frame} came without it (keep the engine's lineage)"
                )));
            }
            if lineage.as_deref().is_some_and(|l| !traceable(l)) {
                rows.extend(self.flush_tracks(&[track])?);
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
        self.transition.validate(&cloud)?;
        // The drift needs the means alone: the engine's twin of its weighted-mean kernel.
        let one_target = BatchShape::new(1, cloud.weights.len(), dims)?;
        let mean = weighted_means(
            &one_target,
            &cloud.states,
            &cloud.weights,
            &self.transition.angular,
        );
        let by_evidence = self.chooses_lag_motion();
        let entry = self.tracks.entry(track).or_default();
        cloud.drift = drift(
            self.gain,
            entry.last_mean.as_deref(),
            &mean,
            &self.transition.angular,
        );
        entry.last_mean = Some(mean);
        if by_evidence {
            by_evidence::push_evidence(entry, &cloud, &self.transition)?;
        }
        entry.frames.push_back(WaitingFrame {
            frame,
            cloud,
            lineage,
        });
        Ok(self.lag.is_some_and(|lag| entry.frames.len() > lag))
    }

    /// The first frame of each of `tracks`' full lag windows, smoothed by its descendants'
    /// weights in the window's last frame (traced back through the lineages; the tracks on all
    /// cores), and dropped from the window.
    fn smooth_first_by_ancestry(&mut self, tracks: &[usize]) -> Result<Vec<SmoothedRow>, PfError> {
        let lag_window =
            |track| PfError::InvalidConfig(format!("track {track}: an empty lag window"));
        let how = self.row_summary();
        let windows: Vec<(usize, &TrackFrames)> = (tracks.iter())
            .map(|&t| {
                self.tracks
                    .get(&t)
                    .map(|w| (t, w))
                    .ok_or_else(|| lag_window(t))
            })
            .collect::<Result<_, _>>()?;
        let smoothed: Vec<(SmoothedRow, Vec<f64>)> = (windows.par_iter())
            .map(|&(track, window)| {
                let weights = ancestry_weights(&window.frames)?;
                let first_weights = weights
                    .into_iter()
                    .next()
                    .ok_or_else(|| lag_window(track))?;
                let first = window.frames.front().ok_or_else(|| lag_window(track))?;
                let row = smoothed_row(how, (first.frame, track), &first.cloud, &first_weights)?;
                Ok((row, first_weights))
            })
            .collect::<Result<_, PfError>>()?;
        let mut rows = Vec::with_capacity(tracks.len());
        for (&track, (row, weights)) in tracks.iter().zip(smoothed) {
            let entry = self
                .tracks
                .get_mut(&track)
                .ok_or_else(|| lag_window(track))?;
            let first = entry.frames.pop_front().ok_or_else(|| lag_window(track))?;
            self.health.add(&weights, &first.cloud.weights);
            rows.push(row);
        }
        Ok(rows)
    }

    /// The first frame of each of `tracks`' full lag windows, smoothed by the marginal smoother
    /// over the window (all windows in one backend call), and dropped from the window.
    fn smooth_windows(&mut self, tracks: &[usize]) -> Result<Vec<SmoothedRow>, PfError> {
        let windows: Vec<Vec<Cloud>> = (tracks.iter())
            .filter_map(|t| self.tracks.get(t))
            .map(|w| w.frames.iter().map(|f| f.cloud.clone()).collect())
            .collect();
        let views: Vec<&[Cloud]> = windows.iter().map(Vec::as_slice).collect();
        let values = self.backend.smooth_first_many(&views, &self.transition)?;
        let lag_window = || PfError::InvalidConfig("an empty lag window".into());
        let mut firsts = Vec::with_capacity(tracks.len());
        for &track in tracks {
            let entry = self.tracks.get_mut(&track).ok_or_else(lag_window)?;
            firsts.push((track, entry.frames.pop_front().ok_or_else(lag_window)?));
        }
        let how = self.row_summary();
        (firsts.into_par_iter().zip(values))
            .map(|((track, first), v)| summarised_row(how, (first.frame, track), &first.cloud, v))
            .collect()
    }

    /// Every frame `tracks` still hold, smoothed, the tracks ended: by the marginal smoother
    /// (all tracks in one backend call), or by each track's ancestry where lag windows are.
    fn flush_tracks(&mut self, tracks: &[usize]) -> Result<Vec<SmoothedRow>, PfError> {
        let waiting: Vec<(usize, TrackFrames)> = (tracks.iter())
            .filter_map(|t| self.tracks.remove(t).map(|w| (*t, w)))
            .collect();
        let mut rows = Vec::new();
        if self.traces_ancestry() {
            let how = self.row_summary();
            let per_track: Vec<Vec<SmoothedRow>> = (waiting.par_iter())
                .map(|(track, w)| {
                    let weights = ancestry_weights(&w.frames)?;
                    (w.frames.iter().zip(&weights))
                        .map(|(f, weights)| smoothed_row(how, (f.frame, *track), &f.cloud, weights))
                        .collect::<Result<Vec<_>, PfError>>()
                })
                .collect::<Result<_, PfError>>()?;
            return Ok(per_track.into_iter().flatten().collect());
        }
        if self.chooses_lag_motion() {
            return self.flush_by_evidence(&waiting);
        }
        let clouds: Vec<Vec<Cloud>> = (waiting.iter())
            .map(|(_, w)| w.frames.iter().map(|f| f.cloud.clone()).collect())
            .collect();
        let views: Vec<&[Cloud]> = clouds.iter().map(Vec::as_slice).collect();
        let values = self.backend.smooth_many(&views, &self.transition)?;
        let how = self.row_summary();
        let frames: Vec<(usize, &WaitingFrame, Vec<Summary>)> = (waiting.iter().zip(values))
            .flat_map(|((track, w), track_values)| {
                (w.frames.iter().zip(track_values)).map(move |(f, v)| (*track, f, v))
            })
            .collect();
        rows.extend(
            (frames.into_par_iter())
                .map(|(track, f, v)| summarised_row(how, (f.frame, track), &f.cloud, v))
                .collect::<Result<Vec<_>, PfError>>()?,
        );
        Ok(rows)
    }
}

/// A row of `cloud` smoothed by `weights`, its filtered summary beside them; `at` is the
/// (frame, track).
fn smoothed_row(
    how: RowSummary<'_>,
    at: (usize, usize),
    cloud: &Cloud,
    weights: &[f64],
) -> Result<SmoothedRow, PfError> {
    summarised_row(how, at, cloud, summarise(cloud, weights, how.angular)?)
}

/// A row of smoothed `values`, the same particles' filtered summary beside them where asked.
fn summarised_row(
    how: RowSummary<'_>,
    (frame, track): (usize, usize),
    cloud: &Cloud,
    values: Vec<Summary>,
) -> Result<SmoothedRow, PfError> {
    Ok(SmoothedRow {
        frame,
        track,
        values,
        filtered: if how.filtered {
            summarise(cloud, &cloud.weights, how.angular)?
        } else {
            Vec::new()
        },
    })
}

/// How a row is summarised: which values are angles, and whether the filtered summary is
/// wanted beside the smoothed one.
#[derive(Clone, Copy)]
struct RowSummary<'a> {
    angular: &'a [bool],
    filtered: bool,
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

#[cfg(test)]
mod tests;
