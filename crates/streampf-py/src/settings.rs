//! The trackers' settings shared by `FaceTracker` and `BodyTracker`.

use pf_core::anneal::Annealing;
use pyo3::prelude::*;

use crate::errors::value_error;

/// `particles` checked, and the annealing of `layers` per frame: the tracker's own schedule
/// (`default`) with that many layers, plain Condensation for one, the default for `None`.
pub fn annealing(
    particles: usize,
    layers: Option<usize>,
    default: &Annealing,
) -> PyResult<Annealing> {
    if particles == 0 {
        return Err(value_error("particles must be at least 1"));
    }
    Ok(match layers {
        None => default.clone(),
        Some(0) => return Err(value_error("layers must be at least 1")),
        Some(1) => Annealing::none(),
        Some(n) => Annealing {
            layers: n,
            ..default.clone()
        },
    })
}

/// `enlarge_below`: `None` for the tracker's default width (`ExtractionConfig::enlarge_below`),
/// 0 for none, else a finite width in pixels; a bool (a Python int that would read as 0 or 1
/// pixel) or a negative or non-finite width is refused.
pub fn enlarge_below(
    value: Option<&Bound<'_, PyAny>>,
    default: Option<f32>,
) -> PyResult<Option<f32>> {
    let Some(value) = value else {
        return Ok(default);
    };
    if value.is_instance_of::<pyo3::types::PyBool>() {
        return Err(pyo3::exceptions::PyTypeError::new_err(
            "enlarge_below is a width in pixels (0: no face enlarged), not a bool",
        ));
    }
    let width: f64 = value.extract().map_err(|_| {
        pyo3::exceptions::PyTypeError::new_err(format!(
            "enlarge_below is a width in pixels, got {value}"
        ))
    })?;
    // Checked as f32, the tracker's type: 1e300 is finite as f64 and infinite as f32.
    let narrow = width as f32;
    if !(narrow.is_finite() && narrow >= 0.0) {
        return Err(value_error(format!(
            "enlarge_below must be a finite width of 0 pixels or more (0: no face enlarged), got {width}"
        )));
    }
    Ok((narrow > 0.0).then_some(narrow))
}
