//! `smooth=True` on `FaceTracker` and `BodyTracker`: every frame's filtered clouds go to the
//! command line's smoother (`pf_core::smooth_tracks::TrackSmoother`, each track whole); `smoothed()`
//! smooths what was tracked so far, the tracks still running included, and returns it as numpy
//! arrays.

use pf_core::smooth::GaussianTransition;
use pf_core::smooth::motion::{EvidenceMotion, SmoothMotion};
use pf_core::smooth_tracks::{SmoothedRow, TrackCloud, TrackSmoother};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::arrays::to_numpy;
use crate::errors::runtime_error;

/// A tracker's smoothing: the smoother, the rows of the tracks that ended, the frames seen.
pub struct Smoothing {
    smoother: TrackSmoother,
    ended: Vec<SmoothedRow>,
    frames: usize,
}

/// `smooth_motion=`: a scale of the smoother's motion (`pf_core::smooth::MOTION_SCALES`) or
/// `"auto"` (each value's chosen by the evidence), only with `smooth=True` (it would scale
/// nothing); `None` is the tracker's own motion.
pub fn smooth_motion(smooth: bool, motion: Option<&Bound<'_, PyAny>>) -> PyResult<SmoothMotion> {
    let Some(motion) = motion.filter(|m| !m.is_none()) else {
        return Ok(SmoothMotion::Scale(1.0));
    };
    if !smooth {
        return Err(pyo3::exceptions::PyValueError::new_err(
            "smooth_motion scales the smoother's motion: pass smooth=True too",
        ));
    }
    motion_argument("smooth_motion", motion)
}

/// A motion argument named `name` (a number or `"auto"`): `SmoothMotion`, or an error naming it.
pub fn motion_argument(name: &str, motion: &Bound<'_, PyAny>) -> PyResult<SmoothMotion> {
    // A bool is a Python int, so it would read as 0 or 1: refused as the mistake it likely is.
    let text = if motion.is_instance_of::<pyo3::types::PyBool>() {
        return Err(pyo3::exceptions::PyTypeError::new_err(format!(
            "{name} is a number or \"auto\", not a bool"
        )));
    } else if let Ok(text) = motion.extract::<String>() {
        text
    } else if let Ok(scale) = motion.extract::<f64>() {
        // Out of f32's range becomes ±inf or 0, and NaN stays NaN: all outside the range.
        (scale as f32).to_string()
    } else {
        return Err(pyo3::exceptions::PyTypeError::new_err(format!(
            "{name} is a number or \"auto\""
        )));
    };
    SmoothMotion::parse(&text)
        .map_err(|e| pyo3::exceptions::PyValueError::new_err(format!("{name}: {e}")))
}

impl Smoothing {
    /// Whole-track smoothing under the tracker's dynamics, on `gpu` (the tracker's GPU) when it
    /// has one (`pf_gpu::smooth::OnGpu`), else on the CPU's cores.
    /// `motion` scales the transition's σ (`smooth_motion=`; 1: the tracker's own diffusion) or
    /// lets the evidence choose it per value (`"auto"`: on the CPU's cores).
    pub fn new(
        transition: GaussianTransition,
        motion: SmoothMotion,
        gain: f32,
        gpu: Option<&pf_gpu::GpuContext>,
    ) -> PyResult<Self> {
        let transition = motion
            .apply(transition)
            .map_err(|e| pyo3::exceptions::PyValueError::new_err(e.to_string()))?;
        let mut smoother = TrackSmoother::new(None, transition, gain);
        if motion == SmoothMotion::ByEvidence {
            smoother = smoother.on(std::sync::Arc::new(EvidenceMotion::default()));
        } else if let Some(ctx) = gpu {
            let on_gpu = pf_gpu::smooth::OnGpu::new(ctx)
                .map_err(|e| runtime_error(format!("building the GPU smoother: {e}")))?;
            smoother = smoother.on(std::sync::Arc::new(on_gpu));
        }
        Ok(Self {
            smoother,
            ended: Vec::new(),
            frames: 0,
        })
    }

    /// The next frame's clouds, one for each target tracked in it.
    pub fn add(&mut self, clouds: Vec<TrackCloud>) -> PyResult<()> {
        let rows = (self.smoother.add_frame(self.frames, clouds))
            .map_err(|e| runtime_error(format!("smoothing: {e:#}")))?;
        self.ended.extend(rows);
        self.frames += 1;
        Ok(())
    }

    /// Every frame tracked so far, smoothed (a running track over the frames it has), in frame
    /// and track order.
    pub fn rows(&self) -> PyResult<Vec<SmoothedRow>> {
        let running = (self.smoother.clone().finish())
            .map_err(|e| runtime_error(format!("smoothing: {e:#}")))?;
        let mut rows: Vec<SmoothedRow> = self.ended.iter().cloned().chain(running).collect();
        rows.sort_by_key(|r| (r.frame, r.track));
        Ok(rows)
    }
}

/// The rows as a dict: `frame` and `track` (n,) int64, `mean`, `lower`, `upper` (n, D) float32.
pub fn rows_dict<'py>(
    py: Python<'py>,
    rows: &[SmoothedRow],
    dims: usize,
) -> PyResult<Bound<'py, PyDict>> {
    let n = rows.len();
    let out = PyDict::new(py);
    let ints = |f: fn(&SmoothedRow) -> usize| rows.iter().map(|r| f(r) as i64).collect::<Vec<_>>();
    out.set_item("frame", to_numpy(py, ints(|r| r.frame), &[n])?)?;
    out.set_item("track", to_numpy(py, ints(|r| r.track), &[n])?)?;
    let column = |pick: fn(&pf_core::smooth::Summary) -> f32| -> Vec<f32> {
        rows.iter()
            .flat_map(|r| r.values.iter().map(pick))
            .collect()
    };
    out.set_item("mean", to_numpy(py, column(|s| s.mean), &[n, dims])?)?;
    out.set_item("lower", to_numpy(py, column(|s| s.lower), &[n, dims])?)?;
    out.set_item("upper", to_numpy(py, column(|s| s.upper), &[n, dims])?)?;
    Ok(out)
}

/// `ParticleFilter.smoothed()`'s work for one target: every kept step (its states in the batch
/// layout and normalised log-weights) smoothed, at the transition's motion or, `by_evidence`,
/// at each value's motion chosen by the evidence (with those scales; none otherwise).
pub fn smooth_steps(
    kept: &[(Vec<f32>, Vec<f32>)],
    (shape, target): (pf_core::batch::BatchShape, usize),
    transition: &GaussianTransition,
    by_evidence: bool,
) -> Result<(Vec<Vec<pf_core::smooth::Summary>>, Vec<f32>), pf_core::PfError> {
    let d = shape.dims;
    let clouds = (kept.iter())
        .map(|(states, lw)| {
            pf_core::smooth::Cloud::of_target(d, shape.particles, target, states, lw, vec![0.0; d])
        })
        .collect::<Result<Vec<_>, _>>()?;
    if !by_evidence {
        return Ok((
            pf_core::smooth::smooth_values(&clouds, transition)?,
            Vec::new(),
        ));
    }
    let (rows, choices) = pf_core::smooth::motion::smooth_values_by_evidence(&clouds, transition)?;
    // No step yet: nothing chosen, the filter's own motion.
    let scales = match choices.is_empty() {
        true => vec![1.0; d],
        false => choices.iter().map(|c| c.scale).collect(),
    };
    Ok((rows, scales))
}
