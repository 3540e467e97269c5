//! The running tracks as the detector's results see them: what a detection near a track needs
//! to know to leave it, move it or restart it.

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
