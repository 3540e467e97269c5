//! `streampf.BodyTracker`: the articulated body tracker on numpy point clouds or depth images.

use crate::smoothing::{Smoothing, rows_dict};
use std::sync::Mutex;

use body_tracker::camera::{DepthImage, Intrinsics};
use body_tracker::human::{human_skeleton, standing_pose};
use body_tracker::likelihood::CoarseLayers;
use body_tracker::tracker::{DEFAULT_COARSE_LAYERS, DEFAULT_COARSE_POINTS};
use body_tracker::{FrameResult, Skeleton, TrackerConfig};
use nalgebra::Vector3;
use numpy::PyUntypedArrayMethods;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::arrays::{check_shape, contiguous, finite_f32, to_numpy};
use crate::backend::{Choice, body_backend, open};
use crate::errors::{body, runtime_error, value_error, whole, whole_opt};

/// Tracks one body in depth frames: N×3 `float32` points (camera frame: x right, y up, z
/// forward, metres) or 16-bit depth images with their intrinsics.
#[pyclass(module = "streampf._streampf")]
pub struct BodyTracker {
    /// Locked only with the GIL released.
    tracker: Mutex<body_tracker::BodyTracker>,
    /// `smooth=True` or `smooth_lag=L`: every frame's samples, for `smoothed()` (locked with the GIL released,
    /// after `tracker` when both are).
    smoothing: Mutex<Option<Smoothing>>,
    skeleton: Skeleton,
    device: String,
}

/// The default human, or a skeleton JSON file.
fn load_skeleton(capsules: usize, skeleton: Option<std::path::PathBuf>) -> PyResult<Skeleton> {
    match skeleton {
        Some(path) => Skeleton::load(&path).map_err(body),
        None => human_skeleton(capsules).map_err(body),
    }
}

fn config(
    particles: usize,
    seed: u64,
    layers: Option<usize>,
    (partitioned, coarse): (bool, Option<CoarseLayers>),
) -> PyResult<TrackerConfig> {
    let defaults = TrackerConfig::default();
    let annealing = crate::settings::annealing(particles, layers, &defaults.annealing)?;
    if let Some(coarse) = &coarse {
        coarse.validate().map_err(body)?;
    }
    Ok(TrackerConfig {
        particles,
        seed,
        annealing,
        partitioned,
        coarse,
        ..defaults
    })
}

#[pymethods]
impl BodyTracker {
    #[new]
    #[pyo3(signature = (
        initial_pose = None, *, capsules = 19, skeleton = None, particles = 1500,
        backend = "auto", allow_software = false, seed = 1, layers = None, partitioned = true,
        coarse_points = DEFAULT_COARSE_POINTS as i128, coarse_layers = DEFAULT_COARSE_LAYERS as i128,
        smooth = false, smooth_motion = None, smooth_lag = None
    ))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        initial_pose: Option<&Bound<'_, PyAny>>,
        capsules: i128,
        skeleton: Option<std::path::PathBuf>,
        particles: i128,
        backend: &str,
        allow_software: bool,
        seed: i128,
        layers: Option<i128>,
        partitioned: bool,
        coarse_points: i128,
        coarse_layers: i128,
        smooth: bool,
        smooth_motion: Option<&Bound<'_, PyAny>>,
        smooth_lag: Option<i128>,
    ) -> PyResult<Self> {
        let request = crate::smoothing::smooth_request(smooth, smooth_lag, smooth_motion)?;
        let coarse = match whole::<usize>("coarse_layers", coarse_layers)? {
            0 => None,
            layers => Some(CoarseLayers {
                points: whole("coarse_points", coarse_points)?,
                layers,
            }),
        };
        let capsules: usize = whole("capsules", capsules)?;
        let particles: usize = whole("particles", particles)?;
        let seed: u64 = whole("seed", seed)?;
        let layers: Option<usize> = whole_opt("layers", layers)?;
        let choice = Choice::parse(backend)?;
        let skeleton = load_skeleton(capsules, skeleton)?;
        let start = match initial_pose {
            Some(pose) => finite_f32(pose, &[Some(skeleton.dofs())], "initial_pose")?.1,
            None => standing_pose(&skeleton, 3.0),
        };
        let config = config(particles, seed, layers, (partitioned, coarse))?;
        let contexts = open(py, choice, allow_software)?;
        let backend = body_backend(contexts, choice);
        let device = match &backend {
            body_tracker::Backend::Cpu => "CPU".to_string(),
            other => other.describe(),
        };
        let for_tracker = skeleton.clone();
        let tracker = py
            .detach(|| body_tracker::BodyTracker::new(for_tracker, &start, config, backend))
            .map_err(body)?;
        let smoothing = match request {
            Some(request) => Some(Smoothing::new(
                tracker.transition().map_err(body)?,
                request,
                tracker.motion_gain(),
                tracker.gpu_context(),
            )?),
            None => None,
        };
        Ok(Self {
            smoothing: Mutex::new(smoothing),
            tracker: Mutex::new(tracker),
            skeleton,
            device,
        })
    }

    /// What the filter runs on.
    #[getter]
    fn device(&self) -> &str {
        &self.device
    }

    /// The names of the pose values, in the order of `pose` and `spread`.
    #[getter]
    fn pose_names(&self) -> Vec<String> {
        self.skeleton.pose_names()
    }

    /// The names of the tracked joints (the root and every bone with an angle), in the order of
    /// `joints`.
    #[getter]
    fn joint_names(&self) -> Vec<String> {
        let bones = self.skeleton.bones();
        self.skeleton
            .joint_bones()
            .into_iter()
            .map(|i| bones[i].name.clone())
            .collect()
    }

    /// The tracked joints' positions (J×3, metres) for a pose.
    fn joints<'py>(
        &self,
        py: Python<'py>,
        pose: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let (_, pose) = finite_f32(pose, &[Some(self.skeleton.dofs())], "pose")?;
        joints_array(py, &self.skeleton, &pose)
    }

    /// Tracks one frame of points (N×3 float32, camera frame); returns a dict (see the stub).
    fn step<'py>(
        &self,
        py: Python<'py>,
        points: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let (_, values) = finite_f32(points, &[None, Some(3)], "points")?;
        let points: Vec<Vector3<f32>> = values
            .chunks_exact(3)
            .map(|p| Vector3::new(p[0], p[1], p[2]))
            .collect();
        self.track(py, points)
    }

    /// Tracks one 16-bit depth image (H×W uint16, z in units of `depth_scale` metres, 0 = no
    /// measurement) seen by a pinhole camera (fx, fy, cx, cy in pixels; y down in the image).
    #[pyo3(signature = (depth, fx, fy, cx, cy, depth_scale = 0.001))]
    #[allow(clippy::too_many_arguments)]
    fn step_depth<'py>(
        &self,
        py: Python<'py>,
        depth: &Bound<'py, PyAny>,
        fx: f32,
        fy: f32,
        cx: f32,
        cy: f32,
        depth_scale: f32,
    ) -> PyResult<Bound<'py, PyDict>> {
        let array = contiguous::<u16>(depth, "depth", "uint16")?;
        let shape = array.shape().to_vec();
        check_shape(&shape, &[None, None], "depth")?;
        let (height, width) = (shape[0] as u32, shape[1] as u32);
        let intrinsics = Intrinsics {
            width,
            height,
            fx,
            fy,
            cx,
            cy,
            depth_scale,
        };
        intrinsics.validate().map_err(body)?;
        let image = DepthImage {
            width,
            height,
            depth: array
                .as_slice()
                .map_err(|e| value_error(format!("depth: {e}")))?
                .to_vec(),
        };
        let points = image.to_points(&intrinsics).map_err(body)?;
        self.track(py, points)
    }

    /// Every frame so far, smoothed by the frames after it (needs `smooth=True`, or `smooth_lag=L`:
    /// then each frame by at most L after it): `frame`, and
    /// the pose's smoothed `mean`, `lower`, `upper` (a 95 % interval), each (frames, P).
    fn smoothed<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let rows = py.detach(|| match &*self.smoothing.lock().map_err(|_| poisoned())? {
            Some(smoothing) => smoothing.rows(),
            None => Err(value_error(
                "smoothed() needs BodyTracker(..., smooth=True) or smooth_lag=L",
            )),
        })?;
        let out = rows_dict(py, &rows, self.skeleton.dofs())?;
        out.del_item("track")?;
        Ok(out)
    }

    /// The particles after the last step: `(poses, log_weights)`, shapes (J, P) and (J,).
    fn particles<'py>(&self, py: Python<'py>) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
        let (shape, states, log_weights) = py.detach(|| {
            let tracker = self.lock()?;
            tracker.particles().map_err(body)
        })?;
        let (m, d) = (shape.particles, shape.dims);
        let mut ordered = vec![0.0f32; states.len()];
        for dim in 0..d {
            for particle in 0..m {
                ordered[particle * d + dim] = states[dim * m + particle];
            }
        }
        Ok((
            to_numpy(py, ordered, &[m, d])?,
            to_numpy(py, log_weights, &[m])?,
        ))
    }
}

fn poisoned() -> PyErr {
    runtime_error("the tracker failed in another thread and cannot go on")
}

impl BodyTracker {
    fn lock(&self) -> PyResult<std::sync::MutexGuard<'_, body_tracker::BodyTracker>> {
        self.tracker
            .lock()
            .map_err(|_| runtime_error("the tracker failed in another thread and cannot go on"))
    }

    fn track<'py>(
        &self,
        py: Python<'py>,
        points: Vec<Vector3<f32>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        if points.is_empty() {
            return Err(value_error("a frame needs at least one point"));
        }
        let (result, smoothed) = py.detach(|| {
            let mut tracker = self.lock()?;
            let result: FrameResult = tracker.step(&points).map_err(body)?;
            let mut smoothing = self.smoothing.lock().map_err(|_| poisoned())?;
            let mut smoothed = None;
            if let Some(smoothing) = smoothing.as_mut() {
                let (_, states, log_weights) = tracker.particles().map_err(body)?;
                let rows = smoothing.add(vec![(0, states, log_weights).into()])?;
                smoothed = smoothing.lagging().then_some(rows);
            }
            Ok::<_, PyErr>((result, smoothed))
        })?;
        let d = PyDict::new(py);
        let dofs = result.pose.len();
        d.set_item("joints", joints_array(py, &self.skeleton, &result.pose)?)?;
        d.set_item("pose", to_numpy(py, result.pose, &[dofs])?)?;
        d.set_item("spread", to_numpy(py, result.spread, &[dofs])?)?;
        d.set_item("ess", result.ess)?;
        d.set_item("log_evidence", result.log_evidence)?;
        d.set_item("confidence", result.confidence)?;
        d.set_item("points", result.points)?;
        if let Some(rows) = smoothed {
            let rows = rows_dict(py, &rows, dofs)?;
            rows.del_item("track")?;
            d.set_item("smoothed", rows)?;
        }
        Ok(d)
    }
}

pub fn joints_array<'py>(
    py: Python<'py>,
    skeleton: &Skeleton,
    pose: &[f32],
) -> PyResult<Bound<'py, PyAny>> {
    let joints = skeleton.tracked_joint_positions(pose).map_err(body)?;
    let n = joints.len();
    to_numpy(
        py,
        joints.iter().flat_map(|j| [j.x, j.y, j.z]).collect(),
        &[n, 3],
    )
}
