//! Two tracks on one face. When faces cross, the track of the face behind can jump onto the
//! face in front and follow it with the other track: both fit it well, neither fails, and the
//! face behind, left without a track, is taken for tracked wherever one of them sits near it.
//! Measured on the identity scenario at 640×480 (heads 80 px wide, 200 frames, seed 2): from
//! the crossing at frame 146 two tracks held one head 2–35 px apart for the 45 frames to the end,
//! while the other head had none until frame 191, and then as a new person.
//!
//! Faces that pass each other coincide only for a few frames; tracks that stay together for
//! [`DUPLICATE_FRAMES`] frames are one face tracked twice, and the one that fits it worse ends
//! (its person may be found again on their own face) — unless it was walking until lately
//! (`walking::LastWalk`: its walk broke off where it jumped): then it goes back to where that
//! walk would have taken it, if its template fits a face there ([`WALK_BACK_FIT_SHARE`]).

use std::collections::BTreeMap;

use super::{AutoTracker, Tracked};
use crate::error::FaceError;
use crate::extraction::FaceRect;
use crate::image::GrayImage;
use crate::projection::{TX, TY};

/// Two tracks are on one face when their centres lie within this share of the wider one's width
/// and their widths within [`DUPLICATE_SIZE_RATIO`] of each other...
pub const DUPLICATE_REACH: f32 = 0.3;

/// ... (the larger width over the smaller) ...
pub const DUPLICATE_SIZE_RATIO: f32 = 1.25;

/// ... for this many frames in a row.
pub const DUPLICATE_FRAMES: usize = 5;

/// A duplicate track walks back to its own face when its template fits there within this share
/// of its fit a quarter face off its face (and below the failure level). Measured on the
/// identity scenario at 640×480 (CPU, seeds 1–3): the crossing heads turn as they pass, and
/// the jumped track's template fitted its own head where its walk led at ε 0.07–0.10, 0.45–0.66
/// of its 0.159 off its face; the drift's quarter (`drift::DRIFT_MATCH_SHARE`) refused all three.
pub const WALK_BACK_FIT_SHARE: f64 = 0.75;

/// Whether running tracks `a` and `b` sit on one face in this frame.
pub(super) fn coincide(a: &Tracked, b: &Tracked) -> bool {
    let ((ax, ay), (bx, by)) = (a.rect.centre(), b.rect.centre());
    let (wide, narrow) = (
        a.rect.width.max(b.rect.width),
        a.rect.width.min(b.rect.width),
    );
    narrow > 0.0
        && wide / narrow <= DUPLICATE_SIZE_RATIO
        && (ax - bx).hypot(ay - by) <= DUPLICATE_REACH * wide
}

/// The frames in a row each pair of running tracks (lower number first) has coincided.
#[derive(Debug, Clone, Default)]
pub(super) struct Together {
    frames: BTreeMap<(usize, usize), usize>,
}

impl Together {
    /// After a step of `tracks`: counts the pairs that coincide, forgets the others, and gives
    /// the tracks to end, each the worse fitting of a pair together for [`DUPLICATE_FRAMES`].
    pub(super) fn update(&mut self, tracks: &[Tracked]) -> Vec<usize> {
        let mut now = BTreeMap::new();
        let mut duplicates = Vec::new();
        for (i, a) in tracks.iter().enumerate() {
            for b in &tracks[i + 1..] {
                if !coincide(a, b) {
                    continue;
                }
                let key = (a.track.min(b.track), a.track.max(b.track));
                let frames = self.frames.get(&key).copied().unwrap_or(0) + 1;
                now.insert(key, frames);
                if frames >= DUPLICATE_FRAMES {
                    let worse = if a.error > b.error { a } else { b };
                    if !duplicates.contains(&worse.track) {
                        duplicates.push(worse.track);
                    }
                }
            }
        }
        self.frames = now;
        duplicates
    }
}

impl AutoTracker {
    /// After a step on `frame`: the tracks that duplicate another's face ([`Together`]) go back
    /// to their own face where they can ([`Self::walk_back`]), else end; the tracks ended.
    pub(super) fn end_duplicates(&mut self, frame: &GrayImage) -> Result<Vec<usize>, FaceError> {
        let duplicates = self.together.update(&self.tracked);
        let mut ended = Vec::new();
        for &track in &duplicates {
            if !self.walk_back(track, frame)? {
                self.tracker.end_track(track)?;
                ended.push(track);
            }
        }
        self.tracked.retain(|t| !ended.contains(&t.track));
        Ok(ended)
    }

    /// A duplicate track whose walk broke off lately (it jumped onto the face crossing its own)
    /// moves to where that walk would have taken it, if its own template fits a face there
    /// (within [`WALK_BACK_FIT_SHARE`] of its ε off its face, and below the failure level), and
    /// walks on from there; whether it did. Measured on the identity scenario at
    /// 640×480 (CPU, seed 2): a track walking with its head jumped onto the head crossing it at
    /// frame 146 and ended as a duplicate five frames later; its head, untracked, came back as a
    /// new person at frame 191.
    fn walk_back(&mut self, track: usize, frame: &GrayImage) -> Result<bool, FaceError> {
        let (Some(last), Some(tracked)) = (
            self.walks.broken_off.get(&track).copied(),
            self.tracked.iter().find(|t| t.track == track).copied(),
        ) else {
            return Ok(false);
        };
        let [x, y] = last.at_frame(self.frame_index);
        let rect = FaceRect {
            x: x - tracked.rect.width / 2.0,
            y: y - tracked.rect.height / 2.0,
            ..tracked.rect
        };
        if rect.validate(frame).is_err() {
            return Ok(false);
        }
        let (Some((fit, state)), Some(off_face)) = (
            self.own_fit(track, tracked.width, frame, &rect),
            self.tracker.off_face_error(track),
        ) else {
            return Ok(false);
        };
        let failing = f64::from(self.config.tracker.failure_error);
        if fit > WALK_BACK_FIT_SHARE * off_face || fit > failing {
            return Ok(false);
        }
        self.tracker.move_track(track, state)?;
        self.walks.broken_off.remove(&track);
        self.resume_walk(track, [state[TX], state[TY]], last.walk.speed)?;
        if let Some(t) = self.tracked.iter_mut().find(|t| t.track == track) {
            t.restarted_at(&rect);
        }
        Ok(true)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::extraction::FaceRect;

    fn track(track: usize, x: f32, width: f32, error: f64) -> Tracked {
        Tracked {
            track,
            rect: FaceRect {
                x,
                y: 100.0,
                width,
                height: 1.25 * width,
            },
            error,
            width,
            turn: 0.0,
            confidence: 1.0,
        }
    }

    /// Two tracks 20 px apart on an 80 px face end the worse fitting on their fifth frame
    /// together, not before; a frame apart starts the count again; tracks of different sizes or
    /// farther apart are two faces.
    #[test]
    fn tracks_together_for_five_frames_end_the_worse_fitting() {
        let mut together = Together::default();
        let pair = [track(1, 100.0, 80.0, 0.05), track(2, 120.0, 84.0, 0.04)];
        for _ in 1..DUPLICATE_FRAMES {
            assert!(together.update(&pair).is_empty());
        }
        assert_eq!(together.update(&pair), vec![1]);
        let apart = [track(1, 100.0, 80.0, 0.05), track(2, 150.0, 80.0, 0.04)];
        assert!(together.update(&apart).is_empty());
        for _ in 1..DUPLICATE_FRAMES {
            assert!(together.update(&pair).is_empty(), "the count starts again");
        }
        assert!(
            !coincide(&pair[0], &track(3, 100.0, 110.0, 0.01)),
            "another size"
        );
        assert!(
            !coincide(&pair[0], &track(3, 130.0, 80.0, 0.01)),
            "30 px off an 80 px face"
        );
    }
}
