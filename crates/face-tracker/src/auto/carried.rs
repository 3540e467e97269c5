//! A track carried off its place. A face that stands still keeps its track there; another
//! face passing in front of it can carry the track off with it, when the detector does not see
//! the passing face (turned away) and so no track of its own holds it. Measured on the identity
//! scenario at 640×480 with heads 80 px wide over 200 frames (CPU, seeds 2 and 3): the
//! returning head, turned 50° away, walked in front of a standing head (frames 115–117), whose
//! track went with it at 20 px a frame (confidence 0.7 → 0.3) while the standing head, turned
//! away too, went untracked until it turned back to the detector: three identity switches.
//!
//! So a track that has stood still for [`STILL_FRAMES`] frames and is then more than
//! [`CARRIED_SHARE`] of its width from that place within [`CARRIED_FRAMES`] frames is checked
//! there for [`LOOK_BACK_FRAMES`] frames: where its own template, searched from the pose it
//! stood in, fits its old place about as well as it fitted the face standing there
//! ([`BACK_REST_SHARE`] of that ε) and better than where it is now ([`BACK_FIT_SHARE`]), it
//! goes back there. A face that really walked off leaves background at its old place, which
//! its template fits far worse than it fitted the face: on that scenario at 640×480 (300 frames,
//! on a GPU, seed 4) the walking head, which starts at its full 19 px a frame, took its track
//! with it, and the track's ε rose to 0.128 as the head passed another; without the first
//! condition its old place, background, fitted within three quarters of that and the track went
//! back there (its ε at rest was 0.047).

use std::collections::BTreeMap;

use super::{AutoTracker, same_face};
use crate::error::FaceError;
use crate::extraction::FaceRect;
use crate::identity::refine_template_at;
use crate::image::GrayImage;
use crate::projection::{DIMS, SCALE, TX, TY};
use crate::tracker::{FaceEstimate, TrackStatus};

/// A track stands still in a frame where it moved at most this share of its width ...
pub const STILL_SHARE: f32 = 0.05;

/// ... and has stood still when it did so for this many frames in a row.
pub const STILL_FRAMES: usize = 10;

/// A track that stood still leaves its place when it moves more than this share of its width
/// in one frame: a face starting to walk speeds up over several frames (the scenario's crossing
/// heads by about 1.5 px a frame each frame in its 200-frame version at 640×480, 0.8 at full
/// size; its faces at rest move at most 2.2 px a frame),
/// where a track taken by a face passing in front moved 15 px (a fifth of the face's width)
/// the first frame.
pub const LEAVING_SHARE: f32 = 0.12;

/// A track that stood still has been carried off when it is more than this share of its width
/// from its place ...
pub const CARRIED_SHARE: f32 = 0.5;

/// ... within this many frames of leaving it (a face that starts to walk speeds up: the
/// scenario's crossing heads gain about 0.8 px a frame each frame at full size).
pub const CARRIED_FRAMES: usize = 4;

/// A carried track's old place is checked in the frame it was found carried off and this many
/// frames after (the face that carried it has to pass first).
pub const LOOK_BACK_FRAMES: usize = 15;

/// A carried track goes back when its template fits its old place within this share of its ε
/// where it is ...
pub const BACK_FIT_SHARE: f64 = 0.75;

/// ... and within this share of its ε where it stood: the standing face found again fitted
/// 1.26 times its ε at rest there (0.049 against 0.039, on the scenario's seed 2 above).
pub const BACK_REST_SHARE: f64 = 1.5;

/// Where a track stands, or stood until it left.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Place {
    /// Its state the last frame it stood still ...
    stood: [f32; DIMS],
    /// ... and its ε then.
    stood_error: f64,
    /// Its position after its last step.
    last: [f32; 2],
    /// Frames in a row it has stood still (0: it moves).
    still: usize,
    /// The frame it left after standing still for [`STILL_FRAMES`], if it has.
    left_at: Option<usize>,
}

/// A track carried off its place: the state it stood in, its ε there, and the frame it was
/// found carried.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Carried {
    pub(super) stood: [f32; DIMS],
    pub(super) stood_error: f64,
    pub(super) frame: usize,
}

/// The running tracks' places, and the tracks carried off theirs lately.
#[derive(Debug, Clone, Default)]
pub(super) struct Places {
    places: BTreeMap<usize, Place>,
    carried: BTreeMap<usize, Carried>,
}

fn distance(a: [f32; 2], b: [f32; 2]) -> f32 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

impl Place {
    fn at(state: [f32; DIMS], error: f64) -> Self {
        Self {
            stood: state,
            stood_error: error,
            last: [state[TX], state[TY]],
            still: 0,
            left_at: None,
        }
    }

    /// The place after a step to `state` at ε `error` (a face `width` pixels wide) at `frame`,
    /// and whether the track has now been carried off it.
    fn stepped(self, state: [f32; DIMS], error: f64, width: f32, frame: usize) -> (Self, bool) {
        let now = [state[TX], state[TY]];
        let still = distance(now, self.last) <= STILL_SHARE * width;
        let leaving = match self.left_at {
            Some(left) => (frame <= left + CARRIED_FRAMES).then_some(left),
            // A face at rest does not start to walk at once; a face passing in front does.
            None => {
                let jump = distance(now, self.last) > LEAVING_SHARE * width;
                (self.still >= STILL_FRAMES && jump).then_some(frame)
            }
        };
        if let Some(left) = leaving {
            let away = distance(now, [self.stood[TX], self.stood[TY]]);
            if away > CARRIED_SHARE * width {
                return (Self::at(state, error), true);
            }
            if !still {
                let next = Self {
                    last: now,
                    left_at: Some(left),
                    ..self
                };
                return (next, false);
            }
        }
        // Standing here: on from the frames before, or from now.
        let standing = still && self.left_at.is_none();
        let next = Self {
            still: if standing {
                self.still + 1
            } else {
                usize::from(still)
            },
            ..Self::at(state, error)
        };
        (next, false)
    }
}

impl Places {
    /// After a step of `estimates` at `frame`: each running track's place, and the tracks found
    /// carried off theirs (remembered for [`LOOK_BACK_FRAMES`]).
    pub(super) fn update(&mut self, estimates: &[FaceEstimate], frame: usize) {
        let running: Vec<&FaceEstimate> = (estimates.iter())
            .filter(|e| e.status == TrackStatus::Tracking && e.state.iter().all(|v| v.is_finite()))
            .collect();
        self.places
            .retain(|track, _| running.iter().any(|e| e.track == *track));
        self.carried.retain(|track, carried| {
            carried.frame + LOOK_BACK_FRAMES >= frame && running.iter().any(|e| e.track == *track)
        });
        for e in running {
            let before =
                (self.places.get(&e.track).copied()).unwrap_or_else(|| Place::at(e.state, e.error));
            let (after, carried) = before.stepped(e.state, e.error, e.rect.width, frame);
            if carried {
                let carried = Carried {
                    stood: before.stood,
                    stood_error: before.stood_error,
                    frame,
                };
                self.carried.insert(e.track, carried);
            }
            self.places.insert(e.track, after);
        }
    }

    /// The tracks carried off their places lately.
    pub(super) fn carried(&self) -> Vec<(usize, Carried)> {
        self.carried.iter().map(|(&t, &c)| (t, c)).collect()
    }

    /// Track `track` was moved or restarted on a detection: where it stood means nothing now.
    pub(super) fn forget(&mut self, track: usize) {
        self.places.remove(&track);
        self.carried.remove(&track);
    }

    /// Track `track` is back at its place, standing in `state` at ε `error`.
    fn back(&mut self, track: usize, state: [f32; DIMS], error: f64) {
        self.carried.remove(&track);
        let place = Place {
            still: STILL_FRAMES,
            ..Place::at(state, error)
        };
        self.places.insert(track, place);
    }
}

impl AutoTracker {
    /// After a step on `frame`: each track carried off its place ([`Places`]) goes back where
    /// its own template fits its old place better than where it is ([`BACK_FIT_SHARE`]), about
    /// as well as it fitted the face standing there ([`BACK_REST_SHARE`]) and below the failure
    /// level, unless another track holds a face there; the tracks moved back.
    pub(super) fn bring_back_carried(
        &mut self,
        frame: &GrayImage,
        estimates: &[FaceEstimate],
    ) -> Result<Vec<usize>, FaceError> {
        self.places.update(estimates, self.frame_index);
        let failing = f64::from(self.config.tracker.failure_error);
        let mut moved = Vec::new();
        for (track, carried) in self.places.carried() {
            let Some(tracked) = self.tracked.iter().find(|t| t.track == track).copied() else {
                continue;
            };
            let templates = self.tracker.templates();
            let Some(template) = templates.iter().find(|(id, _)| *id == track).map(|t| t.1) else {
                continue;
            };
            let lens = self.tracker.lens();
            let face_width = tracked.width * carried.stood[SCALE];
            let (fit, state) =
                refine_template_at(template, frame, &lens, carried.stood, face_width);
            let better = fit <= BACK_FIT_SHARE * tracked.error;
            let like_its_face = fit <= BACK_REST_SHARE * carried.stood_error;
            let rect = FaceRect {
                x: state[TX] - tracked.rect.width / 2.0,
                y: state[TY] - tracked.rect.height / 2.0,
                ..tracked.rect
            };
            // A face found again there may have a track of its own by now (the detector's).
            let held = (self.tracked.iter()).any(|t| t.track != track && same_face(&t.rect, &rect));
            if !(better && like_its_face && fit < failing) || held {
                continue;
            }
            self.tracker.move_track(track, state)?;
            self.walks.forget(track);
            self.places.back(track, state, fit);
            if let Some(t) = self.tracked.iter_mut().find(|t| t.track == track) {
                t.restarted_at(&rect);
            }
            moved.push(track);
        }
        Ok(moved)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(x: f32) -> [f32; DIMS] {
        [x, 100.0, 1.0, 0.0, -0.8, 0.0, 1.0]
    }

    /// Steps a place through the x positions `path` (a face 80 px wide); the frames at which
    /// it was found carried off.
    fn carried_at(path: &[f32]) -> Vec<usize> {
        let mut place = Place::at(at(path[0]), 0.04);
        let mut carried = Vec::new();
        for (frame, &x) in path.iter().enumerate().skip(1) {
            let (next, off) = place.stepped(at(x), 0.04, 80.0, frame);
            if off {
                carried.push(frame);
            }
            place = next;
        }
        carried
    }

    /// A track that stood still for STILL_FRAMES and is then taken 20 px a frame is carried
    /// off once it is half its width (40 px) away; one that stood a frame less, or whose face
    /// speeds up as a walk starts (0.8 px a frame each frame), or that moves a little and
    /// stops, is not.
    #[test]
    fn a_standing_track_taken_off_fast_is_carried_and_no_other() {
        let standing =
            |frames: usize| -> Vec<f32> { (0..=frames).map(|k| 400.0 + 0.5 * k as f32).collect() };
        let mut taken = standing(STILL_FRAMES);
        let from = *taken.last().unwrap();
        taken.extend((1..=6).map(|k| from - 20.0 * k as f32));
        // 20, 40, 60 px away: carried at the third frame after leaving.
        assert_eq!(carried_at(&taken), vec![STILL_FRAMES + 3]);

        let mut too_soon = standing(STILL_FRAMES - 1);
        let from = *too_soon.last().unwrap();
        too_soon.extend((1..=6).map(|k| from - 20.0 * k as f32));
        assert!(carried_at(&too_soon).is_empty());

        let mut walking = standing(STILL_FRAMES + 5);
        let (mut x, mut speed) = (*walking.last().unwrap(), 0.0);
        for _ in 0..30 {
            speed += 0.8;
            x += speed;
            walking.push(x);
        }
        assert!(carried_at(&walking).is_empty(), "a walk that starts");

        let mut nudged = standing(STILL_FRAMES + 5);
        let from = *nudged.last().unwrap();
        nudged.extend([from + 10.0, from + 20.0, from + 20.0, from + 20.5]);
        nudged.extend((1..=4).map(|k| from + 20.0 + 30.0 * k as f32));
        assert!(
            carried_at(&nudged).is_empty(),
            "moved 20 px and stood again: its place is the new one, and it stood a frame"
        );
    }
}
