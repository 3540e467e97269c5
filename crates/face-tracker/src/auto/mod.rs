//! Fully automatic tracking, as the paper's system: a Viola–Jones detector runs in its own thread
//! (the initialisation thread) on every n-th frame while the caller's thread tracks. A detection
//! that overlaps no running track starts a new one (its template extracted from the frame the
//! detector saw); a detection on a running track whose ε is above the failure level restarts
//! that track there if it frames the face at about the track's size (same number: the
//! detector pulls a drifting track back onto the face); a lost
//! track frees its slot, so the face can be found again. Detections whose template shows too
//! little contrast to be a face (dark or flat regions) are ignored. At a scene cut
//! ([`crate::scene_cut`]) the cut's first frame goes to the detector whatever the period, and
//! the tracks it does not find again (at their place and about their size) end there.
//!
//! Live (no `detection_delay`), the detector never holds up tracking: its results are taken when
//! they are ready, and a new frame is handed to it only when it is idle. With a delay of d frames
//! (a file), the detection of frame t is used at frame t + d exactly, waiting for it if it is
//! late, so that a run's results do not depend on timing; the frames handed over in between are
//! detected at the same time on threads of their own, so a delay of a few detection periods lets
//! the detector keep up with the tracker instead of holding it up.

use std::sync::Arc;

use crate::detect::{DetectConfig, Detection, FaceDetector};
use crate::error::FaceError;
use crate::extraction::FaceRect;
use crate::identity::{Identities, IdentityConfig, NewFace};
use crate::image::GrayImage;
use crate::model::FaceModel;
use crate::scene_cut::{PendingCut, SceneCuts};

mod candidates;
mod carried;
mod detectors;
mod drift;
mod duplicates;
mod faint;
mod pinned;
mod shots;
mod tracked;
mod walking;
use crate::synth::HEIGHT_RATIO;
use crate::template::Template;
use crate::tracker::{FaceBackend, FaceEstimate, FaceTracker, FaceTrackerConfig, TrackStatus};
pub use candidates::within_reach;
use candidates::{Candidate, LostFace, earlier_candidate};
use detectors::{DetectionResult, Detectors};
use tracked::Tracked;

/// How detection feeds the tracker.
#[derive(Debug, Clone, PartialEq)]
pub struct AutoConfig {
    /// Hand the detector every n-th frame (when it is idle; 1 = whenever it is idle).
    pub detect_every: usize,
    pub detect: DetectConfig,
    /// Faces tracked at once (the filter batch's slots).
    pub max_faces: usize,
    /// Use the detection of frame t at frame t + d exactly (0: before tracking frame t itself),
    /// waiting for it when the detector is slower; up to d / `detect_every` + 1 frames are
    /// detected at once. Runs repeat exactly. `None`: never wait (live video), one frame at a
    /// time.
    pub detection_delay: Option<usize>,
    /// The face rectangle's width as a share of the detector's square (a frontal Haar square
    /// spans brow to chin and a little beyond the cheeks).
    pub rect_width_share: f32,
    /// A detection starts a track only when its template's gray levels span at least this much
    /// (a face has dark eyes and brows on lighter skin; false detections in dark, flat parts of a
    /// frame give templates that match anything dark forever).
    pub min_template_contrast: f32,
    /// A new face needs detections in this many detector runs in a row (1: the first
    /// detection starts a track), each on the one before or within two of its widths at about
    /// its size (a face walking 30 px a frame moves 150 px between runs five frames apart);
    /// false detections on clutter rarely repeat.
    pub confirmations: usize,
    /// A gray-level histogram change from one frame to the next above this marks a scene cut
    /// ([`crate::scene_cut`]); `None`: cuts are not looked for.
    pub scene_cut: Option<f32>,
    /// Who each track is ([`crate::identity`]): a face found again after its track ended takes
    /// its earlier identity; `None`: every track is an identity of its own.
    pub identities: Option<IdentityConfig>,
    pub tracker: FaceTrackerConfig,
}

impl Default for AutoConfig {
    fn default() -> Self {
        Self {
            detect_every: 5,
            detect: DetectConfig::default(),
            max_faces: 8,
            detection_delay: None,
            rect_width_share: 0.8,
            min_template_contrast: 40.0,
            confirmations: 2,
            scene_cut: Some(crate::scene_cut::DEFAULT_SCENE_CUT),
            identities: Some(IdentityConfig::default()),
            tracker: FaceTrackerConfig::default(),
        }
    }
}

impl AutoConfig {
    pub fn validate(&self) -> Result<(), FaceError> {
        if self.detect_every == 0 || self.max_faces == 0 || self.confirmations == 0 {
            return Err(FaceError::InvalidInput(format!(
                "detection needs a period of at least one frame, room for a face and at least one confirmation (got every {} frames, {} faces, {} confirmations)",
                self.detect_every, self.max_faces, self.confirmations
            )));
        }
        if self.scene_cut.is_some_and(|t| !(t > 0.0 && t < 2.0)) {
            return Err(FaceError::InvalidInput(format!(
                "a scene cut's histogram change must be within (0, 2) (0 the same, 2 disjoint), got {:?}",
                self.scene_cut
            )));
        }
        if !(self.min_template_contrast.is_finite() && self.min_template_contrast >= 0.0) {
            return Err(FaceError::InvalidInput(format!(
                "the smallest template contrast must be >= 0, got {}",
                self.min_template_contrast
            )));
        }
        if !(self.rect_width_share.is_finite()
            && self.rect_width_share > 0.0
            && self.rect_width_share <= 1.0)
        {
            return Err(FaceError::InvalidInput(format!(
                "the face rectangle's share of a detection must be in (0, 1], got {}",
                self.rect_width_share
            )));
        }
        self.detect.validate()
    }

    /// The tracker's face rectangle for a detection: `rect_width_share` of the square's width,
    /// the face's height ratio, on the same centre, clipped to the frame.
    pub fn face_rect(&self, d: &Detection, frame: &GrayImage) -> FaceRect {
        let (cx, cy) = (
            d.x as f32 + d.width as f32 / 2.0,
            d.y as f32 + d.height as f32 / 2.0,
        );
        let width = (d.width as f32 * self.rect_width_share).min(frame.width as f32);
        let height = (width * HEIGHT_RATIO).min(frame.height as f32);
        let x = (cx - width / 2.0).clamp(0.0, frame.width as f32 - width);
        let y = (cy - height / 2.0).clamp(0.0, frame.height as f32 - height);
        FaceRect {
            x,
            y,
            width,
            height,
        }
    }
}

/// Whether two face rectangles are the same face: the centre of either lies inside the other.
pub fn same_face(a: &FaceRect, b: &FaceRect) -> bool {
    let inside = |r: &FaceRect, (x, y): (f32, f32)| {
        x >= r.x && x <= r.x + r.width && y >= r.y && y <= r.y + r.height
    };
    inside(a, b.centre()) || inside(b, a.centre())
}

/// A face is at most this many times larger or smaller than its track when a detection
/// restarts the track or finds it again after a scene cut: a face does not change its size
/// from one detector run to the next, where a false detection on part of a face (an eye and a
/// brow) or a new shot's face at the same place are framed otherwise.
pub const MAX_SIZE_CHANGE: f32 = 1.5;

/// [`same_face`], and the detection `b` within [`MAX_SIZE_CHANGE`] of track `a`'s width.
pub fn same_face_and_size(a: &FaceRect, b: &FaceRect) -> bool {
    let ratio = b.width / a.width;
    same_face(a, b) && (1.0 / MAX_SIZE_CHANGE..=MAX_SIZE_CHANGE).contains(&ratio)
}

/// What happened at a frame.
#[derive(Debug, Clone, PartialEq)]
pub struct AutoFrame {
    /// Every running track's estimate (and tracks lost at this frame, once).
    pub estimates: Vec<FaceEstimate>,
    /// Tracks started before this frame's step: (track, the rectangle it started from, the
    /// frame the detector saw).
    pub started: Vec<(usize, FaceRect, usize)>,
    /// Tracks restarted on a detection before this frame's step: (track, rectangle, the frame
    /// the detector saw).
    pub restarted: Vec<(usize, FaceRect, usize)>,
    /// Detections used this frame that were already tracked well, had no free slot, or were
    /// not a trackable face.
    pub ignored: usize,
    /// Whether this frame starts a new shot (a scene cut).
    pub scene_cut: bool,
    /// Tracks ended before this frame's step because the detection after a cut did not find
    /// their faces again (reported lost by this frame's step).
    pub ended: Vec<usize>,
    /// Tracks ended after this frame's step because another track had held the same face
    /// with them for several frames (reported lost by the next step).
    pub duplicates: Vec<usize>,
    /// Tracks ended after this frame's step, pinned at the turn's limit on what is no longer a
    /// face (`pinned.rs`).
    pub pinned: Vec<usize>,
    /// Tracks ended after this frame's step, faint on what is no longer a face (`faint.rs`).
    pub faint: Vec<usize>,
    /// Tracks moved back after this frame's step to the place a passing face had carried them
    /// off (`carried.rs`).
    pub carried_back: Vec<usize>,
}

/// A tracker fed by a detector thread.
pub struct AutoTracker {
    config: AutoConfig,
    tracker: FaceTracker,
    /// The detector the threads run (for its fallback report).
    detector_used: Arc<FaceDetector>,
    detector: Detectors,
    frame_index: usize,
    /// The running tracks after the last step.
    tracked: Vec<Tracked>,
    /// Untracked faces of the last detector run.
    candidates: Vec<Candidate>,
    cuts: Option<SceneCuts>,
    /// The tracks of the last cut, until a detection from its first frame on decides them.
    pending_cut: Option<PendingCut>,
    identities: Option<Identities>,
    /// The frames that started a new shot so far, and how many tracks ended at them.
    cuts_seen: Vec<usize>,
    /// The tracks that walk, and the paths of the others (`walking.rs`).
    walks: walking::Walks,
    /// Tracks lost lately (not at a scene cut): where they were and the frame they were lost
    /// at (`candidates::LostFace`).
    lost: Vec<LostFace>,
    /// How long pairs of tracks have sat on one face (`duplicates.rs`).
    together: duplicates::Together,
    /// How long each track has been pinned at the turn's limit (`pinned`).
    pinned: pinned::Pinned,
    /// How long each track has been faint (`faint`).
    faint: faint::Faint,
    /// Where the tracks stand, and those carried off their places lately (`carried`).
    places: carried::Places,
    /// The first frame of the current shot (0 until a scene cut).
    shot_start: usize,
    ended_at_cuts: usize,
}

impl AutoTracker {
    /// `detector`: a [`crate::detect::Cascade`] (on the CPU) or a
    /// [`crate::detect::GpuCascade`].
    pub fn new(
        frame_size: (u32, u32),
        detector: impl Into<FaceDetector>,
        model: &FaceModel,
        config: AutoConfig,
        backend: FaceBackend,
    ) -> Result<Self, FaceError> {
        config.validate()?;
        let tracker = FaceTracker::with_capacity(
            frame_size,
            config.max_faces,
            model,
            config.tracker.clone(),
            backend,
        )?;
        // With a delay, every frame handed over before a detection is due runs at once.
        let threads = config
            .detection_delay
            .map_or(1, |delay| delay / config.detect_every + 1);
        let detector_used = Arc::new(detector.into());
        let detector =
            Detectors::spawn(Arc::clone(&detector_used), config.detect.clone(), threads)?;
        let cuts = config.scene_cut.map(SceneCuts::new);
        let identities = config.identities.map(Identities::new);
        Ok(Self {
            config,
            tracker,
            detector_used,
            detector,
            frame_index: 0,
            tracked: Vec::new(),
            candidates: Vec::new(),
            cuts,
            pending_cut: None,
            identities,
            cuts_seen: Vec::new(),
            ended_at_cuts: 0,
            walks: walking::Walks::default(),
            lost: Vec::new(),
            together: duplicates::Together::default(),
            pinned: pinned::Pinned::default(),
            faint: faint::Faint::default(),
            places: carried::Places::default(),
            shot_start: 0,
        })
    }

    pub fn tracker(&self) -> &FaceTracker {
        &self.tracker
    }

    /// Why the detector went over from its GPU to the CPU, if it did
    /// ([`FaceDetector::fallback`]).
    pub fn detector_fallback(&self) -> Option<String> {
        self.detector_used.fallback()
    }

    /// The frames that started a new shot so far ([`AutoConfig::scene_cut`]), and how many
    /// tracks ended at them because the detector did not find their faces again.
    pub fn scene_cuts(&self) -> (&[usize], usize) {
        (&self.cuts_seen, self.ended_at_cuts)
    }

    /// See [`FaceTracker::keep_lineage`].
    pub fn keep_lineage(&mut self) -> Result<(), FaceError> {
        self.tracker.keep_lineage()
    }

    /// See [`FaceTracker::keep_lag_window`].
    pub fn keep_lag_window(&mut self, lag: usize, compare_filtered: bool) -> Result<(), FaceError> {
        self.tracker.keep_lag_window(lag, compare_filtered)
    }

    /// See [`FaceTracker::set_personaliser`].
    pub fn set_personaliser(
        &mut self,
        personaliser: Option<std::sync::Arc<crate::personal::Personaliser>>,
    ) {
        self.tracker.set_personaliser(personaliser);
    }

    /// Starts a track on a rectangle given by the caller (not by the detector) in `frame`, the
    /// frame the next `step` follows; returns the track's number.
    pub fn add_face(&mut self, frame: &GrayImage, rect: &FaceRect) -> Result<usize, FaceError> {
        let track = self.tracker.add_face(frame, rect)?;
        self.identify(track, frame, rect, None);
        self.tracked.push(Tracked::started(track, rect));
        Ok(track)
    }

    /// Gives new track `track`, started on `rect` of `frame`, its identity (`found_again`: the
    /// track lost a moment ago near there).
    fn identify(
        &mut self,
        track: usize,
        frame: &GrayImage,
        rect: &FaceRect,
        found_again: Option<usize>,
    ) {
        let (Some(identities), Some(template), Some(off_face_error)) = (
            self.identities.as_mut(),
            self.tracker.template(track),
            self.tracker.off_face_error(track),
        ) else {
            return;
        };
        let face = NewFace {
            frame,
            rect,
            template,
            off_face_error,
        };
        let lens = self.tracker.lens();
        match found_again {
            Some(lost) => identities.start_found_again(track, &face, &lens, lost),
            None => identities.start(track, &face, &lens),
        };
    }

    /// Starts tracks for a finished detection's new faces, and restarts failing tracks it finds.
    fn use_detection(
        &mut self,
        result: DetectionResult,
        out: &mut AutoFrame,
    ) -> Result<(), FaceError> {
        let faces = result.faces?;
        let mut candidates = Vec::new();
        let mut used = vec![false; self.candidates.len()];
        let mut found_after_cut = Vec::new();
        for d in &faces {
            let rect = self.config.face_rect(d, &result.frame);
            if let Some(cut) = &self.pending_cut {
                (cut.unconfirmed.iter())
                    .filter(|(_, at_cut)| same_face_and_size(at_cut, &rect))
                    .for_each(|&(track, _)| found_after_cut.push(track));
            }
            if self.use_on_tracks(&rect, (&result.frame, result.frame_index), out)? {
                continue;
            }
            let Some(template) = self.trackable_template(&result.frame, &rect) else {
                out.ignored += 1;
                continue;
            };
            let earlier = earlier_candidate(&self.candidates, &rect, &mut used);
            let found_again = self.found_again(&rect, result.frame_index);
            let seen = if found_again.is_some() {
                self.config.confirmations
            } else {
                1 + earlier.map_or(0, |c| c.seen)
            };
            if seen < self.config.confirmations {
                candidates.push(Candidate {
                    rect,
                    seen,
                    frame: result.frame_index,
                });
            } else if self.tracker.free_slots() == 0 {
                out.ignored += 1;
            } else {
                let track = self.tracker.add_template(&result.frame, &rect, template)?;
                // A face that moved out of its earlier rectangle walks: its track starts
                // moving with it.
                if let Some(per_frame) = earlier
                    .filter(|c| !same_face(&c.rect, &rect))
                    .and_then(|c| c.motion_to(&rect, result.frame_index))
                {
                    self.start_moving(track, per_frame, result.frame_index)?;
                }
                self.identify(track, &result.frame, &rect, found_again);
                self.tracked.push(Tracked::started(track, &rect));
                out.started.push((track, rect, result.frame_index));
            }
        }
        self.candidates = candidates;
        self.end_unfound_after_cut(result.frame_index, &found_after_cut, out)
    }

    /// What a detection at `rect` of `frame` (number `frame_index`) does to the running tracks:
    /// moves a stuck or drifted one (`drift`), restarts a failing one it finds, or is ignored on
    /// a healthy one. Whether it was used so (else it may be a new face).
    fn use_on_tracks(
        &mut self,
        rect: &FaceRect,
        (frame, frame_index): (&GrayImage, usize),
        out: &mut AutoFrame,
    ) -> Result<bool, FaceError> {
        let failing = f64::from(self.config.tracker.failure_error);
        let on_track = self.tracked.iter().position(|t| same_face(&t.rect, rect));
        // A track stuck in a wrong pose on this face, or one that slid off it (`drift`),
        // moves to where its own template fits the face, its template kept.
        let moved = match on_track {
            Some(i) if self.tracked[i].error <= failing => {
                self.stuck_on(i, frame, rect).map(|state| (i, state))
            }
            Some(_) => None,
            None => self.drifted_onto(frame, rect),
        };
        if let Some((i, state)) = moved {
            let track = self.tracked[i].track;
            self.tracker.move_track(track, state)?;
            self.tracked[i].restarted_at(rect);
            self.placed_anew(track);
            out.restarted.push((track, *rect, frame_index));
            return Ok(true);
        }
        if on_track.is_some_and(|i| self.tracked[i].error <= failing) {
            out.ignored += 1;
            return Ok(true);
        }
        // A restart needs the face at the track's size: a false detection on part of the
        // face would pull the track onto an eye or the forehead.
        let restarts = on_track.filter(|&i| same_face_and_size(&self.tracked[i].rect, rect));
        if on_track.is_some() && restarts.is_none() {
            out.ignored += 1;
            return Ok(true);
        }
        if let Some(i) = restarts {
            let track = self.tracked[i].track;
            // The new template is taken with the face seen as the track has it.
            let restart = (self.tracker)
                .template_for_restart(track, frame, rect, frame_index)
                .ok()
                .filter(|r| self.has_contrast(r.template()));
            let Some(restart) = restart else {
                out.ignored += 1;
                return Ok(true);
            };
            self.tracker.restart_template(track, restart)?;
            self.tracked[i].restarted_at(rect);
            self.placed_anew(track);
            out.restarted.push((track, *rect, frame_index));
            return Ok(true);
        }
        Ok(false)
    }

    /// The template of a detection's rectangle, if it has the contrast of a face.
    fn trackable_template(&self, frame: &GrayImage, rect: &FaceRect) -> Option<Template> {
        let template = self.tracker.extract(frame, rect).ok()?;
        self.has_contrast(&template).then_some(template)
    }

    /// Whether a template's gray levels span the contrast of a face.
    fn has_contrast(&self, template: &Template) -> bool {
        let (low, high) = template
            .points
            .iter()
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), q| {
                (lo.min(q.gray), hi.max(q.gray))
            });
        high - low >= self.config.min_template_contrast
    }

    /// One frame: hand the detector a copy of this frame when the period says so (live: when it
    /// is idle), take the detection that is due (live: one that is ready; new faces start
    /// tracks), then track.
    pub fn step(&mut self, frame: &GrayImage) -> Result<AutoFrame, FaceError> {
        let mut out = AutoFrame {
            estimates: Vec::new(),
            started: Vec::new(),
            restarted: Vec::new(),
            ignored: 0,
            scene_cut: false,
            ended: Vec::new(),
            duplicates: Vec::new(),
            pinned: Vec::new(),
            faint: Vec::new(),
            carried_back: Vec::new(),
        };
        out.scene_cut = self.look_for_cut(frame);
        match self.config.detection_delay {
            None => {
                // A detection of a frame before the cut does not decide the cut's tracks.
                if let Some(result) = self.detector.take_ready()? {
                    self.use_detection(result, &mut out)?;
                }
                if self.detect_now() && self.detector.idle() {
                    self.send(frame)?;
                }
            }
            Some(delay) => {
                if self.detect_now() {
                    self.send(frame)?;
                }
                if let Some(due) = self.frame_index.checked_sub(delay)
                    && let Some(result) = self.detector.take_frame(due)?
                {
                    self.use_detection(result, &mut out)?;
                }
            }
        }
        out.estimates = self.tracker.step(frame)?;
        if let Some(identities) = self.identities.as_mut() {
            for e in &mut out.estimates {
                e.identity = identities.of(e.track).unwrap_or(e.track);
                if e.status != TrackStatus::Tracking {
                    identities.end(e.track);
                }
            }
        }
        self.keep_walking(&out.estimates)?;
        self.remember_lost(&out.estimates, &out.ended);
        self.tracked = out
            .estimates
            .iter()
            .filter(|e| e.status == TrackStatus::Tracking)
            .map(Tracked::from_estimate)
            .collect();
        out.duplicates = self.end_duplicates(frame)?;
        out.pinned = self.end_pinned()?;
        out.faint = self.end_faint()?;
        out.carried_back = self.bring_back_carried(frame, &out.estimates)?;
        self.frame_index += 1;
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_face_is_the_same_at_its_place_and_about_its_size() {
        let track = FaceRect {
            x: 100.0,
            y: 100.0,
            width: 80.0,
            height: 96.0,
        };
        let moved = FaceRect {
            x: 110.0,
            y: 95.0,
            width: 100.0,
            height: 120.0,
        };
        assert!(same_face_and_size(&track, &moved));
        let larger = FaceRect {
            x: 60.0,
            y: 60.0,
            width: 160.0,
            height: 192.0,
        };
        assert!(same_face(&track, &larger) && !same_face_and_size(&track, &larger));
        let elsewhere = FaceRect {
            x: 300.0,
            y: 100.0,
            width: 80.0,
            height: 96.0,
        };
        assert!(!same_face_and_size(&track, &elsewhere));
    }
}
