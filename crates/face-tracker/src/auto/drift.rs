//! Tracks that have drifted off their faces. A track's ε can stay below the failure level while
//! it slides off its face onto background or an ear (a template fits dark blotches and edges
//! nearly as well as a turned face), so ε alone does not end it, and the detector then finds
//! the face free and starts a second track on it. Instead, a detection near a track, about its
//! size, on no other track, is fitted with the track's own template ([`fit_template_at`], the
//! identities' search over the pose): when the template fits the detected face far better than
//! the place the track holds, the track has drifted, and the detection restarts it there.
//!
//! Measured on the identity scenario (seed 2): two tracks slid 100 px off their faces from
//! frame 100 at ε 0.06–0.11 (the failure level 0.12) and held there for 200 frames, while the
//! detector started new tracks on their faces at frame 176.

use super::{AutoTracker, MAX_SIZE_CHANGE, same_face};
use crate::extraction::FaceRect;
use crate::identity::fit_template_at;
use crate::image::GrayImage;

/// A track has drifted when its template fits the detection at most this share of its ε where
/// it is.
pub const DRIFT_FIT_SHARE: f64 = 0.5;

/// ... and at most this share of its template's ε a quarter face off its face (so that the
/// detection is a face the template knows, not merely better than background).
pub const DRIFT_MATCH_SHARE: f64 = 0.25;

/// A detection is near a track when its centre lies within this many of the track's widths.
pub const DRIFT_REACH: f32 = 2.0;

impl AutoTracker {
    /// The running track (its index among `tracked`) that has drifted off the face detected at
    /// `rect` of `frame`, if one has: the best fitting of those near it, about its size, and
    /// not on it (a detection on a track is that track's face: `use_detection`).
    pub(super) fn drifted_onto(&self, frame: &GrayImage, rect: &FaceRect) -> Option<usize> {
        let templates = self.tracker.templates();
        let lens = self.tracker.lens();
        let (x, y) = rect.centre();
        (self.tracked.iter().enumerate())
            .filter(|(_, (_, at, _, _))| {
                let (tx, ty) = at.centre();
                let ratio = rect.width / at.width;
                !same_face(at, rect)
                    && (x - tx).hypot(y - ty) <= DRIFT_REACH * at.width
                    && (1.0 / MAX_SIZE_CHANGE..=MAX_SIZE_CHANGE).contains(&ratio)
            })
            .filter_map(|(i, &(track, _, error, width))| {
                let template = templates.iter().find(|(id, _)| *id == track)?.1;
                let off_face = self.tracker.off_face_error(track)?;
                let fit = fit_template_at((template, width), frame, rect, &lens);
                let drifted = fit <= DRIFT_FIT_SHARE * error && fit <= DRIFT_MATCH_SHARE * off_face;
                drifted.then_some((i, fit))
            })
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(i, _)| i)
    }
}

impl AutoTracker {
    /// The running track that has drifted off the face at `rect` of `frame` (a detection there
    /// would restart it), if any: what the detector's results are checked with each run.
    pub fn drifted_track(&self, frame: &GrayImage, rect: &FaceRect) -> Option<usize> {
        self.drifted_onto(frame, rect).map(|i| self.tracked[i].0)
    }
}
