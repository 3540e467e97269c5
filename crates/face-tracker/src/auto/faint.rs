//! A track that has faded. A face that leaves the picture faster than its track can follow
//! leaves the track on the background, where its template fits no better than anywhere off a
//! face: its confidence (`FaceEstimate::confidence`, the fit against the template's fit off its
//! face times the likelihood's sharpness) falls near 0 and stays there while the track wanders.
//! Measured on the identity scenario at 640×480 (300 frames, heads 75 px wide; on a GPU, Mesa's
//! lavapipe, seed 3): the walked-out head's track wandered on the background for 99 frames at
//! confidence 0.003–0.05, turned 30–60° (so not pinned at the turn's limit, `pinned.rs`), its ε
//! 0.08–0.09 below the failure level. A track on a face reads below [`FAINT_CONFIDENCE`] for at most 9
//! frames in a row on that scenario at full size, 1 on Megamind.avi, and never on the five
//! real clips.
//!
//! So a track below [`FAINT_CONFIDENCE`] for [`FAINT_FRAMES`] frames in a row has lost its face
//! and ends: its person may be found again when the face comes back.

use super::tracked::Streaks;
use super::{AutoTracker, Tracked};
use crate::error::FaceError;

/// A track is faint below this confidence ...
pub const FAINT_CONFIDENCE: f32 = 0.1;

/// ... for this many frames in a row (half a second at 30 frames/s; a track on a face of the
/// identity scenario reads so for at most 9).
pub const FAINT_FRAMES: usize = 15;

/// The frames in a row each running track has been faint.
#[derive(Debug, Clone, Default)]
pub(super) struct Faint(Streaks);

impl Faint {
    /// After a step of `tracks`: counts the faint tracks, forgets the others, and gives the
    /// tracks faint for [`FAINT_FRAMES`].
    pub(super) fn update(&mut self, tracks: &[Tracked]) -> Vec<usize> {
        // A NaN confidence is no evidence of a face either.
        let faint = |t: &Tracked| t.confidence.is_nan() || t.confidence < FAINT_CONFIDENCE;
        self.0.update(tracks, faint, FAINT_FRAMES)
    }

    /// Track `track` was moved or restarted on a detection: its count starts again.
    pub(super) fn forget(&mut self, track: usize) {
        self.0.forget(track);
    }
}

impl AutoTracker {
    /// Track `track` was moved or restarted on a detection: how long it has been faint, and
    /// where it stood (`carried`), start again.
    pub(super) fn placed_anew(&mut self, track: usize) {
        self.faint.forget(track);
        self.places.forget(track);
    }

    /// After a step: ends the tracks faint for [`FAINT_FRAMES`] ([`Faint`]); the tracks ended.
    pub(super) fn end_faint(&mut self) -> Result<Vec<usize>, FaceError> {
        let faint = self.faint.update(&self.tracked);
        self.end_tracks(&faint)?;
        Ok(faint)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::extraction::FaceRect;

    fn track(track: usize, confidence: f32) -> Tracked {
        let rect = FaceRect {
            x: 100.0,
            y: 100.0,
            width: 80.0,
            height: 100.0,
        };
        Tracked {
            confidence,
            ..Tracked::started(track, &rect)
        }
    }

    /// Faint for FAINT_FRAMES frames ends a track, not a frame before; a frame at or above
    /// FAINT_CONFIDENCE starts the count again; NaN counts as faint; a confident track never
    /// ends.
    #[test]
    fn a_track_faint_for_its_frames_ends_and_no_other() {
        let mut faint = Faint::default();
        let faded = track(3, 0.02);
        let on_face = track(1, 0.7);
        let at_the_bound = track(2, FAINT_CONFIDENCE);
        let tracks = [faded, on_face, at_the_bound];
        for _ in 1..FAINT_FRAMES {
            assert!(faint.update(&tracks).is_empty());
        }
        assert_eq!(faint.update(&tracks), vec![3]);
        // A track that left the running ones (ended) is forgotten.
        assert!(faint.update(&[on_face]).is_empty());
        for _ in 0..FAINT_FRAMES / 2 {
            assert!(faint.update(&[faded]).is_empty());
        }
        assert!(faint.update(&[track(3, 0.3)]).is_empty());
        for _ in 1..FAINT_FRAMES {
            assert!(
                faint.update(&[track(3, f32::NAN)]).is_empty(),
                "the count starts again"
            );
        }
        assert_eq!(faint.update(&[track(3, f32::NAN)]), vec![3]);
        // A track the detector moved or restarted starts its count again.
        let mut faint = Faint::default();
        for _ in 1..FAINT_FRAMES {
            assert!(faint.update(&[faded]).is_empty());
        }
        faint.forget(3);
        assert!(faint.update(&[faded]).is_empty(), "the count starts again");
    }
}
