//! The running tracks as the detector's results see them: what a detection near a track needs
//! to know to leave it, move it or restart it.

use std::collections::BTreeMap;

use super::AutoTracker;
use crate::error::FaceError;
use crate::extraction::FaceRect;
use crate::projection::{RX, RY, SCALE};
use crate::tracker::FaceEstimate;

/// A running track after the last step (or since its start or restart).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Tracked {
    pub track: usize,
    pub rect: FaceRect,
    /// Its ε (0 until its first step).
    pub error: f64,
    /// The face width its template was taken at (its scale 1).
    pub width: f32,
    /// How far it has turned from the pose its template was taken at: the larger of |pitch|
    /// and |yaw| (radians; 0 until its first step).
    pub turn: f32,
    /// Its confidence (`FaceEstimate::confidence`; 1 until its first step).
    pub confidence: f32,
}

impl Tracked {
    /// A track started (by the detector or the caller) on `rect`.
    pub fn started(track: usize, rect: &FaceRect) -> Self {
        Self {
            track,
            rect: *rect,
            error: 0.0,
            width: rect.width,
            turn: 0.0,
            confidence: 1.0,
        }
    }

    /// A running track's state after a step.
    pub fn from_estimate(e: &FaceEstimate) -> Self {
        Self {
            track: e.track,
            rect: e.rect,
            error: e.error,
            width: e.rect.width / e.state[SCALE],
            turn: e.state[RX].abs().max(e.state[RY].abs()),
            confidence: e.confidence,
        }
    }

    /// The track moved or restarted on a detection at `rect`: it is there, facing as the
    /// detector saw it, until its next step says more.
    pub fn restarted_at(&mut self, rect: &FaceRect) {
        self.rect = *rect;
        self.error = 0.0;
        self.turn = 0.0;
        self.confidence = 1.0;
    }
}

/// How many frames in a row each running track has met a condition (a track pinned at the
/// turn's limit, `pinned.rs`; a faint one, `faint.rs`).
#[derive(Debug, Clone, Default)]
pub(super) struct Streaks {
    frames: BTreeMap<usize, usize>,
}

impl Streaks {
    /// After a step of `tracks`: counts on for those that meet `holds`, forgets the others, and
    /// gives the tracks that have met it for `limit` frames in a row.
    pub fn update(
        &mut self,
        tracks: &[Tracked],
        holds: impl Fn(&Tracked) -> bool,
        limit: usize,
    ) -> Vec<usize> {
        let mut now = BTreeMap::new();
        for t in tracks.iter().filter(|t| holds(t)) {
            let frames = self.frames.get(&t.track).copied().unwrap_or(0) + 1;
            now.insert(t.track, frames);
        }
        self.frames = now;
        (self.frames.iter())
            .filter(|&(_, &frames)| frames >= limit)
            .map(|(&track, _)| track)
            .collect()
    }

    /// Track `track`'s count starts again.
    pub fn forget(&mut self, track: usize) {
        self.frames.remove(&track);
    }
}

impl AutoTracker {
    /// Ends running tracks `ended` after a step: their next step reports them lost.
    pub(super) fn end_tracks(&mut self, ended: &[usize]) -> Result<(), FaceError> {
        for &track in ended {
            self.tracker.end_track(track)?;
        }
        self.tracked.retain(|t| !ended.contains(&t.track));
        Ok(())
    }
}
