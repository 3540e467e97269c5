//! New faces: a detection on no running track is a candidate until a later detector run sees it
//! again, at its place or, for a face that walks, within reach of it; a track started on a face
//! that walked starts moving at the two detections' speed.

use super::walking::Walking;
use super::{AutoTracker, MAX_SIZE_CHANGE, drift, same_face};
use crate::error::FaceError;
use crate::extraction::FaceRect;
use crate::projection::{TX, TY};
use crate::tracker::{FaceEstimate, TrackStatus};

/// Whether detection `b` may be the face detected at `a` one detector run earlier, moved:
/// its centre within [`drift::DRIFT_REACH`] of `a`'s widths, about `a`'s size.
pub fn within_reach(a: &FaceRect, b: &FaceRect) -> bool {
    let ((ax, ay), (bx, by)) = (a.centre(), b.centre());
    let ratio = b.width / a.width;
    (ax - bx).hypot(ay - by) <= drift::DRIFT_REACH * a.width
        && (1.0 / MAX_SIZE_CHANGE..=MAX_SIZE_CHANGE).contains(&ratio)
}

/// An untracked face of the last detector run: a new face once seen in
/// [`AutoConfig::confirmations`] runs in a row.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Candidate {
    pub(super) rect: FaceRect,
    /// Detector runs in a row that saw it.
    pub(super) seen: usize,
    /// The frame the last of them looked at.
    pub(super) frame: usize,
}

impl Candidate {
    /// The motion (pixels a frame) from this candidate to the same face detected at `rect` in
    /// frame `frame`, if that is later.
    pub(super) fn motion_to(&self, rect: &FaceRect, frame: usize) -> Option<[f32; 2]> {
        let frames = frame.checked_sub(self.frame).filter(|&f| f > 0)? as f32;
        let ((x0, y0), (x1, y1)) = (self.rect.centre(), rect.centre());
        Some([(x1 - x0) / frames, (y1 - y0) / frames])
    }
}

/// The candidate among `candidates` (the last detector run's) that a detection at `rect` sees
/// again, marked in `used` (each confirms one detection): one on the same face, else the
/// nearest within reach (a walking face).
pub(super) fn earlier_candidate(
    candidates: &[Candidate],
    rect: &FaceRect,
    used: &mut [bool],
) -> Option<Candidate> {
    let (x, y) = rect.centre();
    let distance = |c: &Candidate| {
        let (cx, cy) = c.rect.centre();
        (cx - x).hypot(cy - y)
    };
    let free = || (candidates.iter().enumerate()).filter(|(i, _)| !used[*i]);
    let (i, candidate) = free()
        .find(|(_, c)| same_face(&c.rect, rect))
        .or_else(|| {
            free()
                .filter(|(_, c)| within_reach(&c.rect, rect))
                .min_by(|a, b| distance(a.1).total_cmp(&distance(b.1)))
        })
        .map(|(i, c)| (i, *c))?;
    used[i] = true;
    Some(candidate)
}

/// A track lost lately: which, where it was in the frame before it was lost, and that frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct LostFace {
    pub(super) track: usize,
    pub(super) rect: FaceRect,
    pub(super) frame: usize,
}

/// A face is found again when a detection of a frame at most this many detector periods after
/// its track was lost lies within reach of where the track was.
pub const FOUND_AGAIN_PERIODS: usize = 2;

/// Whether a detection at `rect` of frame `frame` is the face of `lost`, found again within
/// `within` frames of its loss.
pub(super) fn is_found_again(
    lost: &LostFace,
    rect: &FaceRect,
    frame: usize,
    within: usize,
) -> bool {
    frame + 1 >= lost.frame && frame <= lost.frame + within && within_reach(&lost.rect, rect)
}

impl AutoTracker {
    /// Whether a detection at `rect` of frame `frame` finds the face of a track lost lately
    /// again (which then needs no second detection to start: it was confirmed once; on
    /// Megamind.avi a track that slid off its face was lost at frame 120 and its face, detected
    /// at frames 120, 125 and 130, was tracked again only from frame 136). Each lost track is
    /// found again once; the lost track, if this is one.
    pub(super) fn found_again(&mut self, rect: &FaceRect, frame: usize) -> Option<usize> {
        let within = FOUND_AGAIN_PERIODS * self.config.detect_every;
        let i = (self.lost.iter()).position(|lost| is_found_again(lost, rect, frame, within));
        i.map(|i| self.lost.swap_remove(i).track)
    }

    /// After a step: remembers the tracks lost at it (where they were before it; not those
    /// `ended` at a scene cut, whose faces are another shot's), and forgets those lost too long
    /// ago to be found again.
    pub(super) fn remember_lost(&mut self, estimates: &[FaceEstimate], ended: &[usize]) {
        let within = FOUND_AGAIN_PERIODS * self.config.detect_every;
        let now = self.frame_index;
        self.lost.retain(|lost| lost.frame + within >= now);
        for e in estimates {
            if matches!(e.status, TrackStatus::Lost { .. })
                && !ended.contains(&e.track)
                && let Some(t) = self.tracked.iter().find(|t| t.track == e.track)
            {
                self.lost.push(LostFace {
                    track: e.track,
                    rect: t.rect,
                    frame: now,
                });
            }
        }
    }

    /// Sets new track `track`, started on a detection of frame `detected_at` and moving
    /// `per_frame`, going: its particles start where the motion has taken the face by the frame
    /// before the next step (with a detection delay the face has walked on meanwhile), drift as
    /// the constant-velocity model would after seeing that motion, and then carry their whole
    /// last motion while they walk ([`Self::keep_walking`]).
    pub(super) fn start_moving(
        &mut self,
        track: usize,
        per_frame: [f32; 2],
        detected_at: usize,
    ) -> Result<(), FaceError> {
        let Some(mut state) = self.tracker.started_around(track) else {
            return Ok(());
        };
        let frames_on = self.frame_index as f32 - detected_at as f32 - 1.0;
        if frames_on != 0.0 {
            state[TX] += frames_on * per_frame[0];
            state[TY] += frames_on * per_frame[1];
            self.tracker.move_track(track, state)?;
        }
        let gain = self.config.tracker.motion.gain();
        let from = [state[TX], state[TY]];
        self.walks.walking.insert(
            track,
            Walking {
                at: from,
                speed: per_frame,
            },
        );
        self.tracker
            .set_track_drift(track, from, [gain * per_frame[0], gain * per_frame[1]])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A face rectangle `width` wide at `x` (its top at 100).
    fn rect(x: f32, width: f32) -> FaceRect {
        FaceRect {
            x,
            y: 100.0,
            width,
            height: 1.25 * width,
        }
    }

    /// A face that walked 150 px between two detector runs five frames apart is the same
    /// candidate (within two widths, about its size), moving 30 px a frame; one three widths
    /// away, or twice the size, is not.
    #[test]
    fn a_candidate_seen_again_a_walk_away_is_confirmed_with_its_motion() {
        let earlier = Candidate {
            rect: rect(600.0, 120.0),
            seen: 1,
            frame: 180,
        };
        let walked = rect(450.0, 120.0);
        assert!(!same_face(&earlier.rect, &walked) && within_reach(&earlier.rect, &walked));
        let [dx, dy] = earlier.motion_to(&walked, 185).unwrap();
        assert!((dx + 30.0).abs() < 1e-3 && dy.abs() < 1e-3, "{dx}, {dy}");
        assert_eq!(earlier.motion_to(&walked, 180), None);
        assert!(!within_reach(&earlier.rect, &rect(240.0, 120.0)));
        assert!(!within_reach(&earlier.rect, &rect(560.0, 240.0)));
    }

    /// A track lost at frame 120 is found again by a detection within reach of where it was,
    /// of a frame up to two periods later (and of the frame before its loss, which a detection
    /// delay hands over late); not later, not far away, not at twice its size.
    #[test]
    fn a_lost_face_is_found_again_nearby_and_soon() {
        let lost = LostFace {
            track: 3,
            rect: rect(400.0, 100.0),
            frame: 120,
        };
        let within = FOUND_AGAIN_PERIODS * 5;
        let near = rect(440.0, 110.0);
        for frame in [119, 120, 125, 130] {
            assert!(is_found_again(&lost, &near, frame, within), "frame {frame}");
        }
        assert!(!is_found_again(&lost, &near, 131, within));
        assert!(!is_found_again(&lost, &near, 117, within));
        assert!(!is_found_again(&lost, &rect(700.0, 100.0), 125, within));
        assert!(!is_found_again(&lost, &rect(400.0, 200.0), 125, within));
    }

    /// A detection sees again the candidate on its own face, not one listed first a walk away;
    /// each candidate confirms one detection; among those within reach the nearest.
    #[test]
    fn a_detection_takes_the_candidate_on_its_face_and_each_candidate_once() {
        let candidate = |x: f32| Candidate {
            rect: FaceRect {
                x,
                y: 100.0,
                width: 100.0,
                height: 125.0,
            },
            seen: 1,
            frame: 10,
        };
        let candidates = [candidate(150.0), candidate(330.0), candidate(300.0)];
        let detection = candidate(305.0).rect;
        let mut used = [false; 3];
        let first = earlier_candidate(&candidates, &detection, &mut used).unwrap();
        assert_eq!(first.rect.x, 330.0, "the first on the same face");
        assert_eq!(used, [false, true, false]);
        let second = earlier_candidate(&candidates, &detection, &mut used).unwrap();
        assert_eq!(second.rect.x, 300.0);
        let third = earlier_candidate(&candidates, &detection, &mut used).unwrap();
        assert_eq!(third.rect.x, 150.0, "the one left, within reach");
        assert_eq!(earlier_candidate(&candidates, &detection, &mut used), None);
    }
}
