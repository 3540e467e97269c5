//! `streampf.FaceTracker`: the face tracker on numpy frames, with or without the detector.

use crate::smoothing::{SmoothRequest, Smoothing, rows_dict};
use pf_core::smooth_tracks::SmoothedRow;
use std::sync::Mutex;

use face_tracker::detect::{Cascade, DetectConfig, DetectorPlacement, FaceDetector, GpuCascade};
use face_tracker::extraction::FaceRect;
use face_tracker::model::BuiltInModel;
use face_tracker::projection::{pitch_yaw_roll_degrees, rotation_quaternion};
use face_tracker::{
    AutoConfig, AutoTracker, DIMS, FaceBackend, FaceEstimate, FaceTrackerConfig, GrayImage,
    TrackStatus,
};
use numpy::PyUntypedArrayMethods;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::arrays::{ChannelOrder, contiguous, gray_frame, to_numpy};
use crate::backend::{Choice, face_backend, open};
use crate::errors::{face, runtime_error, value_error, whole, whole_opt};

/// The tracker behind the Python object: faces from the caller's rectangles only, or from the
/// detector as well.
enum Engine {
    Fixed(Box<face_tracker::FaceTracker>),
    Detecting(Box<AutoTracker>),
}

impl Engine {
    fn tracker(&self) -> &face_tracker::FaceTracker {
        match self {
            Engine::Fixed(t) => t,
            Engine::Detecting(a) => a.tracker(),
        }
    }
}

struct Inner {
    engine: Engine,
    /// Frames stepped.
    frames: usize,
    /// `smooth=True` or `smooth_lag=L`: every frame's clouds, for `smoothed()` (and the rows due
    /// at each step, with a lag).
    smoothing: Option<Smoothing>,
}

impl Inner {
    /// A tracker with no frame stepped, smoothing as `request` asks.
    fn new(engine: Engine, request: Option<SmoothRequest>) -> PyResult<Self> {
        let smoothing = match request {
            Some(request) => {
                let tracker = engine.tracker();
                Some(Smoothing::new(
                    tracker.transition(),
                    request,
                    tracker.motion_gain(),
                    tracker.gpu_context(),
                )?)
            }
            None => None,
        };
        Ok(Self {
            engine,
            frames: 0,
            smoothing,
        })
    }

    /// A step's estimates to the smoother, when smoothing; with a lag, the rows now due.
    fn smooth(&mut self, estimates: &[FaceEstimate]) -> PyResult<Option<Vec<SmoothedRow>>> {
        let Some(smoothing) = self.smoothing.as_mut() else {
            return Ok(None);
        };
        let clouds = self.engine.tracker().track_clouds(estimates);
        let rows = smoothing.add(clouds.map_err(face)?)?;
        Ok(smoothing.lagging().then_some(rows))
    }
}

/// What a step found, as the Python dict's arrays are built from it.
struct StepOut {
    estimates: Vec<FaceEstimate>,
    started: Vec<usize>,
    restarted: Vec<usize>,
    /// With `smooth_lag=L`: the rows smoothed at this step.
    smoothed: Option<Vec<SmoothedRow>>,
}

/// Tracks faces in frames given as numpy arrays (`uint8`, H×W gray or H×W×3 colour).
#[pyclass(module = "streampf._streampf")]
pub struct FaceTracker {
    /// Locked only with the GIL released (a thread waiting for it must not hold the GIL that
    /// the thread holding it needs to return).
    inner: Mutex<Inner>,
    /// The last frame's pixels, kept so that a frame's conversion does not allocate; locked
    /// only with the GIL held, never across a release.
    buffer: Mutex<Vec<u8>>,
    size: (u32, u32),
    order: ChannelOrder,
    device: String,
    /// Whether the detector runs (its thread needs frames of its own: no borrowed pixels).
    detecting: bool,
    /// Whether the built-in head is the photographed one (else the generic).
    photographed: bool,
}

fn config(
    particles: usize,
    seed: u64,
    layers: Option<usize>,
    enlarge_below: Option<&Bound<'_, PyAny>>,
) -> PyResult<FaceTrackerConfig> {
    let defaults = FaceTrackerConfig::default();
    let annealing = crate::settings::annealing(particles, layers, &defaults.annealing)?;
    let enlarge_below =
        crate::settings::enlarge_below(enlarge_below, defaults.extraction.enlarge_below)?;
    Ok(FaceTrackerConfig {
        particles,
        best: (particles / 10).max(1),
        seed,
        annealing,
        extraction: face_tracker::extraction::ExtractionConfig {
            enlarge_below,
            ..defaults.extraction
        },
        ..defaults
    })
}

/// The detector's cascade when `detect` is on (OpenCV's frontal cascade unless `cascade` names
/// one); a cascade without `detect` is an error.
fn load_cascade(detect: bool, cascade: Option<std::path::PathBuf>) -> PyResult<Option<Cascade>> {
    match (detect, cascade) {
        (false, None) => Ok(None),
        (false, Some(_)) => Err(value_error("cascade is given but detect is False")),
        (true, path) => {
            let path = path.unwrap_or_else(|| face_tracker::detect::DEFAULT_CASCADE.into());
            if !path.exists() {
                return Err(pyo3::exceptions::PyFileNotFoundError::new_err(format!(
                    "the face detector's cascade {} is missing: install Debian's \
                     opencv-data, pass cascade=PATH to an OpenCV Haar cascade XML, or \
                     track from rectangles (detect=False, add_face)",
                    path.display()
                )));
            }
            Ok(Some(Cascade::load(&path).map_err(face)?))
        }
    }
}

/// The detector on a GPU of its own (`on_gpu`) or on the CPU.
fn open_detector(
    py: Python<'_>,
    cascade: Cascade,
    on_gpu: bool,
    allow_software: bool,
) -> PyResult<FaceDetector> {
    if !on_gpu {
        return Ok(FaceDetector::Cpu(cascade));
    }
    let ctx = open(py, Choice::Gpu, allow_software)?
        .into_iter()
        .next()
        .ok_or_else(|| runtime_error("no GPU for the detector"))?;
    Ok(FaceDetector::from(
        py.detach(|| GpuCascade::new(ctx, cascade)).map_err(face)?,
    ))
}

/// What the filters run on, for `device`: "CPU" or the GPUs' names.
fn device_names(backend: &face_tracker::FaceBackend) -> String {
    match backend {
        face_tracker::FaceBackend::Cpu => "CPU".to_string(),
        face_tracker::FaceBackend::Gpu(ctx) => ctx.adapter().name.clone(),
        face_tracker::FaceBackend::Gpus(all) => all
            .iter()
            .map(|c| c.adapter().name.clone())
            .collect::<Vec<_>>()
            .join(", "),
    }
}

fn rect_from(rect: (f32, f32, f32, f32)) -> PyResult<FaceRect> {
    let (x, y, width, height) = rect;
    if ![x, y, width, height].iter().all(|v| v.is_finite()) || width <= 0.0 || height <= 0.0 {
        return Err(value_error(format!(
            "a face rectangle is (x, y, width, height) with finite values and a positive size, \
             got {rect:?}"
        )));
    }
    Ok(FaceRect {
        x,
        y,
        width,
        height,
    })
}

/// The frame size from the constructor's arguments: whole numbers, at least 16×16.
fn frame_size(width: i128, height: i128) -> PyResult<(u32, u32)> {
    let width: u32 = whole("width", width)?;
    let height: u32 = whole("height", height)?;
    if width < 16 || height < 16 {
        return Err(value_error(format!(
            "frames must be at least 16x16 pixels, got {width}x{height}"
        )));
    }
    Ok((width, height))
}

/// The detecting tracker's settings for frames from arrays: these play as a file does (the
/// detector's answer is used before the next is due), so a run is repeatable.
fn auto_config(
    detect_every: usize,
    min_face: u32,
    max_faces: usize,
    scene_cut: Option<f32>,
    tracker: &FaceTrackerConfig,
) -> AutoConfig {
    AutoConfig {
        detect_every,
        detect: DetectConfig {
            min_size: min_face,
            ..DetectConfig::default()
        },
        max_faces,
        detection_delay: Some(1),
        scene_cut,
        tracker: tracker.clone(),
        ..AutoConfig::default()
    }
}

/// `scene_cut`, checked with or without the detector (as the other arguments are).
fn checked_scene_cut(scene_cut: Option<f32>) -> PyResult<Option<f32>> {
    match scene_cut {
        Some(change) if !(change > 0.0 && change < 2.0) => Err(value_error(format!(
            "scene_cut must be within (0, 2) (a histogram change: 0 the same levels, 2 none in common), or None; got {change}"
        ))),
        checked => Ok(checked),
    }
}

/// The tracker behind a `FaceTracker`: faces given by the caller, or found by `detecting`'s
/// detector.
fn build_engine(
    size: (u32, u32),
    max_faces: usize,
    built_in: BuiltInModel,
    config: FaceTrackerConfig,
    backend: FaceBackend,
    detecting: Option<(FaceDetector, AutoConfig)>,
) -> Result<Engine, face_tracker::FaceError> {
    let model = built_in.build(false, 1.0)?;
    Ok(match detecting {
        None => Engine::Fixed(Box::new(face_tracker::FaceTracker::with_capacity(
            size, max_faces, &model, config, backend,
        )?)),
        Some((detector, auto)) => Engine::Detecting(Box::new(AutoTracker::new(
            size, detector, &model, auto, backend,
        )?)),
    })
}

/// `detector=` and `face_model=` parsed: where the detector runs and the built-in head.
fn placement_and_model(
    detector: &str,
    face_model: &str,
) -> PyResult<(DetectorPlacement, BuiltInModel)> {
    let placement =
        (detector.parse()).map_err(|e: face_tracker::FaceError| value_error(e.to_string()))?;
    let model = (face_model.parse())
        .map_err(|e: face_tracker::FaceError| value_error(format!("face_model: {e}")))?;
    Ok((placement, model))
}

#[pymethods]
impl FaceTracker {
    /// See the Python stub (`streampf/__init__.pyi`) for the arguments.
    #[new]
    #[pyo3(signature = (
        width, height, *, max_faces = 8, particles = 1000, detect = false, cascade = None,
        detect_every = 5, min_face = 40, backend = "auto", allow_software = false, seed = 1,
        layers = None, channel_order = "rgb", detector = "auto", fov = None, face_model = "auto",
        smooth = false, camera = None, scene_cut = Some(face_tracker::scene_cut::DEFAULT_SCENE_CUT),
        smooth_motion = None, enlarge_below = None, smooth_lag = None
    ))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        width: i128,
        height: i128,
        max_faces: i128,
        particles: i128,
        detect: bool,
        cascade: Option<std::path::PathBuf>,
        detect_every: i128,
        min_face: i128,
        backend: &str,
        allow_software: bool,
        seed: i128,
        layers: Option<i128>,
        channel_order: &str,
        detector: &str,
        fov: Option<f32>,
        face_model: &str,
        smooth: bool,
        camera: Option<&Bound<'_, PyAny>>,
        scene_cut: Option<f32>,
        smooth_motion: Option<&Bound<'_, PyAny>>,
        enlarge_below: Option<&Bound<'_, PyAny>>,
        smooth_lag: Option<i128>,
    ) -> PyResult<Self> {
        let (width, height) = frame_size(width, height)?;
        let smoothing = crate::smoothing::smooth_request(smooth, smooth_lag, smooth_motion)?;
        let max_faces: usize = whole("max_faces", max_faces)?;
        let particles: usize = whole("particles", particles)?;
        let detect_every: usize = whole("detect_every", detect_every)?;
        let min_face: u32 = whole("min_face", min_face)?;
        let scene_cut = checked_scene_cut(scene_cut)?;
        let seed: u64 = whole("seed", seed)?;
        let layers: Option<usize> = whole_opt("layers", layers)?;
        let order = ChannelOrder::parse(channel_order)?;
        let choice = Choice::parse(backend)?;
        let (detector_on, built_in) = placement_and_model(detector, face_model)?;
        // Frames from arrays are real frames (a synthetic video is asked for by name).
        let photographed = built_in.is_photographed(false);
        let config = config(particles, seed, layers, enlarge_below)?;
        let config = crate::camera::with_lens(config, fov, camera, (width, height))?;
        let cascade = load_cascade(detect, cascade)?;
        let contexts = open(py, choice, allow_software)?;
        let backend = face_backend(contexts, choice, max_faces, &config);
        let device = device_names(&backend);
        let detecting = match cascade {
            Some(cascade) => {
                let on_gpu = detector_on.runs_on_gpu(&backend);
                let detector = open_detector(py, cascade, on_gpu, allow_software)?;
                let auto = auto_config(detect_every, min_face, max_faces, scene_cut, &config);
                Some((detector, auto))
            }
            None => None,
        };
        let size = (width, height);
        let engine = py
            .detach(|| build_engine(size, max_faces, built_in, config, backend, detecting))
            .map_err(face)?;
        Ok(Self {
            inner: Mutex::new(Inner::new(engine, smoothing)?),
            buffer: Mutex::new(Vec::new()),
            size,
            order,
            device,
            detecting: detect,
            photographed,
        })
    }

    /// The built-in head the tracker uses: "photographed" or "generic".
    #[getter]
    fn face_model(&self) -> &'static str {
        if self.photographed {
            "photographed"
        } else {
            "generic"
        }
    }

    /// What the filters run on: "CPU" or the GPUs' names.
    #[getter]
    fn device(&self) -> &str {
        &self.device
    }

    /// Frames stepped so far.
    #[getter]
    fn frames(&self, py: Python<'_>) -> PyResult<usize> {
        py.detach(|| Ok(self.lock()?.frames))
    }

    /// Starts a track on the face in `rect` = (x, y, width, height) of `frame` (its template
    /// is extracted there); returns the track's number. Call it before `step` on that frame.
    fn add_face(
        &self,
        py: Python<'_>,
        frame: &Bound<'_, PyAny>,
        rect: (f32, f32, f32, f32),
    ) -> PyResult<usize> {
        let rect = rect_from(rect)?;
        let image = gray_frame(frame, self.size, self.order, Vec::new())?;
        py.detach(|| {
            let mut inner = self.lock()?;
            match &mut inner.engine {
                Engine::Fixed(t) => t.add_face(&image, &rect),
                Engine::Detecting(a) => a.add_face(&image, &rect),
            }
            .map_err(face)
        })
    }

    /// Tracks one frame; returns a dict of numpy arrays, one row per track reported (see the
    /// stub for the keys).
    fn step<'py>(
        &self,
        py: Python<'py>,
        frame: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let (width, height) = self.size;
        let array = contiguous::<u8>(frame, "frame", "uint8")?;
        if !self.detecting && array.shape() == [height as usize, width as usize] {
            // A gray frame goes to the tracker as it lies in numpy's memory: a GPU uploads it
            // with no copy on the host (the binding's cost per frame, bench/face_overhead.py).
            let pixels = array
                .as_slice()
                .map_err(|e| value_error(format!("frame: {e}")))?;
            let out = py.detach(|| {
                let mut inner = self.lock()?;
                let Engine::Fixed(tracker) = &mut inner.engine else {
                    return Err(runtime_error("the tracker's engine changed"));
                };
                let estimates = tracker.step_pixels(width, height, pixels).map_err(face)?;
                inner.frames += 1;
                let smoothed = inner.smooth(&estimates)?;
                Ok(StepOut {
                    estimates,
                    started: Vec::new(),
                    restarted: Vec::new(),
                    smoothed,
                })
            })?;
            return step_dict(py, out);
        }
        drop(array);
        let buffer = std::mem::take(&mut *self.buffer.lock().unwrap_or_else(|e| e.into_inner()));
        let image = gray_frame(frame, self.size, self.order, buffer)?;
        let (out, image) = py.detach(|| {
            let out = self.lock().and_then(|mut inner| {
                let mut out = step_engine(&mut inner.engine, &image).map_err(face)?;
                inner.frames += 1;
                out.smoothed = inner.smooth(&out.estimates)?;
                Ok(out)
            });
            (out, image)
        });
        *self.buffer.lock().unwrap_or_else(|e| e.into_inner()) = image.data;
        step_dict(py, out?)
    }

    /// Every tracked face-frame so far, smoothed by the frames after it (needs `smooth=True` or
    /// `smooth_lag=L`; with a lag, each frame by at most L after it):
    /// `frame`, `track`, and the state's smoothed `mean`, `lower`, `upper` (a 95 % interval).
    fn smoothed<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let rows = py.detach(|| match &self.lock()?.smoothing {
            Some(smoothing) => smoothing.rows(),
            None => Err(value_error(
                "smoothed() needs FaceTracker(..., smooth=True) or smooth_lag=L",
            )),
        })?;
        rows_dict(py, &rows, face_tracker::projection::DIMS)
    }

    /// The particles after the last step: `(states, log_weights)` with shapes
    /// (slots, particles, 7) and (slots, particles); a track's slot is the step's `slot`.
    fn particles<'py>(&self, py: Python<'py>) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
        let (shape, states, log_weights) = py.detach(|| {
            let inner = self.lock()?;
            inner.engine.tracker().particles().map_err(face)
        })?;
        let (t, m, d) = (shape.targets, shape.particles, shape.dims);
        // The batch layout is [(t·D + d)·M + m]: reorder to (t, m, d).
        let mut ordered = vec![0.0f32; states.len()];
        for target in 0..t {
            for dim in 0..d {
                for particle in 0..m {
                    ordered[(target * m + particle) * d + dim] =
                        states[(target * d + dim) * m + particle];
                }
            }
        }
        Ok((
            to_numpy(py, ordered, &[t, m, d])?,
            to_numpy(py, log_weights, &[t, m])?,
        ))
    }
}

impl FaceTracker {
    fn lock(&self) -> PyResult<std::sync::MutexGuard<'_, Inner>> {
        self.inner
            .lock()
            .map_err(|_| runtime_error("the tracker failed in another thread and cannot go on"))
    }
}

fn step_engine(engine: &mut Engine, image: &GrayImage) -> Result<StepOut, face_tracker::FaceError> {
    Ok(match engine {
        Engine::Fixed(t) => StepOut {
            estimates: t.step(image)?,
            started: Vec::new(),
            restarted: Vec::new(),
            smoothed: None,
        },
        Engine::Detecting(a) => {
            let frame = a.step(image)?;
            StepOut {
                estimates: frame.estimates,
                started: frame.started.iter().map(|s| s.0).collect(),
                restarted: frame.restarted.iter().map(|s| s.0).collect(),
                smoothed: None,
            }
        }
    })
}

fn step_dict(py: Python<'_>, out: StepOut) -> PyResult<Bound<'_, PyDict>> {
    let n = out.estimates.len();
    let e = &out.estimates;
    let flat =
        |f: &dyn Fn(&FaceEstimate) -> Vec<f32>| -> Vec<f32> { e.iter().flat_map(f).collect() };
    let d = PyDict::new(py);
    let whole = |f: &dyn Fn(&FaceEstimate) -> usize| -> Vec<i64> {
        e.iter().map(|e| f(e) as i64).collect()
    };
    d.set_item("track", to_numpy(py, whole(&|e| e.track), &[n])?)?;
    d.set_item("identity", to_numpy(py, whole(&|e| e.identity), &[n])?)?;
    d.set_item("slot", to_numpy(py, whole(&|e| e.slot), &[n])?)?;
    d.set_item(
        "state",
        to_numpy(py, flat(&|e| e.state.to_vec()), &[n, DIMS])?,
    )?;
    d.set_item(
        "spread",
        to_numpy(py, flat(&|e| e.spread.to_vec()), &[n, DIMS])?,
    )?;
    d.set_item(
        "pitch_yaw_roll_deg",
        to_numpy(
            py,
            flat(&|e| pitch_yaw_roll_degrees(&e.state).to_vec()),
            &[n, 3],
        )?,
    )?;
    d.set_item(
        "quaternion",
        to_numpy(
            py,
            flat(&|e| rotation_quaternion(&e.state).to_vec()),
            &[n, 4],
        )?,
    )?;
    d.set_item(
        "rect",
        to_numpy(
            py,
            flat(&|e| vec![e.rect.x, e.rect.y, e.rect.width, e.rect.height]),
            &[n, 4],
        )?,
    )?;
    d.set_item(
        "ess",
        to_numpy(py, e.iter().map(|e| e.ess).collect(), &[n])?,
    )?;
    d.set_item(
        "log_evidence",
        to_numpy(py, e.iter().map(|e| e.log_evidence).collect(), &[n])?,
    )?;
    d.set_item(
        "error",
        to_numpy(py, e.iter().map(|e| e.error).collect(), &[n])?,
    )?;
    d.set_item(
        "confidence",
        to_numpy(py, e.iter().map(|e| e.confidence).collect(), &[n])?,
    )?;
    d.set_item(
        "lost",
        to_numpy(
            py,
            e.iter()
                .map(|e| matches!(e.status, TrackStatus::Lost { .. }))
                .collect(),
            &[n],
        )?,
    )?;
    let ids = |v: Vec<usize>| v.into_iter().map(|t| t as i64).collect::<Vec<_>>();
    let (started, restarted) = (out.started.len(), out.restarted.len());
    d.set_item("started", to_numpy(py, ids(out.started), &[started])?)?;
    d.set_item("restarted", to_numpy(py, ids(out.restarted), &[restarted])?)?;
    if let Some(rows) = out.smoothed {
        d.set_item("smoothed", rows_dict(py, &rows, DIMS)?)?;
    }
    Ok(d)
}
