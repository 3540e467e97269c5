//! streampf for Python (`import streampf`): the face and body trackers and a generic particle
//! filter, numpy arrays in and out. The Python package (`python/streampf`) re-exports these
//! classes and adds `track_video`'s result loading, the docstrings' stubs and `track_corpus`'s
//! helpers.
//!
//! Conventions every class keeps: arrays are checked before any work (dtype, shape, C order,
//! finite values), a bad one is a `ValueError` naming the argument; GPU failures are
//! `RuntimeError`s carrying the Rust error's message; every call that tracks releases the GIL,
//! so trackers in different Python threads run at once.

mod arrays;
mod backend;
mod bench;
mod body;
mod camera;
mod errors;
mod face;
mod filter;
mod lagged;
mod mot;
mod settings;
mod smoothing;
mod synthetic;
mod video;

use pyo3::prelude::*;

#[pymodule]
fn _streampf(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(backend::devices, m)?)?;
    m.add_class::<face::FaceTracker>()?;
    m.add_class::<body::BodyTracker>()?;
    m.add_class::<filter::ParticleFilter>()?;
    m.add_function(wrap_pyfunction!(synthetic::synthetic_faces, m)?)?;
    m.add_function(wrap_pyfunction!(synthetic::synthetic_body, m)?)?;
    m.add_function(wrap_pyfunction!(video::run_command, m)?)?;
    m.add_function(wrap_pyfunction!(mot::mot_scores, m)?)?;
    m.add_function(wrap_pyfunction!(bench::_rust_face_step_times, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
