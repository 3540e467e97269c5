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
