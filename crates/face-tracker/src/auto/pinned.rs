//! A track pinned at the turn's limit. When a face leaves the picture its track can stay behind
//! on the background, its pose turned to the state's bound (`MAX_TURN`) so that only a few of
//! its template's points face the camera and fit whatever lies there, below the failure level.
//! Measured on the identity scenario at 640×480 (heads 80 px wide, 200 frames, CPU, seeds 1–3):
//! the walking head's track stayed on the background from frame 32 to the end in two seeds of
//! three (122–168 frames turned at least 65° with ε at least half the failure level, ε 0.08
//! against 0.03–0.05 on a face), 139–170 false positives a run, and the head, back at frame 176, was a
//! new person. A track on a turned-away face of that scenario holds both for at most 24 frames
//! in a row (full size, 300 frames), and the real clips' and Megamind.avi's for at most 5.
//!
//! So a track that is both for [`PINNED_FRAMES`] frames in a row has lost its face and ends: its
//! person may be found again when the face comes back.

use super::tracked::Streaks;
use super::{AutoTracker, Tracked};
use crate::error::FaceError;
use crate::tracker::MAX_TURN;

/// A track is pinned when it has turned to within 5° of the turn's bound ...
pub const PINNED_TURN: f32 = MAX_TURN - 5.0 * std::f32::consts::PI / 180.0;

/// ... and its ε is at least this share of the failure level ...
pub const PINNED_ERROR_SHARE: f64 = 0.5;

/// ... for this many frames in a row (a second at 30 frames/s; a face of the identity scenario
/// holds both for at most 24). At 640×480 (seeds 1–3, CPU) 45 frames left the walked-out
/// head's track on the background 15 frames longer: IDF1 0.910 / 0.895 / 0.892 at 45, 0.919 /
/// 0.905 / 0.901 at 30, the full-size scenario 0.975 on seeds 1–12 at both.
pub const PINNED_FRAMES: usize = 30;

/// The frames in a row each running track has been pinned.
#[derive(Debug, Clone, Default)]
pub(super) struct Pinned(Streaks);

impl Pinned {
    /// After a step of `tracks` (failing at ε above `failure_error`): counts the pinned tracks,
    /// forgets the others, and gives the tracks pinned for [`PINNED_FRAMES`].
    pub(super) fn update(&mut self, tracks: &[Tracked], failure_error: f64) -> Vec<usize> {
        let pinned =
            |t: &Tracked| t.turn >= PINNED_TURN && t.error >= PINNED_ERROR_SHARE * failure_error;
        self.0.update(tracks, pinned, PINNED_FRAMES)
    }
}

impl AutoTracker {
    /// After a step: ends the tracks pinned at the turn's limit ([`Pinned`]); the tracks ended.
    pub(super) fn end_pinned(&mut self) -> Result<Vec<usize>, FaceError> {
        let failing = f64::from(self.config.tracker.failure_error);
        let pinned = self.pinned.update(&self.tracked, failing);
        self.end_tracks(&pinned)?;
        Ok(pinned)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::extraction::FaceRect;

    fn track(track: usize, turn: f32, error: f64) -> Tracked {
        let rect = FaceRect {
            x: 100.0,
            y: 100.0,
            width: 80.0,
            height: 100.0,
        };
        Tracked {
            track,
            rect,
            error,
            width: 80.0,
            turn,
            confidence: 1.0,
        }
    }

    /// Pinned for PINNED_FRAMES frames ends a track, not a frame before; a frame off the limit,
    /// or fitting well, starts the count again; a turned track that fits well is never pinned.
    #[test]
    fn a_track_pinned_for_its_frames_ends_and_no_other() {
        let failing = 0.12;
        let mut pinned = Pinned::default();
        let stuck = track(3, PINNED_TURN + 0.01, 0.08);
        let turned_on_face = track(1, MAX_TURN, 0.04);
        let frontal = track(2, 0.1, 0.5);
        let tracks = [stuck, turned_on_face, frontal];
        for _ in 1..PINNED_FRAMES {
            assert!(pinned.update(&tracks, failing).is_empty());
        }
        assert_eq!(pinned.update(&tracks, failing), vec![3]);
        let off_limit = track(3, PINNED_TURN - 0.01, 0.08);
        assert!(pinned.update(&[off_limit], failing).is_empty());
        let fitting = track(3, MAX_TURN, 0.05);
        for _ in 0..PINNED_FRAMES / 2 {
            assert!(pinned.update(&[stuck], failing).is_empty());
        }
        assert!(pinned.update(&[fitting], failing).is_empty());
        for _ in 1..PINNED_FRAMES {
            assert!(
                pinned.update(&[stuck], failing).is_empty(),
                "the count starts again"
            );
        }
        assert_eq!(pinned.update(&[stuck], failing), vec![3]);
    }
}
