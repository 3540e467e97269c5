//! `smooth=True` and `smooth_lag=L` on `FaceTracker` and `BodyTracker`: every frame's filtered
//! clouds go to the command line's smoother (`pf_core::smooth_tracks::TrackSmoother`, each track
//! whole, or L frames behind); `smoothed()` smooths what was tracked so far, the tracks still
//! running included, and returns it as numpy arrays; with a lag, each step returns the rows due.

use pf_core::smooth::GaussianTransition;
use pf_core::smooth::motion::{EvidenceMotion, SmoothMotion};
use pf_core::smooth_tracks::{LagSmoother, SmoothedRow, TrackCloud, TrackSmoother};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::sync::Arc;

use crate::arrays::to_numpy;
use crate::errors::runtime_error;

/// A tracker's smoothing: the smoother, the rows smoothed so far (of the tracks that ended, and
/// with a lag every row due), the frames seen.
pub struct Smoothing {
    smoother: TrackSmoother,
    /// Every row smoothed so far (kept for `smoothed()`: a row a value, track and frame).
    so_far: Vec<SmoothedRow>,
    frames: usize,
    lagging: bool,
}

/// The longest lag `smooth_lag=` takes (the command line's `--smooth-lag` range).
const MAX_LAG: usize = 1000;

/// What a tracker's smoothing arguments ask for: whole tracks (`lag` `None`, `smooth=True`) or a
/// lag of L frames (`smooth_lag=L`), under `motion`.
#[derive(Debug, Clone, Copy)]
pub struct SmoothRequest {
    lag: Option<usize>,
    motion: SmoothMotion,
}

/// `smooth=`, `smooth_lag=` and `smooth_motion=` read together: no smoothing (`None`), whole
/// tracks or a lag, each refused with a clear error where they do not fit (both `smooth=True`
/// and a lag; a lag outside 1 to 1 000; a motion with nothing to scale).
pub fn smooth_request(
    smooth: bool,
    smooth_lag: Option<i128>,
    motion: Option<&Bound<'_, PyAny>>,
) -> PyResult<Option<SmoothRequest>> {
    let lag: Option<usize> = crate::errors::whole_opt("smooth_lag", smooth_lag)?;
    if let Some(lag) = lag.filter(|l| !(1..=MAX_LAG).contains(l)) {
        return Err(pyo3::exceptions::PyValueError::new_err(format!(
            "smooth_lag is a number of frames from 1 to {MAX_LAG}, not {lag}"
        )));
    }
    if smooth && lag.is_some() {
        return Err(pyo3::exceptions::PyValueError::new_err(
            "smooth=True smooths whole tracks and smooth_lag=L smooths L frames behind: choose one",
        ));
    }
    let motion = smooth_motion(smooth || lag.is_some(), motion)?;
    Ok((smooth || lag.is_some()).then_some(SmoothRequest { lag, motion }))
}

/// `smooth_motion=`: a scale of the smoother's motion (`pf_core::smooth::MOTION_SCALES`) or
/// `"auto"` (each value's chosen by the evidence), only with a smoother (it would scale
/// nothing); `None` is the tracker's own motion.
fn smooth_motion(smooth: bool, motion: Option<&Bound<'_, PyAny>>) -> PyResult<SmoothMotion> {
    let Some(motion) = motion.filter(|m| !m.is_none()) else {
        return Ok(SmoothMotion::Scale(1.0));
    };
    if !smooth {
        return Err(pyo3::exceptions::PyValueError::new_err(
            "smooth_motion scales the smoother's motion: pass smooth=True or smooth_lag=L too",
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
    /// Smoothing as `request` asks, under the tracker's dynamics: on `gpu` (the tracker's GPU)
    /// when it has one (`pf_gpu::smooth::OnGpu`), else on the CPU's cores. The motion scales the
    /// transition's σ (1: the tracker's own diffusion) or is chosen per value by the evidence
    /// (`"auto"`: on the CPU's cores; with a lag, by the evidence of the track's frames so far).
    /// A lag smooths each window by the marginal smoother, as the command line's `--smooth-lag`
    /// does for an annealed tracker (the trackers here do not keep the particles' lineage).
    pub fn new(
        transition: GaussianTransition,
        request: SmoothRequest,
        gain: f32,
        gpu: Option<&pf_gpu::GpuContext>,
    ) -> PyResult<Self> {
        let transition = (request.motion.apply(transition))
            .map_err(|e| pyo3::exceptions::PyValueError::new_err(e.to_string()))?;
        let mut smoother = TrackSmoother::new(request.lag, transition, gain);
        if request.lag.is_some() {
            smoother = smoother.lagging_by(LagSmoother::Marginal);
        }
        if request.motion == SmoothMotion::ByEvidence {
            smoother = smoother.choosing_motion_by_evidence(Arc::new(EvidenceMotion::default()));
        } else if let Some(ctx) = gpu {
            let on_gpu = pf_gpu::smooth::OnGpu::new(ctx)
                .map_err(|e| runtime_error(format!("building the GPU smoother: {e}")))?;
            smoother = smoother.on(Arc::new(on_gpu));
        }
        Ok(Self {
            smoother,
            so_far: Vec::new(),
            frames: 0,
            lagging: request.lag.is_some(),
        })
    }

    /// Whether rows come out as frames arrive (`smooth_lag=L`), each frame L frames behind.
    pub fn lagging(&self) -> bool {
        self.lagging
    }

    /// The next frame's clouds, one for each target tracked in it; returns the rows smoothed
    /// now (with a lag: each track's frame L back, and the last frames of a track that ended),
    /// in frame and track order.
    pub fn add(&mut self, clouds: Vec<TrackCloud>) -> PyResult<Vec<SmoothedRow>> {
        let mut rows = (self.smoother.add_frame(self.frames, clouds))
            .map_err(|e| runtime_error(format!("smoothing: {e:#}")))?;
        rows.sort_by_key(|r| (r.frame, r.track));
        self.so_far.extend(rows.iter().cloned());
        self.frames += 1;
        Ok(rows)
    }

    /// Every frame tracked so far, smoothed (a running track over the frames it has), in frame
    /// and track order.
    pub fn rows(&self) -> PyResult<Vec<SmoothedRow>> {
        let running = (self.smoother.clone().finish())
            .map_err(|e| runtime_error(format!("smoothing: {e:#}")))?;
        let mut rows: Vec<SmoothedRow> = self.so_far.iter().cloned().chain(running).collect();
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
