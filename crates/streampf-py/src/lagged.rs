//! `ParticleFilter(lag=L)`: each step also returns the step L back smoothed from the particles'
//! ancestry, a mean and 95 % interval per target and value. On the GPU the window stays there
//! (`pf_gpu::GpuFilter::keep_lag_window`) and only the summaries come back with the step; a
//! Python likelihood's filter runs on the CPU, where the twin (`pf_core::smooth::lag_window::
//! LagWindow`) traces the particles the host already has.

use pf_core::batch::BatchShape;
use pf_core::smooth::lag_window::{LagWindow, LaggedSummaries};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::arrays::to_numpy;
use crate::errors::{value_error, whole_opt};

/// `lag=`: 1 to `pf_gpu::MAX_LAG` steps, or none.
pub fn lag_arg(lag: Option<i128>) -> PyResult<Option<usize>> {
    let lag: Option<usize> = whole_opt("lag", lag)?;
    match lag {
        Some(l) if !(1..=pf_gpu::MAX_LAG).contains(&l) => Err(value_error(format!(
            "lag must be 1 to {} steps, got {l}",
            pf_gpu::MAX_LAG
        ))),
        _ => Ok(lag),
    }
}

/// The host's lag window for a filter on the CPU.
pub fn cpu_window(
    shape: BatchShape,
    lag: usize,
    angular: Vec<bool>,
) -> PyResult<std::sync::Mutex<LagWindow>> {
    let window = LagWindow::new(shape, lag, angular, false).map_err(crate::errors::pf)?;
    Ok(std::sync::Mutex::new(window))
}

/// A step's `lagged` entry: `None` before the window filled, else a dict of `lag`, `mean`,
/// `lower`, `upper` (T, D) and `kept` (T,), NaN for a target whose trace crosses a reset.
pub fn lagged_dict<'py>(
    py: Python<'py>,
    lagged: Option<&LaggedSummaries>,
    shape: &BatchShape,
) -> PyResult<Bound<'py, PyAny>> {
    let Some(lagged) = lagged else {
        return Ok(py.None().into_bound(py));
    };
    let (t, d) = (shape.targets, shape.dims);
    let mut columns = [
        vec![f32::NAN; t * d],
        vec![f32::NAN; t * d],
        vec![f32::NAN; t * d],
    ];
    let mut kept = vec![f32::NAN; t];
    for (target, summary) in lagged.targets.iter().enumerate().take(t) {
        let Some(summary) = summary else { continue };
        kept[target] = summary.kept;
        for (dim, s) in summary.smoothed.iter().enumerate().take(d) {
            let at = target * d + dim;
            (columns[0][at], columns[1][at], columns[2][at]) = (s.mean, s.lower, s.upper);
        }
    }
    let out = PyDict::new(py);
    out.set_item("lag", lagged.lag)?;
    for (name, values) in ["mean", "lower", "upper"].into_iter().zip(columns) {
        out.set_item(name, to_numpy(py, values, &[t, d])?)?;
    }
    out.set_item("kept", to_numpy(py, kept, &[t])?)?;
    Ok(out.into_any())
}
