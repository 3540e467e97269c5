//! Tracks that walk. The tracker's constant-velocity drift carries half a track's last motion
//! into the next step, which trails a face walking across the frame: on the identity scenario
//! a head walking 16 px a frame was followed 10–13 px behind, at ε 0.06, and lost where another
//! face crossed it. A walking track carries its whole last motion instead, for as long as it
//! walks steadily: a track started on a face that walked between its two detections walks from
//! its start ([`AutoTracker::start_moving`]); any other track walks once it has moved at least
//! [`WALK_SPEED`] a frame, steadily, for [`WALK_START_FRAMES`] frames in a row
//! ([`AutoTracker::keep_walking`]).

use std::collections::BTreeMap;

use super::AutoTracker;
use crate::error::FaceError;
use crate::projection::{TX, TY};
use crate::tracker::{FaceEstimate, TrackStatus};

/// A walking track walks no more below this speed (pixels a frame): a face that has stopped.
/// Measured (CPU): the identity scenario's head that stays put moves a median 1.0 px a frame
/// between estimates (95th percentile 2.2); the five talking-head clips' faces 0.4–1.6 px
/// (95th percentiles 1.0–6.5).
pub const WALK_SPEED: f32 = 5.0;

/// A walking track walks no more when its last motion differs from the one before by more than
/// this share of it: a face that stops. Measured on the identity scenario: the returning head
/// moved 29–30 px a frame between estimates while it walked; in the frame it stopped, its track
/// overshot by the drift of 30 px and moved 18 px, and carrying that on took the track off the
/// head within ten frames (one run in six at 300 frames lost the head so, and with it its
/// identity).
pub const WALK_STEADY: f32 = 1.0 / 3.0;

/// A track walks once it has moved at least [`WALK_SPEED`] a frame, each motion within
/// [`WALK_STEADY`] of the one before, for this many frames in a row. Measured on the identity
/// scenario (CPU, seed 8): the head that starts walking at the crossing speeds up by about
/// 0.8 px a frame each frame, so its track walks from the third frame over 5 px a frame. On the
/// five talking-head clips no track moved so (the same states.csv); on Megamind.avi two tracks
/// did for a few frames, with the same share of rows on faces.
pub const WALK_START_FRAMES: u32 = 3;

/// How many frames a broken-off walk is remembered: a pair of tracks on one face ends one after
/// `duplicates::DUPLICATE_FRAMES` (5) frames together, a few frames after the jump.
pub const BROKEN_OFF_FRAMES: usize = 12;

/// Where a walking track was after its last step, and how far it moved a frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Walking {
    pub(super) at: [f32; 2],
    pub(super) speed: [f32; 2],
}

/// A track that does not walk (yet): where it was after its last step, its last motion, and
/// for how many frames in a row it has moved as a walk does.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Path {
    at: [f32; 2],
    motion: Option<[f32; 2]>,
    steady_frames: u32,
}

/// How a track walked until its motion broke off: its last position while it walked, its speed
/// then, and that frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct LastWalk {
    pub(super) walk: Walking,
    pub(super) frame: usize,
}

impl LastWalk {
    /// Where the walk would have taken the track by `frame`.
    pub(super) fn at_frame(&self, frame: usize) -> [f32; 2] {
        let frames = frame.saturating_sub(self.frame) as f32;
        let Walking { at, speed } = self.walk;
        [at[0] + frames * speed[0], at[1] + frames * speed[1]]
    }
}

/// The tracks that walk, the paths of those that do not, and the last walk of each track whose
/// walk broke off lately (`duplicates`: a track that jumped onto a crossing face).
#[derive(Debug, Clone, Default)]
pub(super) struct Walks {
    pub(super) walking: BTreeMap<usize, Walking>,
    paths: BTreeMap<usize, Path>,
    pub(super) broken_off: BTreeMap<usize, LastWalk>,
}

/// The next drift of walking track `walk` that moved to `now` in the last frame: that whole
/// motion, or `None` once it is slower than [`WALK_SPEED`] or not as steady as
/// [`WALK_STEADY`].
fn walking_drift(walk: &Walking, now: [f32; 2]) -> Option<[f32; 2]> {
    let motion = [now[0] - walk.at[0], now[1] - walk.at[1]];
    steady_walk(motion, walk.speed).then_some(motion)
}

/// Whether `motion` follows `before` as a walk: at least [`WALK_SPEED`], and within
/// [`WALK_STEADY`] of it.
fn steady_walk(motion: [f32; 2], before: [f32; 2]) -> bool {
    let change = (motion[0] - before[0]).hypot(motion[1] - before[1]);
    let steady = change <= WALK_STEADY * before[0].hypot(before[1]);
    motion[0].hypot(motion[1]) >= WALK_SPEED && steady
}

impl Walks {
    /// Track `track` was moved: it walks no more, its path starts again and its broken-off
    /// walk is forgotten.
    pub(super) fn forget(&mut self, track: usize) {
        self.walking.remove(&track);
        self.paths.remove(&track);
        self.broken_off.remove(&track);
    }
}

impl Path {
    fn starting_at(at: [f32; 2]) -> Self {
        Self {
            at,
            motion: None,
            steady_frames: 0,
        }
    }

    /// The path after the track moved to `now`; with the motion to walk on once it has walked
    /// [`WALK_START_FRAMES`] frames.
    fn moved_to(self, now: [f32; 2]) -> (Self, Option<[f32; 2]>) {
        let motion = [now[0] - self.at[0], now[1] - self.at[1]];
        let steady = match self.motion {
            Some(before) => steady_walk(motion, before),
            None => false,
        };
        let fast = motion[0].hypot(motion[1]) >= WALK_SPEED;
        let steady_frames = if steady {
            self.steady_frames + 1
        } else {
            u32::from(fast)
        };
        let path = Self {
            at: now,
            motion: Some(motion),
            steady_frames,
        };
        (path, (steady_frames >= WALK_START_FRAMES).then_some(motion))
    }
}

impl AutoTracker {
    /// Track `track`, moved to `at`, walks on at `speed` a frame from the next step.
    pub(super) fn resume_walk(
        &mut self,
        track: usize,
        at: [f32; 2],
        speed: [f32; 2],
    ) -> Result<(), FaceError> {
        self.walks.paths.remove(&track);
        self.walks.walking.insert(track, Walking { at, speed });
        self.tracker.set_track_drift(track, at, speed)
    }

    /// After a step: each walking track that still moves at least [`WALK_SPEED`], and about as
    /// it moved before ([`WALK_STEADY`]), drifts by its whole last motion in the next step; one
    /// that has slowed, turned or ended walks no more. A track that does not walk starts to
    /// once it has moved so for [`WALK_START_FRAMES`] frames.
    pub(super) fn keep_walking(&mut self, estimates: &[FaceEstimate]) -> Result<(), FaceError> {
        let walks = &mut self.walks;
        let frame = self.frame_index;
        walks
            .paths
            .retain(|track, _| estimates.iter().any(|e| e.track == *track));
        (walks.broken_off).retain(|_, last| last.frame + BROKEN_OFF_FRAMES >= frame);
        for e in estimates {
            let now = [e.state[TX], e.state[TY]];
            if e.status != TrackStatus::Tracking {
                walks.walking.remove(&e.track);
                walks.paths.remove(&e.track);
                continue;
            }
            let drift = match walks.walking.get(&e.track) {
                Some(walk) => walking_drift(walk, now),
                None => {
                    let path = (walks.paths.get(&e.track).copied())
                        .unwrap_or_else(|| Path::starting_at(now));
                    let (path, walk) = path.moved_to(now);
                    walks.paths.insert(e.track, path);
                    walk
                }
            };
            match drift {
                Some(drift) => {
                    walks.paths.remove(&e.track);
                    let walk = Walking {
                        at: now,
                        speed: drift,
                    };
                    walks.walking.insert(e.track, walk);
                    self.tracker.set_track_drift(e.track, now, drift)?;
                }
                None => {
                    if let Some(walk) = walks.walking.remove(&e.track) {
                        let last = LastWalk {
                            walk,
                            frame: frame.saturating_sub(1),
                        };
                        walks.broken_off.insert(e.track, last);
                        walks.paths.insert(e.track, Path::starting_at(now));
                    }
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A track walks on at its whole last motion while it moves at least WALK_SPEED a frame.
    #[test]
    fn a_walking_track_carries_its_last_motion_until_it_slows() {
        let walk = Walking {
            at: [100.0, 50.0],
            speed: [29.0, -3.0],
        };
        assert_eq!(walking_drift(&walk, [130.0, 46.0]), Some([30.0, -4.0]));
        assert_eq!(walking_drift(&walk, [103.0, 53.0]), None, "stopped");
        assert_eq!(walking_drift(&walk, [f32::NAN, 50.0]), None);
        // The frame a face stops, its track overshoots and moves less: no longer walking.
        assert_eq!(walking_drift(&walk, [118.0, 50.0]), None, "slowed by 40 %");
        assert_eq!(walking_drift(&walk, [70.0, 50.0]), None, "turned back");
    }

    /// A broken-off walk leads on at its speed from the frame it was last followed.
    #[test]
    fn a_broken_off_walk_leads_on_at_its_speed() {
        let last = LastWalk {
            walk: Walking {
                at: [300.0, 260.0],
                speed: [11.0, -8.5],
            },
            frame: 144,
        };
        assert_eq!(last.at_frame(150), [366.0, 209.0]);
        assert_eq!(last.at_frame(144), [300.0, 260.0]);
        assert_eq!(last.at_frame(100), [300.0, 260.0], "never backwards");
    }

    /// A track that speeds up steadily past WALK_SPEED walks from its third such frame; a
    /// jerk (a motion unlike the one before) starts the count again, and slow motion never
    /// counts.
    #[test]
    fn a_track_moving_steadily_starts_to_walk() {
        let mut path = Path::starting_at([0.0, 0.0]);
        let mut x = 0.0;
        let mut walked_at = None;
        for (frame, speed) in [2.0, 4.0, 5.75, 6.5, 7.25, 8.0].into_iter().enumerate() {
            x += speed;
            let (next, walk) = path.moved_to([x, 0.0]);
            path = next;
            if walked_at.is_none() {
                walked_at = walk.map(|motion| (frame, motion));
            }
        }
        assert_eq!(
            walked_at,
            Some((4, [7.25, 0.0])),
            "5.75, 6.5, 7.25: three frames"
        );
        let mut path = Path::starting_at([0.0, 0.0]);
        let mut x = 0.0;
        for speed in [6.0, 6.25, -6.0, 6.0, 6.25] {
            x += speed;
            let (next, walk) = path.moved_to([x, 0.0]);
            path = next;
            assert_eq!(walk, None, "the turn at -6 starts the count again");
        }
        let (_, walk) = path.moved_to([x + 6.5, 0.0]);
        assert_eq!(walk, Some([6.5, 0.0]));
        let mut path = Path::starting_at([0.0, 0.0]);
        for k in 1..20 {
            let (next, walk) = path.moved_to([4.9 * k as f32, 0.0]);
            path = next;
            assert_eq!(walk, None, "below WALK_SPEED");
        }
    }
}
