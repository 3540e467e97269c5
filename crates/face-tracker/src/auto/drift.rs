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

use super::{AutoTracker, MAX_SIZE_CHANGE, Tracked, same_face};
use crate::extraction::FaceRect;
use crate::identity::fit_template_at;
use crate::image::GrayImage;
use crate::projection::DIMS;

/// A track has drifted when its template fits the detection at most this share of its ε where
/// it is.
pub const DRIFT_FIT_SHARE: f64 = 0.5;

/// ... and at most this share of its template's ε a quarter face off its face (so that the
/// detection is a face the template knows, not merely better than background).
pub const DRIFT_MATCH_SHARE: f64 = 0.25;

/// A detection is near a track when its centre lies within this many of the track's widths.
pub const DRIFT_REACH: f32 = 2.0;

/// A track has drifted onto a detection farther than [`DRIFT_REACH`] when its template fits the
/// detection at most this share of its ε where it is (the stuck track's share): measured on the
/// identity scenario (GPU, seed 3), a track pulled off its face where two faces crossed sat on
/// background at ε 0.107–0.113, under the failure level, for 70 frames, while its face, 3.3
/// widths away, went untracked and then took a new identity.
pub const FAR_DRIFT_FIT_SHARE: f64 = STUCK_FIT_SHARE;

/// ... and only a track near failing, its ε at least this share of the failure level: heads
/// drawn alike fit each other's faces, and a healthy track (ε 0.01–0.03 on the four-face test
/// video) was moved onto a face entering 3 widths away.
pub const FAR_DRIFT_MIN_FAILURE_SHARE: f64 = 0.75;

/// A track on the detected face is stuck in a wrong pose when its own template fits the
/// detection at most this share of its ε (a healthy track's ε is within a few times what the
/// search finds; a stuck one's many times).
pub const STUCK_FIT_SHARE: f64 = 0.25;

/// A track turned this far (radians, pitch or yaw) from the pose its template was taken at is
/// unlikely to be on a face the frontal detector finds: the detector found the identity
/// scenario's heads turned at most 39° (95 % of its 49 detections within 29°), and the template
/// was itself taken at a pose the detector found. Such a track is stuck whenever its own
/// template fits the detection better than it fits where the track is (on the scenario a track
/// pinned at 66° while its head had turned back to frontal: ε 0.083 where it was, 0.042 on the
/// detected face).
pub const TURNED_AWAY: f32 = 1.05;

/// A track's own template fitted at a detection: its ε there, the track's ε where it is, and
/// the template's ε a quarter face off the face it was taken from.
#[derive(Debug, Clone, Copy)]
struct OwnFit {
    fit: f64,
    error: f64,
    off_face: f64,
}

/// Whether a track on a detected face is stuck in a wrong pose there, by how its own template
/// fits the detection (`turned_away`: the track is turned beyond [`TURNED_AWAY`] and no other
/// track is on the detection). The detection must be a face the template knows, not merely
/// better than background.
fn stuck_in_wrong_pose(fits: OwnFit, turned_away: bool) -> bool {
    let OwnFit {
        fit,
        error,
        off_face,
    } = fits;
    let fits_better = if turned_away {
        fit < error
    } else {
        fit <= STUCK_FIT_SHARE * error
    };
    fits_better && fit <= DRIFT_MATCH_SHARE * off_face
}

/// How closely a track's own template must fit a detection on no track for the track to have
/// drifted onto it, by where the track is: within [`DRIFT_REACH`] a share
/// [`DRIFT_FIT_SHARE`] of its ε; farther, [`FAR_DRIFT_FIT_SHARE`], and only for a track near
/// failing (its ε at least [`FAR_DRIFT_MIN_FAILURE_SHARE`] of `failing`); `None` when it cannot
/// have (and its template need not be fitted).
fn drift_fit_share(near: bool, error: f64, failing: f64) -> Option<f64> {
    if near {
        Some(DRIFT_FIT_SHARE)
    } else {
        (error >= FAR_DRIFT_MIN_FAILURE_SHARE * failing).then_some(FAR_DRIFT_FIT_SHARE)
    }
}

/// Whether a track has drifted onto a detection its template fits so (`share`:
/// [`drift_fit_share`]): better than that share of its ε, and a face the template knows.
fn drifted_onto_it(fits: OwnFit, share: f64) -> bool {
    fits.fit <= share * fits.error && fits.fit <= DRIFT_MATCH_SHARE * fits.off_face
}

impl AutoTracker {
    /// Where track `i` (among `tracked`), on the face detected at `rect`, should be if it is
    /// stuck in a wrong pose there: its ε below the failure level, yet its template fits the
    /// detected face far better (measured on the identity scenario: a track's yaw pinned at the
    /// state's 70° limit while its head had turned back to 8°, at ε 0.06, before it slid off
    /// the face; on the five talking-head clips a track's ε was 0.98 times or more what the
    /// search found, never a quarter).
    pub(super) fn stuck_on(
        &self,
        i: usize,
        frame: &GrayImage,
        rect: &FaceRect,
    ) -> Option<[f32; DIMS]> {
        let &Tracked {
            track,
            error,
            width,
            turn,
            ..
        } = self.tracked.get(i)?;
        let (fit, state) = self.own_fit(track, width, frame, rect)?;
        let off_face = self.tracker.off_face_error(track)?;
        // Faces passing each other: the detection may be the other track's face.
        let alone = (self.tracked.iter().enumerate())
            .all(|(j, other)| j == i || !same_face(&other.rect, rect));
        let fits = OwnFit {
            fit,
            error,
            off_face,
        };
        stuck_in_wrong_pose(fits, turn > TURNED_AWAY && alone).then_some(state)
    }

    /// The running track (its index among `tracked`) that has drifted off the face detected at
    /// `rect` of `frame`, if one has, and where its template fits the face: the best fitting
    /// of those near it, about its size, and not on it (a detection on a track is that track's
    /// face: `use_detection`).
    pub(super) fn drifted_onto(
        &self,
        frame: &GrayImage,
        rect: &FaceRect,
    ) -> Option<(usize, [f32; DIMS])> {
        let (x, y) = rect.centre();
        (self.tracked.iter().enumerate())
            .filter(|(_, Tracked { rect: at, .. })| {
                let ratio = rect.width / at.width;
                !same_face(at, rect) && (1.0 / MAX_SIZE_CHANGE..=MAX_SIZE_CHANGE).contains(&ratio)
            })
            .filter_map(|(i, t)| {
                let Tracked {
                    track,
                    rect: at,
                    error,
                    width,
                    ..
                } = *t;
                let (tx, ty) = at.centre();
                let near = (x - tx).hypot(y - ty) <= DRIFT_REACH * at.width;
                let failing = f64::from(self.config.tracker.failure_error);
                let share = drift_fit_share(near, error, failing)?;
                let (fit, state) = self.own_fit(track, width, frame, rect)?;
                let off_face = self.tracker.off_face_error(track)?;
                let fits = OwnFit {
                    fit,
                    error,
                    off_face,
                };
                drifted_onto_it(fits, share).then_some((i, fit, state))
            })
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(i, _, state)| (i, state))
    }

    /// Running track `track`'s own template (taken on a face `width` wide) fitted at `rect`:
    /// its ε (`None` unless finite) and the state found.
    pub(super) fn own_fit(
        &self,
        track: usize,
        width: f32,
        frame: &GrayImage,
        rect: &FaceRect,
    ) -> Option<(f64, [f32; DIMS])> {
        let templates = self.tracker.templates();
        let template = templates.iter().find(|(id, _)| *id == track)?.1;
        let (fit, state) = fit_template_at((template, width), frame, rect, &self.tracker.lens());
        fit.is_finite().then_some((fit, state))
    }

    /// The running track that has drifted off the face at `rect` of `frame` (a detection there
    /// would move it there), if any: what the detector's results are checked with each run.
    pub fn drifted_track(&self, frame: &GrayImage, rect: &FaceRect) -> Option<usize> {
        self.drifted_onto(frame, rect)
            .map(|(i, _)| self.tracked[i].track)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The identity scenario's pinned track (ε 0.083 where it was, its template 0.042 on the
    /// detected face, 0.249 off its face): stuck only when turned away; a detection its template
    /// fits worse than where it is, or fits no better than background, never moves it.
    #[test]
    fn a_track_turned_away_is_stuck_when_its_template_fits_the_detection_better() {
        let pinned = OwnFit {
            fit: 0.042,
            error: 0.083,
            off_face: 0.249,
        };
        assert!(stuck_in_wrong_pose(pinned, true));
        assert!(!stuck_in_wrong_pose(pinned, false), "a quarter of ε needed");
        let far_better = OwnFit {
            fit: 0.02,
            ..pinned
        };
        assert!(stuck_in_wrong_pose(far_better, false));
        let worse = OwnFit {
            fit: 0.09,
            ..pinned
        };
        assert!(!stuck_in_wrong_pose(worse, true));
        let background_like = OwnFit {
            fit: 0.07,
            error: 0.3,
            off_face: 0.2,
        };
        assert!(!stuck_in_wrong_pose(background_like, true));
        assert!(!stuck_in_wrong_pose(background_like, false));
    }

    /// A track on background at ε 0.11 (failure level 0.12) whose template fits a detection at
    /// 0.04: near, it has drifted there (half its ε); far, only at a quarter of it (0.02), and a
    /// healthy track far away (ε 0.03) is not fitted at all.
    #[test]
    fn a_far_detection_needs_a_closer_fit_to_take_a_drifted_track() {
        let failing = 0.12;
        let near = drift_fit_share(true, 0.11, failing).unwrap();
        let far = drift_fit_share(false, 0.11, failing).unwrap();
        assert_eq!(
            drift_fit_share(false, 0.03, failing),
            None,
            "a healthy far track"
        );
        assert_eq!(drift_fit_share(true, 0.03, failing), Some(DRIFT_FIT_SHARE));
        let on_background = OwnFit {
            fit: 0.04,
            error: 0.11,
            off_face: 0.25,
        };
        assert!(drifted_onto_it(on_background, near));
        assert!(!drifted_onto_it(on_background, far));
        let close_fit = OwnFit {
            fit: 0.02,
            ..on_background
        };
        assert!(drifted_onto_it(close_fit, far));
        let like_background = OwnFit {
            fit: 0.02,
            error: 0.11,
            off_face: 0.06,
        };
        assert!(!drifted_onto_it(like_background, near));
    }
}
