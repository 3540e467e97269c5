//! The synthetic sequences of the command line's `--synthetic` runs, as numpy arrays with their
//! ground truth: test data for the trackers, and examples for a first try.

use body_tracker::human::human_skeleton;
use body_tracker::synth::{Motion, SynthConfig, pose_at, render};
use face_tracker::DIMS;
use face_tracker::model::FaceModel;
use face_tracker::synth::{FaceSynthConfig, FaceVideoRenderer, face_state, initial_rect};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::arrays::to_numpy;
use crate::body::joints_array;
use crate::errors::{body, face, value_error, whole};

/// A synthetic video of textured heads that move, turn and change lighting: a dict with
/// `frames` (F, H, W) uint8, `truth` (F, K, 7) float32 (each face's state per frame, the
/// tracker's convention) and `rects` (K, 4) float32 (each face's rectangle in the first frame).
#[pyfunction]
#[pyo3(signature = (frames = 30, *, width = 640, height = 480, faces = 2, half_width = 50.0, max_yaw_deg = 50.0, occlusion = false, seed = 11, fov = None))]
#[allow(clippy::too_many_arguments)]
pub fn synthetic_faces(
    py: Python<'_>,
    frames: i128,
    width: i128,
    height: i128,
    faces: i128,
    half_width: f32,
    max_yaw_deg: f32,
    occlusion: bool,
    seed: i128,
    fov: Option<f32>,
) -> PyResult<Bound<'_, PyDict>> {
    let frames: usize = whole("frames", frames)?;
    let width: u32 = whole("width", width)?;
    let height: u32 = whole("height", height)?;
    let faces: usize = whole("faces", faces)?;
    let seed: u64 = whole("seed", seed)?;
    let config = FaceSynthConfig {
        focal_length: crate::camera::focal_length(fov, width)?,
        width,
        height,
        frames,
        faces,
        half_width,
        max_yaw: max_yaw_deg.to_radians(),
        occlusion,
        seed,
        ..FaceSynthConfig::paper(frames)
    };
    config.validate().map_err(face)?;
    let pixels = py
        .detach(|| -> Result<Vec<u8>, face_tracker::FaceError> {
            let model = FaceModel::generic(129)?;
            let renderer = FaceVideoRenderer::new(&config, &model)?;
            let mut pixels = Vec::new();
            let bytes = (width as usize)
                .checked_mul(height as usize)
                .and_then(|p| p.checked_mul(frames));
            bytes
                .and_then(|b| pixels.try_reserve_exact(b).ok())
                .ok_or_else(|| {
                    face_tracker::FaceError::InvalidInput(format!(
                        "{frames} frames of {width}x{height} do not fit in memory"
                    ))
                })?;
            // A frame per core at once (the frames are independent of each other).
            let batch = std::thread::available_parallelism().map_or(1, |n| n.get());
            for first in (0..frames).step_by(batch) {
                for image in renderer.render_frames(first..(first + batch).min(frames)) {
                    pixels.extend_from_slice(&image?.data);
                }
            }
            Ok(pixels)
        })
        .map_err(face)?;
    let truth: Vec<f32> = (0..frames)
        .flat_map(|f| (0..faces).map(move |k| (f, k)))
        .flat_map(|(f, k)| face_state(&config, k, f))
        .collect();
    let rects: Vec<f32> = (0..faces)
        .flat_map(|k| {
            let r = initial_rect(&config, k);
            [r.x, r.y, r.width, r.height]
        })
        .collect();
    let out = PyDict::new(py);
    out.set_item(
        "frames",
        to_numpy(py, pixels, &[frames, height as usize, width as usize])?,
    )?;
    out.set_item("truth", to_numpy(py, truth, &[frames, faces, DIMS])?)?;
    out.set_item("rects", to_numpy(py, rects, &[faces, 4])?)?;
    Ok(out)
}

/// A synthetic depth sequence of the default human (ray-cast, with depth noise, dropout and
/// outliers): a dict with `points` (a list of (N, 3) float32 arrays, camera frame), `depth`
/// (F, H, W) uint16 (millimetres), `truth` (F, P) float32 poses, `joints` (F, J, 3) float32,
/// `intrinsics` (a dict: fx, fy, cx, cy, depth_scale) and `pose_names`.
#[pyfunction]
#[pyo3(signature = (frames = 20, *, width = 160, height = 120, motion = "walk-wave", capsules = 19, seed = 7))]
pub fn synthetic_body<'py>(
    py: Python<'py>,
    frames: i128,
    width: i128,
    height: i128,
    motion: &str,
    capsules: i128,
    seed: i128,
) -> PyResult<Bound<'py, PyDict>> {
    let frames: usize = whole("frames", frames)?;
    let width: u32 = whole("width", width)?;
    let height: u32 = whole("height", height)?;
    let capsules: usize = whole("capsules", capsules)?;
    let seed: u64 = whole("seed", seed)?;
    if frames == 0 {
        return Err(value_error("frames must be at least 1"));
    }
    let motion: Motion = motion.parse().map_err(body)?;
    let skeleton = human_skeleton(capsules).map_err(body)?;
    let mut config = SynthConfig::small(frames).map_err(body)?;
    config.motion = motion;
    config.seed = seed;
    config.camera =
        body_tracker::camera::Intrinsics::with_fov(width, height, 60.0).map_err(body)?;
    config.validate().map_err(body)?;
    let rendered = py
        .detach(|| -> Result<Vec<_>, body_tracker::BodyError> {
            (0..frames)
                .map(|f| {
                    let truth = pose_at(&skeleton, &config, f)?;
                    let frame = render(&skeleton, &truth, &config, f)?;
                    Ok((truth, frame))
                })
                .collect()
        })
        .map_err(body)?;
    let dofs = skeleton.dofs();
    let points = rendered
        .iter()
        .map(|(_, frame)| points_array(py, &frame.points))
        .collect::<PyResult<Vec<_>>>()?;
    let depth: Vec<u16> = rendered
        .iter()
        .flat_map(|(_, f)| f.depth.depth.iter().copied())
        .collect();
    let truth: Vec<f32> = rendered
        .iter()
        .flat_map(|(t, _)| t.iter().copied())
        .collect();
    let joints = rendered
        .iter()
        .map(|(t, _)| joints_array(py, &skeleton, t))
        .collect::<PyResult<Vec<_>>>()?;
    let numpy = py.import("numpy")?;
    let out = PyDict::new(py);
    out.set_item("points", points)?;
    out.set_item(
        "depth",
        to_numpy(py, depth, &[frames, height as usize, width as usize])?,
    )?;
    out.set_item("truth", to_numpy(py, truth, &[frames, dofs])?)?;
    out.set_item("joints", numpy.call_method1("stack", (joints,))?)?;
    out.set_item("intrinsics", intrinsics_dict(py, &config.camera)?)?;
    out.set_item("pose_names", skeleton.pose_names())?;
    Ok(out)
}

/// A frame's points as an (N, 3) float32 array.
fn points_array<'py>(
    py: Python<'py>,
    points: &[nalgebra::Vector3<f32>],
) -> PyResult<Bound<'py, PyAny>> {
    let n = points.len();
    to_numpy(
        py,
        points.iter().flat_map(|p| [p.x, p.y, p.z]).collect(),
        &[n, 3],
    )
}

/// A camera's intrinsics as the dict Python reads (fx, fy, cx, cy, depth_scale).
fn intrinsics_dict<'py>(
    py: Python<'py>,
    camera: &body_tracker::camera::Intrinsics,
) -> PyResult<Bound<'py, PyDict>> {
    let intrinsics = PyDict::new(py);
    intrinsics.set_item("fx", camera.fx)?;
    intrinsics.set_item("fy", camera.fy)?;
    intrinsics.set_item("cx", camera.cx)?;
    intrinsics.set_item("cy", camera.cy)?;
    intrinsics.set_item("depth_scale", camera.depth_scale)?;
    Ok(intrinsics)
}
