//! Synthetic face videos with ground truth: textured heads (the generic face model with a
//! face-like albedo, Lambert-shaded; [`look`] draws them, each a person of their own in a
//! scenario about identities) moving and turning along known 7-D paths over a textured
//! background, under a changing light, with an occluder passing over one face.
//!
//! Ground truth is in the tracker's terms: a head drawn with half-width `half_width·s` has scale
//! S = s/s₀ relative to its first frame, where it is frontal; (Tx, Ty) is its centre's image
//! position; α = 1/g for a light gain g (the tracker's α·I ≈ J undoes it).

use std::f32::consts::PI;
use std::ops::Range;
use std::sync::{Arc, Mutex, PoisonError};

use rayon::prelude::*;

use crate::error::FaceError;
use crate::extraction::FaceRect;
use crate::image::GrayImage;
use crate::lens::Lens;
use crate::model::FaceModel;
use crate::projection::{ALPHA, DIMS, RX, RY, RZ, SCALE, TX, TY};

mod look;
mod splat;
pub use look::{Look, albedo, albedo_of};
use look::{background, value_noise};
use splat::{BAND_ROWS, HeadSurface, Splatter, SurfaceSample, splat_head};

/// How a synthetic video is made.
#[derive(Debug, Clone, PartialEq)]
pub struct FaceSynthConfig {
    pub width: u32,
    pub height: u32,
    pub frames: usize,
    pub faces: usize,
    /// The head's half-width in pixels at its first frame's scale.
    pub half_width: f32,
    /// Largest yaw (radians).
    pub max_yaw: f32,
    /// Draw an occluder over the first face in the middle third of the video.
    pub occlusion: bool,
    /// From this frame on, the first face walks out of the frame to the right at `walk_speed`.
    pub exit_after: Option<usize>,
    /// With `exit_after`: from this frame on, the first face walks back the way it went (at the
    /// same speed) to its place, re-entering the frame on the way.
    pub return_at: Option<usize>,
    /// How far the walking face of `exit_after` moves a frame (pixels): 30 in the paper's
    /// setting; the identity scenario's in proportion to the frame ([`Self::exits_and_crossings`]).
    pub walk_speed: f32,
    /// From this frame on, faces 1 and 2 walk across each other to each other's place (over a
    /// fifth of the video, at least 10 frames), passing in front of one another half way.
    pub crossing_at: Option<usize>,
    /// Face k is in the video from frame k·`enter_every` on (0: every face from the start).
    pub enter_every: usize,
    /// Draw each face as a person of their own ([`Look::of_person`]: hair, brows, eyes, mouth,
    /// a beard), as a scenario about who is who needs; `false`: every head has the paper's look
    /// ([`Look::SHARED`]), its skin's noise apart.
    pub distinct_people: bool,
    pub seed: u64,
    /// The camera's focal length in pixels (the principal point the frame's middle): the heads
    /// are seen through that pinhole. `None`: weak perspective, as the paper's videos.
    pub focal_length: Option<f32>,
}

/// The walking face's speed (pixels a frame) in a video of the paper's width, [`PAPER_WIDTH`].
pub const WALK_SPEED_AT_PAPER_WIDTH: f32 = 30.0;

/// The paper's frame width in pixels.
pub const PAPER_WIDTH: f32 = 1024.0;

/// How far a head wobbles either way across the frame (pixels).
const WOBBLE_X: f32 = 40.0;

/// The shortest focal length a synthetic video takes, in head half-widths.
pub const MIN_FOCAL_HALF_WIDTHS: f32 = 4.0;

impl FaceSynthConfig {
    /// The paper's setting: 1024×768, four faces.
    pub fn paper(frames: usize) -> Self {
        Self {
            width: 1024,
            height: 768,
            frames,
            faces: 4,
            half_width: 60.0,
            max_yaw: 60f32.to_radians(),
            occlusion: true,
            exit_after: None,
            return_at: None,
            walk_speed: WALK_SPEED_AT_PAPER_WIDTH,
            crossing_at: None,
            enter_every: 0,
            distinct_people: false,
            seed: 11,
            focal_length: None,
        }
    }

    /// The lens the heads are seen through (weak perspective for a focal length that
    /// [`Self::validate`] refuses).
    pub fn lens(&self) -> Lens {
        (self.focal_length)
            .and_then(|f| Lens::pinhole(f, self.width, self.height).ok())
            .unwrap_or(Lens::WEAK)
    }

    pub fn validate(&self) -> Result<(), FaceError> {
        let bad = |m: String| Err(FaceError::InvalidInput(m));
        if !(64..=16384).contains(&self.width) || !(64..=16384).contains(&self.height) {
            return bad(format!(
                "frames must be 64x64 to 16384x16384, got {}x{}",
                self.width, self.height
            ));
        }
        if self.frames == 0 || self.faces == 0 || self.faces > 16 {
            return bad(format!(
                "a video needs 1 or more frames and 1 to 16 faces (got {} frames, {} faces)",
                self.frames, self.faces
            ));
        }
        if !(self.half_width.is_finite() && self.half_width >= 8.0) {
            return bad(format!(
                "the head half-width must be >= 8 px, got {}",
                self.half_width
            ));
        }
        if !(self.walk_speed.is_finite() && self.walk_speed >= 0.0) {
            return bad(format!(
                "the walking speed must be a finite number of pixels a frame, at least 0, got {}",
                self.walk_speed
            ));
        }
        if !(self.max_yaw.is_finite() && self.max_yaw.abs() <= PI / 2.0) {
            return bad(format!("the yaw must be within ±90°, got {}", self.max_yaw));
        }
        // A head spans about ±1.5 half-widths in depth, and grows to twice its size: a camera
        // nearer than this would have part of it at or behind its centre.
        let nearest = MIN_FOCAL_HALF_WIDTHS * self.half_width;
        if let Some(f) = self.focal_length
            && !(f.is_finite() && f >= nearest)
        {
            return bad(format!(
                "the focal length must be at least {nearest} px ({MIN_FOCAL_HALF_WIDTHS} head half-widths) for these heads, got {f}"
            ));
        }
        Ok(())
    }

    /// The identity scenario's walking speed: 30 px a frame at the paper's 1024 px width, in
    /// proportion at other widths, so that a smaller video is the same scenario made smaller
    /// (its heads, whose default width follows the frame's, and their places scale with the
    /// frame too); faster in a video too short for that speed to take the face's centre out of
    /// the picture ([`Self::leave_speed`]), so that the face always leaves.
    fn scenario_walk_speed(&self) -> f32 {
        let scaled = WALK_SPEED_AT_PAPER_WIDTH * self.width as f32 / PAPER_WIDTH;
        scaled.max(self.leave_speed())
    }

    /// The speed that takes the walking face's centre past the frame's right edge (and its
    /// wobble) in nine tenths of its time away, `exit_after` to `return_at`; 0 when it does not
    /// return.
    fn leave_speed(&self) -> f32 {
        let (Some(exit), Some(back)) = (self.exit_after, self.return_at) else {
            return 0.0;
        };
        let away = back.saturating_sub(exit);
        if away == 0 {
            return 0.0;
        }
        let distance = self.width as f32 - self.home(0).0 + WOBBLE_X;
        distance / (0.9 * away as f32)
    }

    /// Where face `k` sits at t = 0: a grid of cells over the frame.
    fn home(&self, k: usize) -> (f32, f32) {
        let cols = (self.faces as f32).sqrt().ceil() as usize;
        let rows = self.faces.div_ceil(cols);
        let (c, r) = (k % cols, k / cols);
        (
            self.width as f32 * (c as f32 + 0.5) / cols as f32,
            self.height as f32 * (r as f32 + 0.5) / rows as f32,
        )
    }
}

impl FaceSynthConfig {
    /// The first frame face `k` is in.
    pub fn entry_frame(&self, k: usize) -> usize {
        k * self.enter_every
    }

    /// Whether face `k` is in frame `frame`.
    pub fn present(&self, k: usize, frame: usize) -> bool {
        frame >= self.entry_frame(k)
    }

    /// Whether face `k` is in frame `frame` with its centre inside the picture: the faces a
    /// tracker is scored on (`crate::mot`).
    pub fn visible(&self, k: usize, frame: usize) -> bool {
        let s = face_state(self, k, frame);
        self.present(k, frame)
            && (0.0..self.width as f32).contains(&s[TX])
            && (0.0..self.height as f32).contains(&s[TY])
    }

    /// A named ground-truth scenario for identities (`face synth --scenario`): four faces over
    /// `frames` frames; the first walks out to the right at 15 % of the video (30 px a frame at
    /// 1024 px wide, in proportion at other widths, faster in a short video:
    /// [`Self::scenario_walk_speed`])
    /// and turns back at 40 %, faces 1 and 2 cross each other's path from 65 %.
    pub fn exits_and_crossings(mut self, frames: usize) -> Self {
        self.frames = frames;
        self.faces = 4;
        self.occlusion = false;
        self.enter_every = 0;
        self.exit_after = Some(frames * 15 / 100);
        self.return_at = Some(frames * 40 / 100);
        self.crossing_at = Some(frames * 65 / 100);
        self.distinct_people = true;
        self.walk_speed = self.scenario_walk_speed();
        self
    }
}

/// The light gain g(t) of frame `frame` (α = 1/g).
fn light_gain(frame: usize) -> f32 {
    1.0 + 0.2 * (frame as f32 * 0.05).sin()
}

/// Face `k`'s ground-truth state at `frame` (frontal, S = 1, α = 1 at its entry frame; its
/// motion runs on its own clock from there).
pub fn face_state(config: &FaceSynthConfig, k: usize, frame: usize) -> [f32; DIMS] {
    let entry = config.entry_frame(k);
    let t = frame.saturating_sub(entry) as f32;
    let phase = k as f32 * 1.7;
    let (hx, hy) = config.home(k);
    let wobble = |f: f32, p: f32| (f * t + p).sin();
    let mut s = [0.0; DIMS];
    s[TX] = hx + WOBBLE_X * wobble(0.03, phase) - WOBBLE_X * phase.sin();
    s[TY] = hy + 25.0 * wobble(0.025, 2.0 * phase) - 25.0 * (2.0 * phase).sin();
    s[SCALE] = 1.0 + 0.1 * (0.02 * t).sin();
    s[RX] = 0.2 * (0.04 * t).sin();
    s[RY] = config.max_yaw * (0.035 * t).sin();
    s[RZ] = 0.15 * (0.03 * t).sin();
    s[ALPHA] = light_gain(entry) / light_gain(frame);
    if let Some(start) = config.exit_after
        && k == 0
        && frame > start
    {
        let out = (frame - start) as f32;
        let walked = match config.return_at {
            // Back the way it went, from where it had got to, to its place.
            Some(back) if frame > back => {
                let away = back.saturating_sub(start) as f32;
                (away - (frame - back) as f32).max(0.0)
            }
            _ => out,
        };
        s[TX] += config.walk_speed * walked;
    }
    if let Some(at) = config.crossing_at
        && (k == 1 || k == 2)
        && config.faces > 2
        && frame > at
    {
        // Along the line between the two places, eased in and out.
        let span = (config.frames / 5).max(10);
        let t = ((frame - at) as f32 / span as f32).min(1.0);
        let eased = t * t * (3.0 - 2.0 * t);
        let (mine, other) = (config.home(k), config.home(3 - k));
        s[TX] += eased * (other.0 - mine.0);
        s[TY] += eased * (other.1 - mine.1);
    }
    s
}

/// The face rectangle at its entry frame (frame 0 unless faces enter in turn), in the tracker's
/// terms.
pub fn initial_rect(config: &FaceSynthConfig, k: usize) -> FaceRect {
    let s = face_state(config, k, config.entry_frame(k));
    let (hw, hh) = (
        config.half_width * s[SCALE],
        config.half_width * HEIGHT_RATIO * s[SCALE],
    );
    FaceRect {
        x: s[TX] - hw,
        y: s[TY] - hh,
        width: 2.0 * hw,
        height: 2.0 * hh,
    }
}

/// A face is this much taller than wide.
pub const HEIGHT_RATIO: f32 = 1.25;

/// The surface samples of head `k` on the grid of `steps` per unit, inside the unit disk, in
/// row order.
fn head_surface(model: &FaceModel, steps: i32, seed: u64, look: &Look) -> HeadSurface {
    let samples: Vec<SurfaceSample> = (-steps..=steps)
        .into_par_iter()
        .flat_map_iter(|j| {
            (-steps..=steps).filter_map(move |i| {
                let (u, v) = (i as f32 / steps as f32, j as f32 / steps as f32);
                if u * u + v * v > 1.0 {
                    return None;
                }
                let (height, normal) = model.sample(u, v);
                Some(SurfaceSample {
                    u,
                    v,
                    height,
                    normal,
                    albedo: albedo_of(u, v, seed, look),
                })
            })
        })
        .collect();
    HeadSurface::new(steps, &samples)
}

/// Renders a synthetic video frame by frame. What stays the same from frame to frame is made
/// once: the background, and each head's surface samples (model height, normal and albedo) at
/// one grid density, the finest its scale asks for over the video (a density that followed the
/// scale would change every few frames, and making a surface costs more than splatting it). A
/// frame is then the background, the heads splatted from their samples with a depth
/// buffer, the occluder and the light: the same pixels as [`render_frame`], several times
/// faster, so that the synthetic run shows the tracker's speed rather than the renderer's.
///
/// Frames are independent of each other: [`FaceVideoRenderer::render_frames`] renders several
/// at once, one per core, which scales far better than the parallel passes inside one frame
/// (each of those is a short pass over a frame, with a barrier after it).
#[derive(Debug)]
pub struct FaceVideoRenderer {
    config: FaceSynthConfig,
    model: FaceModel,
    background: Vec<f32>,
    /// Each head's surface density over the video: the most samples per unit any of its
    /// frames asks for.
    video_steps: Vec<i32>,
    /// Each head's surfaces for the densities its latest frames asked for, newest last, shared
    /// by the frames being rendered at once. A head's density steps with its scale every few
    /// frames, so a batch of frames asks for several; making one costs more than splatting it.
    surfaces: Mutex<Vec<Vec<Arc<HeadSurface>>>>,
}

/// A head at one frame: which head, its pose, and its surface's density (samples per unit).
struct HeadPose {
    head: usize,
    state: [f32; DIMS],
    steps: i32,
}

/// Densities kept per head: the video's, and finer ones for frames past its end.
const SURFACES_KEPT: usize = 8;

/// Surface samples per unit of the model's u and v for a head at `scale`: a sample every
/// ≤ 0.4 px in the image, so that a turned head's stretched flanks are still covered.
fn steps_for_scale(config: &FaceSynthConfig, scale: f32) -> i32 {
    (2.5 * config.half_width * HEIGHT_RATIO * scale).ceil() as i32
}

impl Clone for FaceVideoRenderer {
    fn clone(&self) -> Self {
        Self {
            config: self.config.clone(),
            model: self.model.clone(),
            background: self.background.clone(),
            video_steps: self.video_steps.clone(),
            surfaces: Mutex::new(self.cached_surfaces().clone()),
        }
    }
}

impl FaceVideoRenderer {
    pub fn new(config: &FaceSynthConfig, model: &FaceModel) -> Result<Self, FaceError> {
        config.validate()?;
        let w = config.width;
        let background = (0..w * config.height)
            .into_par_iter()
            .map(|k| background((k % w) as f32, (k / w) as f32, config.seed))
            .collect();
        let video_steps = (0..config.faces)
            .map(|k| {
                (0..config.frames)
                    .map(|f| steps_for_scale(config, face_state(config, k, f)[SCALE]))
                    .max()
                    .unwrap_or(1)
            })
            .collect();
        Ok(Self {
            config: config.clone(),
            model: model.clone(),
            background,
            video_steps,
            surfaces: Mutex::new(vec![Vec::new(); config.faces]),
        })
    }

    fn cached_surfaces(&self) -> std::sync::MutexGuard<'_, Vec<Vec<Arc<HeadSurface>>>> {
        // A panic elsewhere cannot leave the cache half-written (a slot is replaced whole).
        self.surfaces.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Head `k`'s surface at `steps` samples per unit: the cached one, or made (outside the
    /// lock, so that other frames go on) and cached.
    fn surface(&self, k: usize, steps: i32) -> Arc<HeadSurface> {
        if let Some(surface) = self.cached_surfaces()[k]
            .iter()
            .find(|surface| surface.steps == steps)
        {
            return Arc::clone(surface);
        }
        let seed = self.config.seed.wrapping_add(k as u64 * 1000);
        let look = match self.config.distinct_people {
            true => Look::of_person(self.config.seed, k),
            false => Look::SHARED,
        };
        let surface = Arc::new(head_surface(&self.model, steps, seed, &look));
        let mut cache = self.cached_surfaces();
        let kept = &mut cache[k];
        if !kept.iter().any(|s| s.steps == steps) {
            if kept.len() == SURFACES_KEPT {
                kept.remove(0);
            }
            kept.push(Arc::clone(&surface));
        }
        surface
    }

    /// Frames `frames` of the video, rendered at once (each on one core), in order; the same
    /// pixels as [`FaceVideoRenderer::render`]. The heads' surfaces the batch needs are made
    /// first, each once: frames rendered side by side ask for the same new densities at the
    /// same time, and each would make its own.
    pub fn render_frames(&self, frames: Range<usize>) -> Vec<Result<GrayImage, FaceError>> {
        let poses: Vec<Vec<HeadPose>> = frames.clone().map(|f| self.head_poses(f)).collect();
        let mut needed: Vec<(usize, i32)> =
            poses.iter().flatten().map(|p| (p.head, p.steps)).collect();
        needed.sort_unstable();
        needed.dedup();
        let surfaces: Vec<((usize, i32), Arc<HeadSurface>)> = needed
            .into_par_iter()
            .map(|(k, steps)| ((k, steps), self.surface(k, steps)))
            .collect();
        let surface_of = |pose: &HeadPose| {
            match surfaces.binary_search_by_key(&(pose.head, pose.steps), |s| s.0) {
                Ok(i) => Arc::clone(&surfaces[i].1),
                // Not reached: every pose's surface was made above.
                Err(_) => self.surface(pose.head, pose.steps),
            }
        };
        frames
            .zip(poses)
            .collect::<Vec<_>>()
            .into_par_iter()
            .map(|(f, poses)| {
                let heads: Vec<_> = poses.iter().map(|p| (p.state, surface_of(p))).collect();
                self.render_on_this_thread(f, &heads)
            })
            .collect()
    }

    /// The heads present at `frame`: each one's pose and its surface's density (the video's,
    /// or finer where a frame past the video's end asks for more).
    fn head_poses(&self, frame: usize) -> Vec<HeadPose> {
        let config = &self.config;
        (0..config.faces)
            .filter(|&k| config.present(k, frame))
            .map(|k| {
                let state = face_state(config, k, frame);
                HeadPose {
                    head: k,
                    state,
                    steps: steps_for_scale(config, state[SCALE]).max(self.video_steps[k]),
                }
            })
            .collect()
    }

    /// Head `k`'s pose at `frame` and its surface samples for that pose's scale.
    fn posed_head(&self, pose: &HeadPose) -> ([f32; DIMS], Arc<HeadSurface>) {
        (pose.state, self.surface(pose.head, pose.steps))
    }

    /// Frame `frame` on the calling thread alone, in buffers that the thread keeps from frame
    /// to frame (a fresh 3 MB buffer per frame costs page faults, which serialise threads): the
    /// splats in sample order with one depth test each, as the banded pass resolves them.
    fn render_on_this_thread(
        &self,
        frame: usize,
        heads: &[([f32; DIMS], Arc<HeadSurface>)],
    ) -> Result<GrayImage, FaceError> {
        thread_local! {
            static SCRATCH: std::cell::RefCell<(Vec<f32>, Vec<f32>)> =
                const { std::cell::RefCell::new((Vec::new(), Vec::new())) };
        }
        let config = &self.config;
        SCRATCH.with_borrow_mut(|(data, depth)| {
            data.clear();
            data.extend_from_slice(&self.background);
            depth.clear();
            depth.resize(data.len(), f32::NEG_INFINITY);
            for (state, surface) in heads {
                let splatter = Splatter::new(config, state);
                splatter.splat(surface, 0..surface.len(), |idx, z, value| {
                    if z > depth[idx] {
                        depth[idx] = z;
                        data[idx] = value;
                    }
                });
            }
            if config.occlusion && config.frames >= 3 {
                draw_occluder(config, frame, data);
            }
            let gain = light_gain(frame);
            data.iter_mut().for_each(|v| *v *= gain);
            GrayImage::from_levels_on_this_thread(config.width, config.height, data)
        })
    }

    pub fn config(&self) -> &FaceSynthConfig {
        &self.config
    }

    /// Frame `frame` of the video (any order; frames past the last continue the motion).
    pub fn render(&self, frame: usize) -> Result<GrayImage, FaceError> {
        let config = &self.config;
        let (w, h) = (config.width, config.height);
        let mut data = self.background.clone();
        let mut depth = vec![f32::NEG_INFINITY; data.len()];
        for pose in self.head_poses(frame) {
            let (state, surface) = self.posed_head(&pose);
            // Splats (pixel, depth, value) of every surface sample in parallel, sorted into
            // bands of rows; then each band's depth test in parallel, its splats in sample order
            // (so that ties resolve as one pass over the samples would).
            let splats = splat_head(config, &surface, &state);
            let band_len = BAND_ROWS * w as usize;
            data.par_chunks_mut(band_len)
                .zip(depth.par_chunks_mut(band_len))
                .enumerate()
                .for_each(|(band, (data, depth))| {
                    for chunk in &splats {
                        for &(idx, z, value) in &chunk[band] {
                            let local = idx - band * band_len;
                            if z > depth[local] {
                                depth[local] = z;
                                data[local] = value;
                            }
                        }
                    }
                });
        }
        if config.occlusion && config.frames >= 3 {
            draw_occluder(config, frame, &mut data);
        }
        let gain = light_gain(frame);
        data.par_iter_mut().for_each(|v| *v *= gain);
        // Rounded to 8 bits, as a camera gives.
        GrayImage::from_levels(w, h, &data)
    }
}

/// In the middle third of the video, a bar a fifth of the face wide sweeping across the first
/// face.
fn draw_occluder(config: &FaceSynthConfig, frame: usize, data: &mut [f32]) {
    let third = config.frames / 3;
    if !(third..2 * third).contains(&frame) {
        return;
    }
    let w = config.width;
    let face = face_state(config, 0, frame);
    let (hw, hh) = (config.half_width, config.half_width * HEIGHT_RATIO);
    let progress = (frame - third) as f32 / third.max(1) as f32;
    let x0 = face[TX] - 2.0 * hw + 4.0 * hw * progress;
    // Only the bar's bounding columns and rows are visited; the test inside decides.
    let columns = (x0 - 0.2 * hw).floor().max(0.0) as u32
        ..((x0 + 0.2 * hw).ceil() + 1.0).clamp(0.0, w as f32) as u32;
    let rows = (face[TY] - 1.6 * hh).floor().max(0.0) as u32
        ..((face[TY] + 1.6 * hh).ceil() + 1.0).clamp(0.0, config.height as f32) as u32;
    for y in rows {
        for x in columns.clone() {
            let (fx, fy) = (x as f32, y as f32);
            if (fx - x0).abs() < 0.2 * hw && (fy - face[TY]).abs() < 1.6 * hh {
                data[(y * w + x) as usize] = 120.0 + 40.0 * value_noise(fx, fy, 6.0, 3);
            }
        }
    }
}

/// Renders frame `frame` alone: background, then every head by forward splatting its surface
/// with a depth buffer, then the occluder; all times the light gain. A video is rendered faster
/// by one [`FaceVideoRenderer`], which keeps what the frames share.
pub fn render_frame(
    config: &FaceSynthConfig,
    model: &FaceModel,
    frame: usize,
) -> Result<GrayImage, FaceError> {
    FaceVideoRenderer::new(config, model)?.render(frame)
}
