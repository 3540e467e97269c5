//! A [`TrackSmoother`] whose motion the evidence chooses (`--smooth-motion auto`): whole tracks
//! by [`EvidenceMotion`], lag windows by each track's evidence of every frame so far
//! ([`OnlineMotion`], kept in the track's [`TrackFrames`]).

use std::sync::Arc;

use super::{LagSmoother, SmoothedRow, TrackFrames, TrackSmoother, summarised_row};
use crate::error::PfError;
use crate::smooth::Cloud;
use crate::smooth::motion::{EvidenceMotion, OnlineMotion};

impl TrackSmoother {
    /// The same smoother with each value's motion chosen by the evidence, track by track: whole
    /// tracks by [`EvidenceMotion`] (on the CPU's cores), and with a lag smoothed by the marginal
    /// smoother, each window's first frame under the motion the evidence of every frame of its
    /// track so far chooses ([`OnlineMotion`]). `chooser` keeps each track's choices (at its
    /// end) for the run's report.
    pub fn choosing_motion_by_evidence(self, chooser: Arc<EvidenceMotion>) -> Self {
        Self {
            backend: chooser.clone(),
            evidence: Some(chooser),
            ..self
        }
    }

    /// Whether lag windows are smoothed under the motion each track's evidence so far chooses.
    pub(super) fn chooses_lag_motion(&self) -> bool {
        self.lag.is_some() && self.evidence.is_some() && self.lag_smoother == LagSmoother::Marginal
    }

    /// The first frame of each of `tracks`' full lag windows, smoothed under the motion its
    /// track's evidence chooses so far, and dropped from the window.
    pub(super) fn smooth_windows_by_evidence(
        &mut self,
        tracks: &[usize],
    ) -> Result<Vec<SmoothedRow>, PfError> {
        let lag_window =
            |track| PfError::InvalidConfig(format!("track {track}: an empty lag window"));
        let mut rows = Vec::with_capacity(tracks.len());
        for &track in tracks {
            let entry = self
                .tracks
                .get_mut(&track)
                .ok_or_else(|| lag_window(track))?;
            let window: Vec<Cloud> = entry.frames.iter().map(|f| f.cloud.clone()).collect();
            let evidence = entry.evidence.as_mut().ok_or_else(|| lag_window(track))?;
            let values = evidence.smooth_first(&window)?;
            let first = entry.frames.pop_front().ok_or_else(|| lag_window(track))?;
            rows.push((first, track, values));
        }
        let how = self.row_summary();
        rows.into_iter()
            .map(|(first, track, values)| {
                summarised_row(how, (first.frame, track), &first.cloud, values)
            })
            .collect()
    }

    /// Every frame of the ended tracks `waiting`, smoothed under the motion each track's
    /// evidence chose; the choices go to the chooser's report.
    pub(super) fn flush_by_evidence(
        &self,
        waiting: &[(usize, TrackFrames)],
    ) -> Result<Vec<SmoothedRow>, PfError> {
        let how = self.row_summary();
        let mut rows = Vec::new();
        for (track, w) in waiting {
            let Some(evidence) = &w.evidence else {
                continue;
            };
            if let Some(chooser) = &self.evidence {
                chooser.record(evidence.choices());
            }
            if w.frames.is_empty() {
                continue;
            }
            let clouds: Vec<Cloud> = w.frames.iter().map(|f| f.cloud.clone()).collect();
            let values = evidence.smooth_all(&clouds)?;
            for (f, v) in w.frames.iter().zip(values) {
                rows.push(summarised_row(how, (f.frame, *track), &f.cloud, v)?);
            }
        }
        Ok(rows)
    }
}

/// A track's next cloud into its evidence, when its lag windows are smoothed by it.
pub(super) fn push_evidence(
    entry: &mut TrackFrames,
    cloud: &Cloud,
    transition: &crate::smooth::GaussianTransition,
) -> Result<(), PfError> {
    entry
        .evidence
        .get_or_insert_with(|| OnlineMotion::new(transition.clone()))
        .push(cloud)
}
