//! Starting tracks: a new face in a free slot, or a running track afresh on a new template
//! (a restart keeps the track's pose), and the templates they start from (extracted on the
//! face model, personalised to the face's landmarks when a personaliser is set); and ending a
//! track from outside.

use std::collections::VecDeque;
use std::sync::Arc;
use std::sync::atomic::Ordering;

use pf_core::batch::{BatchShape, gaussian_clouds};

use super::{FaceTracker, Track};
use crate::enlarge::Enlarged;
use crate::error::FaceError;
use crate::extraction::{ExtractionConfig, FaceRect, extract_template_seen, eye_outlines};
use crate::image::GrayImage;
use crate::landmarks::Landmarks;
use crate::lens::Lens;
use crate::likelihood::residual_error_through;
use crate::personal::Personaliser;
use crate::projection::{DIMS, RX, RY, RZ, SCALE, TX, TY, rotation};
use crate::template::Template;
use crate::view::View;

/// How many of a track's estimates it keeps for a restart (a detector's answer arrives
/// `--detection-delay` frames after the frame it looked at).
pub(super) const RECENT_ESTIMATES: usize = 16;

impl Track {
    /// The estimate of `frame`, else the newest one.
    fn estimate_at(&self, frame: usize) -> Option<[f32; DIMS]> {
        (self.recent.iter().find(|(f, _)| *f == frame))
            .or(self.recent.back())
            .map(|(_, state)| *state)
    }
}

/// A restart's new template and the state its particles start around, made only by
/// [`FaceTracker::template_for_restart`].
#[derive(Debug, Clone, PartialEq)]
pub struct Restart {
    template: Template,
    mean: [f32; DIMS],
    off_face_error: f64,
}

impl Restart {
    pub fn template(&self) -> &Template {
        &self.template
    }
}

/// Where a track (re)starts: the rectangle its S is relative to, the state its particles start
/// around, and its template's fit off the face there ([`FaceTracker::off_face_error`]).
struct Start {
    rect: FaceRect,
    mean: [f32; DIMS],
    off_face_error: f64,
}

fn not_running(track: usize) -> FaceError {
    FaceError::InvalidInput(format!("track {track} is not running"))
}

/// The state a new track's particles start around: the rectangle's centre, S = 1, R = 0, α = 1.
fn fresh_state(rect: &FaceRect) -> [f32; DIMS] {
    let (cx, cy) = rect.centre();
    [cx, cy, 1.0, 0.0, 0.0, 0.0, 1.0]
}

impl FaceTracker {
    /// Starts a new track on `rect` in `frame` (its template is extracted there; its particles
    /// start around (centre, S = 1, R = 0, α = 1)) in a free slot, and returns the track's number.
    /// The next `step` is the track's first.
    pub fn add_face(&mut self, frame: &GrayImage, rect: &FaceRect) -> Result<usize, FaceError> {
        let template = self.extract(frame, rect)?;
        self.add_template(frame, rect, template)
    }

    /// `add_face` with the template already extracted from `rect` of `frame` (by
    /// [`Self::extract`]).
    pub fn add_template(
        &mut self,
        frame: &GrayImage,
        rect: &FaceRect,
        template: Template,
    ) -> Result<usize, FaceError> {
        let slot = self.slots.iter().position(Option::is_none).ok_or_else(|| {
            FaceError::InvalidInput(format!(
                "all {} face slots are taken; free one or make the tracker larger",
                self.slots.len()
            ))
        })?;
        let id = self.next_track;
        let mean = fresh_state(rect);
        let off_face_error = self.measure_off_face_error(frame, &template, &mean, rect);
        let start = Start {
            rect: *rect,
            mean,
            off_face_error,
        };
        self.start_in_slot(slot, id, start, template)?;
        self.next_track += 1;
        Ok(id)
    }

    /// The template a restart of running track `track` takes from `rect` of `frame` (frame
    /// number `taken_at`), and the state its particles start around: for a detector that finds
    /// a face its track has drifted from ([`Self::restart_template`]).
    ///
    /// The track keeps its pose: the particles start at the track's scale and rotation in
    /// `taken_at` (or its newest estimate), and the template is taken with the face seen that
    /// way (`extraction::extract_template_seen`; the landmarks cast onto the turned model too),
    /// so the track's angles and scale go on from where they were instead of starting again
    /// from 0 and 1 with every new template: head pose read over a whole video stays one series.
    pub fn template_for_restart(
        &self,
        track: usize,
        frame: &GrayImage,
        rect: &FaceRect,
        taken_at: usize,
    ) -> Result<Restart, FaceError> {
        let running = self.running(track)?;
        let (cx, cy) = rect.centre();
        let (mean, view) = match running.estimate_at(taken_at) {
            Some(pose) => {
                let view = View {
                    scale: pose[SCALE],
                    rotation: rotation(pose[RX], pose[RY], pose[RZ]),
                };
                (
                    [cx, cy, pose[SCALE], pose[RX], pose[RY], pose[RZ], 1.0],
                    view,
                )
            }
            None => (fresh_state(rect), View::frontal()),
        };
        let template = self.extract_seen(frame, rect, &view)?.0;
        let off_face_error = self.measure_off_face_error(frame, &template, &mean, rect);
        Ok(Restart {
            template,
            mean,
            off_face_error,
        })
    }

    /// How well `template` fits its own frame off its face: the mean ε with the template a
    /// quarter of `rect`'s width or height to each side of `state` (its pose in `frame`). A
    /// track's confidence measures its fit against this: ε alone does not tell a face from
    /// background, since a small or blurred face's smooth template fits flat background about
    /// as well as it fits the face (docs/ACCURACY.md, "Tracks on faces").
    fn measure_off_face_error(
        &self,
        frame: &GrayImage,
        template: &Template,
        state: &[f32; DIMS],
        rect: &FaceRect,
    ) -> f64 {
        let (dx, dy) = (rect.width / 4.0, rect.height / 4.0);
        let shifts = [(dx, 0.0), (-dx, 0.0), (0.0, dy), (0.0, -dy)];
        let sum: f64 = (shifts.iter())
            .map(|&(x, y)| {
                let mut shifted = *state;
                shifted[TX] += x;
                shifted[TY] += y;
                residual_error_through(&shifted, template, frame, &self.lens)
            })
            .sum();
        sum / shifts.len() as f64
    }

    /// Starts running track `track` afresh from `restart` ([`Self::template_for_restart`]):
    /// new particles, the same number, S still relative to the rectangle it started from.
    pub fn restart_template(&mut self, track: usize, restart: Restart) -> Result<(), FaceError> {
        let slot = self.slot_of(track)?;
        let start = Start {
            rect: self.running(track)?.start,
            mean: restart.mean,
            off_face_error: restart.off_face_error,
        };
        self.start_in_slot(slot, track, start, restart.template)
    }

    /// Moves running track `track` to `state` (its particles start afresh around it), keeping
    /// its template: for a track found off its face, or stuck in a wrong pose on it, where its
    /// own template fits a detected face at `state` (`crate::auto`).
    pub fn move_track(&mut self, track: usize, state: [f32; DIMS]) -> Result<(), FaceError> {
        let running = self.running(track)?;
        let restart = Restart {
            template: running.template.clone(),
            mean: state,
            off_face_error: running.off_face_error,
        };
        self.restart_template(track, restart)
    }

    /// Sets running track `track` moving: its next step drifts its particles by `drift`
    /// (pixels in Tx and Ty) before the noise, and the motion it estimates then is measured
    /// from `from` (its position now: where it was started, or its newest estimate); its other
    /// values keep their own drift. The engine's `set_target_motion`, with the motion that the
    /// constant-velocity gain turns into `drift`. For a face found walking by two detections (a
    /// face that walks 30 px a frame outruns particles that start at rest within three
    /// frames), and to carry a walking track's whole last motion (`crate::auto`). The random
    /// walk ignores it.
    pub fn set_track_drift(
        &mut self,
        track: usize,
        from: [f32; 2],
        drift: [f32; 2],
    ) -> Result<(), FaceError> {
        self.check_nothing_in_flight("a track's motion is set")?;
        let gain = self.config.motion.gain();
        if gain <= 0.0 {
            return Ok(());
        }
        let slot = self.slot_of(track)?;
        let mut estimate = [f32::NAN; DIMS];
        let mut motion = [0.0; DIMS];
        for (d, at, by) in [(TX, from[0], drift[0]), (TY, from[1], drift[1])] {
            (estimate[d], motion[d]) = (at, by / gain);
        }
        let shard = (self.shards.iter_mut().find(|s| s.holds(slot)))
            .ok_or_else(|| FaceError::InvalidInput(format!("slot {slot} is in no shard")))?;
        shard.set_motion(slot, &estimate, &motion)
    }

    /// The state running track `track`'s particles were last started around (a start,
    /// restart or move), if it is running.
    pub fn started_around(&self, track: usize) -> Option<[f32; DIMS]> {
        self.running(track).ok().map(|t| t.started_around)
    }

    /// Ends running track `track`: its next step reports it lost (`TrackStatus::Lost`) and
    /// frees its slot. For a caller that knows the face is gone (a scene cut after which the
    /// detector does not find it again).
    pub fn end_track(&mut self, track: usize) -> Result<(), FaceError> {
        let slot = self.slot_of(track)?;
        if let Some(running) = &mut self.slots[slot] {
            running.ending = true;
        }
        Ok(())
    }

    /// Running track `track`'s template's ε a quarter of a face off its face in the frame it
    /// was taken from: the scale of its confidence.
    pub fn off_face_error(&self, track: usize) -> Option<f64> {
        self.running(track).ok().map(|t| t.off_face_error)
    }

    /// Whether track `track` is running (started and not yet reported lost).
    pub fn is_running(&self, track: usize) -> bool {
        self.running(track).is_ok()
    }

    fn slot_of(&self, track: usize) -> Result<usize, FaceError> {
        (self.slots.iter())
            .position(|s| s.as_ref().is_some_and(|t| t.id == track))
            .ok_or_else(|| not_running(track))
    }

    fn running(&self, track: usize) -> Result<&Track, FaceError> {
        let slot = self.slot_of(track)?;
        (self.slots[slot].as_ref()).ok_or_else(|| not_running(track))
    }

    /// The template this tracker would build for a face at `rect` in `frame`.
    pub fn extract(&self, frame: &GrayImage, rect: &FaceRect) -> Result<Template, FaceError> {
        Ok(self.extract_with_landmarks(frame, rect)?.0)
    }

    /// [`Self::extract`], with the landmarks the model was personalised to (`None` without a
    /// personaliser, or when the fit missed the face and the generic model was used).
    pub fn extract_with_landmarks(
        &self,
        frame: &GrayImage,
        rect: &FaceRect,
    ) -> Result<(Template, Option<Landmarks>), FaceError> {
        self.extract_seen(frame, rect, &View::frontal())
    }

    /// [`Self::extract_with_landmarks`] for a face seen with `view`. A face narrower than
    /// `ExtractionConfig::enlarge_below` is fitted and extracted in its region enlarged
    /// ([`Enlarged`]), and its template and landmarks scaled back to the frame.
    fn extract_seen(
        &self,
        frame: &GrayImage,
        rect: &FaceRect,
        view: &View,
    ) -> Result<(Template, Option<Landmarks>), FaceError> {
        self.check_size((frame.width, frame.height))?;
        rect.validate(frame)?;
        let enlarged = match self.config.extraction.enlarge_below {
            Some(width) => Enlarged::around(frame, rect, width)?,
            None => None,
        };
        let extraction = &self.config.extraction;
        let Some(enlarged) = enlarged else {
            return self.extract_through(frame, rect, view, &self.lens, extraction);
        };
        let lens = enlarged.lens(&self.lens);
        // A face takes as many points as its own width allows, not its enlarged width.
        let extraction = ExtractionConfig {
            points_per_width: (extraction.points_per_width).map(|p| p / enlarged.factor()),
            ..*extraction
        };
        let (template, landmarks) =
            self.extract_through(&enlarged.frame, &enlarged.rect, view, &lens, &extraction)?;
        let landmarks =
            landmarks.map(|fitted| fitted.into_iter().map(|l| enlarged.to_frame(l)).collect());
        Ok((enlarged.shrink(template), landmarks))
    }

    /// The template of the face at `rect` in `frame` seen with `view` through `lens`, extracted
    /// as `extraction` says (the tracker's frame, lens and settings, or a face's enlarged region,
    /// the lens as it sees it and the points its own width allows).
    fn extract_through(
        &self,
        frame: &GrayImage,
        rect: &FaceRect,
        view: &View,
        lens: &Lens,
        extraction: &ExtractionConfig,
    ) -> Result<(Template, Option<Landmarks>), FaceError> {
        let personal = self.personaliser.as_ref().and_then(|p| {
            let fitted = (p.personalise_seen(frame, rect, &self.model, view, lens)).ok();
            let counter = if fitted.is_some() {
                &self.personalised
            } else {
                &self.fit_failures
            };
            counter.fetch_add(1, Ordering::Relaxed);
            fitted
        });
        let model = personal.as_ref().map_or(&self.model, |p| &p.model);
        // The eyes are left out where the fit found them (they blink and turn on their own).
        let avoid = match (&personal, extraction.eye_outline_growth) {
            (Some(p), Some(growth)) => eye_outlines(&p.landmarks, growth),
            _ => Vec::new(),
        };
        let mut template =
            extract_template_seen(frame, rect, model, extraction, view, lens, &avoid)?;
        // The landmarks on the model's surface: the fitted ones, else the generic head's.
        let (cx, cy) = rect.centre();
        let (hw, hh) = (rect.width / 2.0, rect.height / 2.0);
        let on_surface = |u: f32, v: f32| view.surface_point(model, (hw, hh), u, v);
        // A fitted landmark seen frontally lies at its offset; seen turned, where its ray meets
        // the turned model (where it misses, as if seen frontally: only --landmarks-out uses
        // them).
        let fitted_on_surface = |l: &[f32; 2]| {
            let offset = [l[0] - cx, l[1] - cy];
            let frontal = || on_surface(offset[0] / hw, offset[1] / hh);
            if view.is_frontal() && lens.is_weak() {
                return frontal();
            }
            (view.cast_through(lens, [cx, cy], model, (hw, hh), offset))
                .map_or_else(frontal, |(point, _)| point)
        };
        template.landmarks = match (&personal, &self.personaliser) {
            (Some(p), _) => Some(p.landmarks.iter().map(fitted_on_surface).collect()),
            (None, Some(personaliser)) => Some(
                (personaliser.generic_landmarks().iter())
                    .map(|l| on_surface(l[0], l[1]))
                    .collect(),
            ),
            (None, None) => None,
        };
        Ok((template, personal.map(|p| p.landmarks)))
    }

    /// Builds each new face's template on the face model warped to that face's landmarks (the
    /// paper's personalised model), or on the generic model (`None`, the default). A face whose
    /// landmark fit fails (folds the model, leaves the face) gets the generic model.
    pub fn set_personaliser(&mut self, personaliser: Option<Arc<Personaliser>>) {
        self.personaliser = personaliser;
    }

    /// Templates built so far on a personalised model, and on the generic model because the
    /// landmark fit failed.
    pub fn personalisation_counts(&self) -> (usize, usize) {
        (
            self.personalised.load(Ordering::Relaxed),
            self.fit_failures.load(Ordering::Relaxed),
        )
    }

    /// Starts `track` in `slot` on `template`: its particles around `start.mean`, S relative
    /// to `start.rect`.
    fn start_in_slot(
        &mut self,
        slot: usize,
        track: usize,
        start: Start,
        template: Template,
    ) -> Result<(), FaceError> {
        self.check_nothing_in_flight("a face is started or restarted")?;
        let shape = BatchShape::new(1, self.config.particles, DIMS)?;
        // Each start gets its own initial cloud (the track's number and the frame key it).
        let key = (track as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ self.frame_index as u64;
        let cloud = gaussian_clouds(
            &shape,
            self.config.seed ^ key,
            &start.mean,
            &self.config.diffusion,
        );
        let shard = (self.shards.iter_mut().find(|s| s.holds(slot)))
            .ok_or_else(|| FaceError::InvalidInput(format!("slot {slot} is in no shard")))?;
        shard.start(slot, &cloud, &template)?;
        self.slots[slot] = Some(Track {
            id: track,
            template,
            start: start.rect,
            started_around: start.mean,
            off_face_error: start.off_face_error,
            bad_frames: 0,
            ending: false,
            recent: VecDeque::with_capacity(RECENT_ESTIMATES),
            started_before: self.frame_index,
        });
        Ok(())
    }
}
