//! The yardstick of the binding's overhead (`bench/face_overhead.py`): the same face tracking
//! driven from Rust alone, timed per frame inside Rust.

use std::time::Instant;

use face_tracker::model::FaceModel;
use face_tracker::{FaceTracker, FaceTrackerConfig, GrayImage};
use numpy::PyUntypedArrayMethods;
use pyo3::prelude::*;

use crate::arrays::{contiguous, to_numpy};
use crate::backend::{Choice, face_backend, open};
use crate::errors::{face, value_error, whole};

/// Tracks `frames` (F, H, W) uint8 from `rects` with the Rust API alone, as `FaceTracker` with
/// the same settings would, and returns each `step`'s wall time in seconds (F,). The frames are
/// made `GrayImage`s before the clock starts.
#[pyfunction]
#[pyo3(signature = (frames, rects, *, particles = 1000, backend = "auto", allow_software = false, seed = 1))]
pub fn _rust_face_step_times<'py>(
    py: Python<'py>,
    frames: &Bound<'py, PyAny>,
    rects: Vec<(f32, f32, f32, f32)>,
    particles: i128,
    backend: &str,
    allow_software: bool,
    seed: i128,
) -> PyResult<Bound<'py, PyAny>> {
    let particles: usize = whole("particles", particles)?;
    let seed: u64 = whole("seed", seed)?;
    let array = contiguous::<u8>(frames, "frames", "uint8")?;
    let shape = array.shape().to_vec();
    let [count, height, width] = shape[..] else {
        return Err(value_error(format!(
            "frames must be (F, H, W), got {shape:?}"
        )));
    };
    if count == 0 || width == 0 || height == 0 {
        return Err(value_error(format!(
            "frames must hold at least one non-empty frame, got {shape:?}"
        )));
    }
    let pixels = array
        .as_slice()
        .map_err(|e| value_error(format!("frames: {e}")))?;
    let images = pixels
        .chunks_exact(width * height)
        .map(|p| GrayImage::new(width as u32, height as u32, p.to_vec()))
        .collect::<Result<Vec<_>, _>>()
        .map_err(face)?;
    let choice = Choice::parse(backend)?;
    let contexts = open(py, choice, allow_software)?;
    let config = FaceTrackerConfig {
        particles,
        best: (particles / 10).max(1),
        seed,
        ..FaceTrackerConfig::default()
    };
    let backend = face_backend(contexts, choice, rects.len().max(1), &config);
    let times = py
        .detach(|| -> Result<Vec<f64>, face_tracker::FaceError> {
            let model = FaceModel::generic(129)?;
            let mut tracker = FaceTracker::with_capacity(
                (width as u32, height as u32),
                rects.len().max(1),
                &model,
                config,
                backend,
            )?;
            for (x, y, w, h) in &rects {
                let rect = face_tracker::extraction::FaceRect {
                    x: *x,
                    y: *y,
                    width: *w,
                    height: *h,
                };
                tracker.add_face(&images[0], &rect)?;
            }
            images
                .iter()
                .map(|image| {
                    let start = Instant::now();
                    tracker.step(image)?;
                    Ok(start.elapsed().as_secs_f64())
                })
                .collect()
        })
        .map_err(face)?;
    to_numpy(py, times, &[count])
}
