//! Tracking several faces at once: each face is its own particle filter over the 7-D state,
//! all faces stepped together — on the CPU (`pf_core::batch::BatchFilter`, the likelihood on all
//! cores) or on the GPU (`pf_gpu::GpuFilter` with the packed, batched face likelihood: one submission per
//! frame, the frame the one upload).
//!
//! The batch has a fixed number of slots. A face starts in a free slot from a rectangle (its
//! template is extracted there, state (centre, S = 1, R = 0, α = 1)), at the start or later (from
//! a detector, see [`crate::auto`]). Its estimate is the weighted mean of its best M′ particles
//! (eq. 14). A track ends when the estimate's ε stays above a threshold for n frames in a row, or
//! when the face's centre leaves the frame; its slot is then free for a new face.

use crate::likelihood::gpu::FaceDispatch;
use pf_core::anneal::Annealing;
use pf_core::batch::{BatchConfig, BatchShape, Motion};
use pf_gpu::{GpuContext, GpuTime};

use crate::error::FaceError;
use crate::extraction::{ExtractionConfig, FaceRect};
use crate::image::GrayImage;
use crate::lens::Lens;
use crate::model::FaceModel;
use crate::personal::Personaliser;
use crate::projection::{ALPHA, DIMS, RX, RY, RZ, SCALE, TX, TY, rotation};
use crate::template::Template;
use in_flight::FrameInFlight;
use shards::ShardStep;
use shards::{FrameRef, Shard, joined_particles, shard_sizes, step_all};
use std::collections::VecDeque;
use std::sync::Arc;
use std::sync::atomic::AtomicUsize;

mod clouds;
pub mod confidence;
pub mod in_flight;
mod lag_window;
mod model;
pub mod shards;
mod start;
use start::RECENT_ESTIMATES;

/// Which state values the filter wraps as angles: the roll Rz (Rx and Ry are bounded to ±70°).
pub const ANGULAR: [bool; DIMS] = [false, false, false, false, false, true, false];
pub use start::Restart;

/// The largest pitch and yaw a track may take (70°).
pub const MAX_TURN: f32 = 1.222;

/// Where the filters run.
pub enum FaceBackend {
    Cpu,
    Gpu(Box<GpuContext>),
    /// The slots split over several GPUs, each running the whole step for its share
    /// ([`shards`]).
    Gpus(Vec<GpuContext>),
}

/// The tracker's settings.
#[derive(Debug, Clone, PartialEq)]
pub struct FaceTrackerConfig {
    /// Particles per face.
    pub particles: usize,
    /// Diffusion σ per frame for (Tx, Ty, S, Rx, Ry, Rz, α).
    pub diffusion: [f32; DIMS],
    /// M′ of the best-M′ weighted mean (eq. 14).
    pub best: usize,
    /// γ in π ∝ ε^−γ (the paper: 1). 0 weighs every particle the same: the filter only diffuses,
    /// the baseline a likelihood must beat (`reproduce-figures` draws it beside the tracker).
    pub sharpness: f32,
    /// A track ends when the estimate's ε exceeds this (tracked faces measured 0.005–0.09 on the
    /// synthetic videos, a face's template over textured background about 0.19) ...
    pub failure_error: f32,
    /// ... for this many frames in a row (a third of a second at 30 frames/s: an occluder over a
    /// third of the face raised ε to 0.22 for five frames, which must not end the track).
    pub failure_frames: usize,
    pub extraction: ExtractionConfig,
    /// How the GPU weighs the faces (the packed batched kernel by default).
    pub gpu_dispatch: FaceDispatch,
    pub seed: u64,
    /// Annealing layers per frame (`pf_core::anneal`; one layer: plain Condensation).
    pub annealing: Annealing,
    /// The dynamics' drift before the random walk (`pf_core::batch::Motion`).
    pub motion: Motion,
    /// The camera's focal length in pixels, its principal point the frame's middle: faces are
    /// seen through that pinhole ([`Lens`]). `None`: weak perspective, the paper's, right for
    /// a camera far from the faces (docs/ACCURACY.md, "The camera's lens").
    pub focal_length: Option<f32>,
    /// Where the camera's axis meets the frame (pixels; a calibration's cx, cy), with
    /// `focal_length`. `None`: the frame's middle.
    pub principal_point: Option<[f32; 2]>,
}

impl FaceTrackerConfig {
    /// The lens faces are seen through in frames of `frame_size`.
    pub fn lens(&self, (width, height): (u32, u32)) -> Result<Lens, FaceError> {
        let Some(focal) = self.focal_length else {
            return Ok(Lens::WEAK);
        };
        let mut lens = Lens::pinhole(focal, width, height)?;
        if let Some(principal) = self.principal_point {
            if !principal.iter().all(|c| c.is_finite()) {
                return Err(FaceError::InvalidInput(format!(
                    "the principal point must be finite (pixels), got {principal:?}"
                )));
            }
            lens.principal = principal;
        }
        Ok(lens)
    }

    /// This config seeing faces through a calibrated camera (`focal_length` the mean of fx and fy,
    /// `principal_point` (cx, cy)).
    pub fn with_camera(self, camera: &crate::camera::Intrinsics) -> Self {
        Self {
            focal_length: Some(camera.focal_length()),
            principal_point: Some([camera.cx, camera.cy]),
            ..self
        }
    }
}

impl Default for FaceTrackerConfig {
    fn default() -> Self {
        Self {
            particles: 1000,
            diffusion: [4.0, 4.0, 0.01, 0.03, 0.05, 0.03, 0.01],
            best: 100,
            sharpness: 8.0,
            failure_error: 0.12,
            failure_frames: 10,
            extraction: ExtractionConfig::default(),
            gpu_dispatch: FaceDispatch::PackedByLoad,
            seed: 1,
            // Chosen on the synthetic four-face video (docs/ACCURACY.md): five layers keeping
            // half the particles effective, the noise ×0.6 a layer, took the mean error from
            // 2.6 px and 3.8° (one layer) to 1.3 px and 2.2° over three seeds, and half the last
            // frame's motion as a drift to 1.2 px and 2.0°.
            annealing: Annealing::survival(5, 0.5, 0.6),
            motion: Motion::ConstantVelocity { gain: 0.5 },
            focal_length: None,
            principal_point: None,
        }
    }
}

/// Whether a face is still tracked.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TrackStatus {
    Tracking,
    /// Ended at this frame (the estimate's ε stayed too high, the face left the frame, or the
    /// caller ended it: [`FaceTracker::end_track`], after a scene cut). The
    /// track is reported once with this status; its slot is then free for a new face.
    Lost {
        frame: usize,
    },
}

/// One track's result for a frame.
#[derive(Debug, Clone, PartialEq)]
pub struct FaceEstimate {
    /// The track's number: 0, 1, … in the order faces were added, never reused.
    pub track: usize,
    /// The person the track follows: the track's number here; an [`crate::AutoTracker`] with
    /// identities gives a face found again after its track ended its earlier identity
    /// ([`crate::identity`]).
    pub identity: usize,
    /// The filter slot the track runs in (slots are reused after a track is lost).
    pub slot: usize,
    pub state: [f32; DIMS],
    /// ε of the estimate.
    pub error: f64,
    /// The posterior's spread per state dimension: the weighted standard deviation of the
    /// particles about their weighted mean (pixels, scale, radians, α), circular for the roll.
    pub spread: [f32; DIMS],
    /// The effective sample size of the last weighing (of the last annealing layer).
    pub ess: f64,
    /// The frame's log evidence for this track, log p̂(frame | earlier frames) up to the
    /// likelihood's constant: the filter's first weighing at β = 1 (`EngineReport::log_evidence`).
    /// Summed over a track's frames it compares models (a field of view, a template) on the
    /// same frames; −∞ when no particle fitted.
    pub log_evidence: f64,
    /// Whether the track is on its face, in [0, 1]: (1 − ε / ε_off, clamped) × the likelihood's
    /// sharpness ([`confidence::likelihood_sharpness`]), where ε_off is the template's fit a
    /// quarter of a face to the side of its face in the frame it was taken from (four sides,
    /// mean). 1 is a perfect fit under a likelihood sharp enough for the survival rule; 0 a fit
    /// no better than the template's off its face, or a likelihood equal for every particle.
    /// Unlike ε it compares across faces: a small or blurred face's smooth template fits
    /// background with a small ε too.
    pub confidence: f32,
    pub status: TrackStatus,
    /// The face's rectangle at this estimate: the starting rectangle scaled by S about the
    /// estimated centre (rotation ignored), for overlap tests and drawing.
    pub rect: FaceRect,
}

/// A face being tracked in a slot.
struct Track {
    id: usize,
    template: Template,
    /// The rectangle the track started from (a restart keeps it: S stays relative to it).
    start: FaceRect,
    /// The state its particles were last started around (a start, restart or move).
    started_around: [f32; DIMS],
    /// The template's ε off its face in the frame it was taken from (`off_face_error`): the
    /// confidence's scale.
    off_face_error: f64,
    bad_frames: usize,
    /// Ended from outside ([`FaceTracker::end_track`]): reported lost at the next step.
    ending: bool,
    /// The last [`RECENT_ESTIMATES`] estimates (frame, state), oldest first: a restart poses
    /// its new template in the estimate of the frame the template was taken from.
    recent: VecDeque<(usize, [f32; DIMS])>,
    /// The frame its particles were last started before (a start, restart or move): its
    /// lineage names no ancestors there ([`FaceTracker::slot_tracks`]).
    started_before: usize,
}

impl Track {
    /// [`FaceEstimate::confidence`] of a fit with ε `error` under a likelihood of
    /// [`confidence::likelihood_sharpness`] `sharpness`.
    fn confidence(&self, error: f64, sharpness: f64) -> f32 {
        confidence::confidence(error, self.off_face_error, sharpness)
    }
}

/// Several faces, each its own particle filter in a slot of one batch. Faces can be added while
/// tracking (`add_face`, from a detector); a lost track frees its slot.
pub struct FaceTracker {
    config: FaceTrackerConfig,
    /// The camera, from the config's focal length and the frame's size.
    lens: Lens,
    model: FaceModel,
    /// When set, each new face's template is built on the model warped to its landmarks.
    personaliser: Option<Arc<Personaliser>>,
    /// Templates built on a personalised model, and on the generic one after a failed fit.
    personalised: AtomicUsize,
    fit_failures: AtomicUsize,
    slots: Vec<Option<Track>>,
    next_track: usize,
    frame_size: (u32, u32),
    frame_index: usize,
    /// The filters: one engine (the CPU or one GPU), or one per GPU with a share of the slots.
    pub(crate) shards: Vec<Shard>,
    /// The last step's GPU time (GPU engines only; the longest of the GPUs').
    last_time: Option<GpuTime>,
    /// The last step's slots a lag behind, smoothed on the GPUs ([`Self::keep_lag_window`]).
    last_lagged: Option<pf_core::smooth::lag_window::LaggedSummaries>,
    /// Frames submitted and not yet finished, oldest first ([`in_flight`]).
    pub(crate) in_flight: VecDeque<FrameInFlight>,
}

/// The state bounds: S and α in sensible ranges, pitch and yaw within ±`MAX_TURN`.
fn state_bounds() -> (Vec<f32>, Vec<f32>) {
    let mut lower = vec![f32::NEG_INFINITY; DIMS];
    let mut upper = vec![f32::INFINITY; DIMS];
    (lower[SCALE], upper[SCALE]) = (0.2, 5.0);
    (lower[ALPHA], upper[ALPHA]) = (0.25, 4.0);
    // Towards ±90° of pitch or yaw a frontal template is ambiguous: on the synthetic videos a
    // pose 15° beyond a face turned 60° fitted as well as the true one (ε 0.054), and with a
    // ±75° bound one run in four (on the CPU; two faces of four on an H200) ran away to the
    // bound when the yaw turned back, and stayed. With ±70°, six of six runs kept all faces.
    // The roll wraps.
    for d in [RX, RY] {
        (lower[d], upper[d]) = (-MAX_TURN, MAX_TURN);
    }
    (lower, upper)
}

impl FaceTracker {
    /// Extracts a template per rectangle from the first frame and starts a filter per face
    /// (tracks 0, 1, … in the rectangles' order), with no room for more faces.
    pub fn new(
        first_frame: &GrayImage,
        rects: &[FaceRect],
        model: &FaceModel,
        config: FaceTrackerConfig,
        backend: FaceBackend,
    ) -> Result<Self, FaceError> {
        if rects.is_empty() {
            return Err(FaceError::InvalidInput(
                "give at least one face rectangle".into(),
            ));
        }
        let mut tracker = Self::with_capacity(
            (first_frame.width, first_frame.height),
            rects.len(),
            model,
            config,
            backend,
        )?;
        for (i, r) in rects.iter().enumerate() {
            tracker
                .add_face(first_frame, r)
                .map_err(|e| FaceError::InvalidInput(format!("face {i}: {e}")))?;
        }
        Ok(tracker)
    }

    /// A tracker for frames of `frame_size` with room for `capacity` faces at once, none yet.
    pub fn with_capacity(
        frame_size: (u32, u32),
        capacity: usize,
        model: &FaceModel,
        config: FaceTrackerConfig,
        backend: FaceBackend,
    ) -> Result<Self, FaceError> {
        if capacity == 0 {
            return Err(FaceError::InvalidInput(
                "a tracker needs room for at least one face".into(),
            ));
        }
        if !(config.failure_error > 0.0 && config.failure_error <= 1.0) {
            return Err(FaceError::InvalidInput(format!(
                "failure_error must be within (0, 1] (a fit's ε lies in [0, 1); 1 never ends a track), got {}",
                config.failure_error
            )));
        }
        if !(config.sharpness.is_finite() && config.sharpness >= 0.0) {
            return Err(FaceError::InvalidInput(format!(
                "sharpness must be finite and >= 0, got {}",
                config.sharpness
            )));
        }
        let shape = BatchShape::new(capacity, config.particles, DIMS)?;
        let batch = BatchConfig {
            shape,
            seed: config.seed,
            sigma: config.diffusion.to_vec(),
            bounds: Some(state_bounds()),
            angular: ANGULAR.to_vec(),
            ess_threshold: f64::INFINITY,
            best: config.best.min(config.particles),
            annealing: config.annealing.clone(),
            motion: config.motion,
        };
        batch.validate()?;
        let contexts = match backend {
            FaceBackend::Cpu => vec![None],
            FaceBackend::Gpu(ctx) => vec![Some(*ctx)],
            // At most one GPU per slot: more would idle.
            FaceBackend::Gpus(contexts) => contexts.into_iter().take(capacity).map(Some).collect(),
        };
        let sizes = shard_sizes(capacity, contexts.len())?;
        let mut shards = Vec::with_capacity(sizes.len());
        let mut first_slot = 0;
        for (ctx, slots) in contexts.into_iter().zip(sizes) {
            shards.push(Shard::new(
                &config, &batch, first_slot, slots, frame_size, ctx,
            )?);
            first_slot += slots;
        }
        Ok(Self {
            lens: config.lens(frame_size)?,
            model: model.clone(),
            personaliser: None,
            personalised: AtomicUsize::new(0),
            fit_failures: AtomicUsize::new(0),
            slots: (0..capacity).map(|_| None).collect(),
            next_track: 0,
            frame_size,
            frame_index: 0,
            shards,
            last_time: None,
            last_lagged: None,
            in_flight: VecDeque::new(),
            config,
        })
    }

    /// Slots with no face in them.
    pub fn free_slots(&self) -> usize {
        self.slots.iter().filter(|s| s.is_none()).count()
    }

    pub fn capacity(&self) -> usize {
        self.slots.len()
    }

    /// The template of a track that is still running.
    pub fn template(&self, track: usize) -> Option<&Template> {
        self.slots
            .iter()
            .flatten()
            .find(|t| t.id == track)
            .map(|t| &t.template)
    }

    /// The templates of the running tracks, by track number.
    pub fn templates(&self) -> Vec<(usize, &Template)> {
        let mut out: Vec<_> = self
            .slots
            .iter()
            .flatten()
            .map(|t| (t.id, &t.template))
            .collect();
        out.sort_by_key(|(id, _)| *id);
        out
    }

    /// Every slot's particles after the last step: the batch shape (slots × particles × 7), the
    /// states in the batch layout `[(slot·7 + d)·M + m]` and the normalised log-weights
    /// `[slot·M + m]`. On the GPU this reads them back (a wait), so call it only when needed.
    pub fn particles(&self) -> Result<(BatchShape, Vec<f32>, Vec<f32>), FaceError> {
        self.check_nothing_in_flight("the particles are read")?;
        joined_particles(&self.shards)
    }

    /// The constant-velocity gain of the dynamics (0 for the random walk).
    pub fn motion_gain(&self) -> f32 {
        self.config.motion.gain()
    }

    /// The camera the faces are seen through ([`FaceTrackerConfig::focal_length`]).
    pub fn lens(&self) -> Lens {
        self.lens
    }

    /// The GPU the filter runs on (the first one with several; `None` on the CPU engine).
    pub fn gpu_context(&self) -> Option<&pf_gpu::GpuContext> {
        self.shards.first().and_then(|s| s.filter.context())
    }

    /// The GPU's time for the last step's submission (timestamps where the adapter has them),
    /// on the GPU backend after a step.
    pub fn last_gpu_time(&self) -> Option<GpuTime> {
        self.last_time
    }

    pub(crate) fn check_size(&self, (width, height): (u32, u32)) -> Result<(), FaceError> {
        if (width, height) != self.frame_size {
            return Err(FaceError::InvalidInput(format!(
                "frame {} is {width}x{height}; the video started at {}x{}",
                self.frame_index, self.frame_size.0, self.frame_size.1
            )));
        }
        Ok(())
    }

    /// One frame for every running track, in slot order. A track that fails here is reported
    /// as `Lost` and its slot freed.
    pub fn step(&mut self, frame: &GrayImage) -> Result<Vec<FaceEstimate>, FaceError> {
        self.step_frame(FrameRef::Image(frame))
    }

    /// [`FaceTracker::step`] on borrowed 8-bit pixels (`width × height`, row-major): a GPU
    /// uploads them with no copy of the frame on the host (a binding's arrays).
    pub fn step_pixels(
        &mut self,
        width: u32,
        height: u32,
        pixels: &[u8],
    ) -> Result<Vec<FaceEstimate>, FaceError> {
        if pixels.len() != width as usize * height as usize {
            return Err(FaceError::InvalidInput(format!(
                "a {width}x{height} frame has {} pixels, got {}",
                width as usize * height as usize,
                pixels.len()
            )));
        }
        self.step_frame(FrameRef::Pixels {
            width,
            height,
            data: pixels,
        })
    }

    pub(crate) fn step_frame(
        &mut self,
        frame: FrameRef<'_>,
    ) -> Result<Vec<FaceEstimate>, FaceError> {
        self.check_nothing_in_flight("a frame is stepped alone")?;
        self.step_now(frame)
    }

    /// One frame, stepped and waited for (frames in flight are the caller's to rule out).
    pub(crate) fn step_now(&mut self, frame: FrameRef<'_>) -> Result<Vec<FaceEstimate>, FaceError> {
        self.check_size(frame.size())?;
        // Each slot's estimate and its ε (the failure test's input); free slots are not weighed
        // on the CPU, and weigh the GPU's empty template there (ε = 1, a flat likelihood).
        let templates: Vec<Option<&Template>> = (self.slots.iter())
            .map(|s| s.as_ref().map(|t| &t.template))
            .collect();
        let steps = step_all(&mut self.shards, frame, &templates, self.config.sharpness)?;
        Ok(self.conclude(steps, frame.size()))
    }

    /// [`confidence::likelihood_sharpness`] of a track whose last layer's ESS is `ess`.
    fn sharpness(&self, ess: f64) -> f64 {
        confidence::likelihood_sharpness(ess, self.config.particles, &self.config.annealing)
    }

    /// The tracks' results from the shards' steps of the next frame (`frame_size`): each
    /// running track's estimate, its failure test, and the slots of lost tracks freed.
    pub(crate) fn conclude(
        &mut self,
        steps: Vec<ShardStep>,
        (frame_width, frame_height): (u32, u32),
    ) -> Vec<FaceEstimate> {
        let slots = self.slots.len();
        let state_of = |estimates: &[f32], t: usize| -> [f32; DIMS] {
            std::array::from_fn(|d| estimates[t * DIMS + d])
        };
        self.last_time = (steps.iter().filter_map(|s| s.gpu_time)).max_by_key(|t| t.duration());
        self.last_lagged = lag_window::joined(&steps);
        let (mut estimates, mut spreads, mut ess, mut log_evidence, mut errors) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for step in steps {
            estimates.extend(step.estimates);
            spreads.extend(step.spreads);
            ess.extend(step.ess);
            log_evidence.extend(step.log_evidence);
            errors.extend(step.errors);
        }
        let checked: Vec<([f32; DIMS], f64)> = (0..slots)
            .map(|t| (state_of(&estimates, t), errors[t]))
            .collect();
        let mut out = Vec::new();
        for (slot, (state, error)) in checked.into_iter().enumerate() {
            let sharpness = self.sharpness(ess[slot]);
            let Some(track) = &mut self.slots[slot] else {
                continue;
            };
            if track.recent.len() == RECENT_ESTIMATES {
                track.recent.pop_front();
            }
            track.recent.push_back((self.frame_index, state));
            track.bad_frames = if error > f64::from(self.config.failure_error) {
                track.bad_frames + 1
            } else {
                0
            };
            let outside = !(0.0..frame_width as f32).contains(&state[TX])
                || !(0.0..frame_height as f32).contains(&state[TY]);
            let status =
                if outside || track.ending || track.bad_frames >= self.config.failure_frames {
                    TrackStatus::Lost {
                        frame: self.frame_index,
                    }
                } else {
                    TrackStatus::Tracking
                };
            let (w, h) = (
                track.start.width * state[SCALE],
                track.start.height * state[SCALE],
            );
            let confidence = track.confidence(error, sharpness);
            out.push(FaceEstimate {
                track: track.id,
                identity: track.id,
                slot,
                state,
                error,
                spread: std::array::from_fn(|d| spreads[slot * DIMS + d]),
                ess: ess[slot],
                log_evidence: log_evidence[slot],
                confidence,
                status,
                rect: FaceRect {
                    x: state[TX] - w / 2.0,
                    y: state[TY] - h / 2.0,
                    width: w,
                    height: h,
                },
            });
            if status != TrackStatus::Tracking {
                self.slots[slot] = None;
            }
        }
        self.frame_index += 1;
        out
    }
}

/// Translation error (pixels) and rotation error (degrees: the angle of R_est⁻¹·R_true) between
/// two states.
pub fn pose_errors(estimate: &[f32; DIMS], truth: &[f32; DIMS]) -> (f32, f32) {
    let translation =
        ((estimate[TX] - truth[TX]).powi(2) + (estimate[TY] - truth[TY]).powi(2)).sqrt();
    let a = rotation(estimate[RX], estimate[RY], estimate[RZ]);
    let b = rotation(truth[RX], truth[RY], truth[RZ]);
    let relative = a.transpose() * b;
    let cos = ((relative.trace() - 1.0) / 2.0).clamp(-1.0, 1.0);
    (translation, cos.acos().to_degrees())
}
