//! Rust errors as Python exceptions, with the Rust messages: what the caller gave wrong is a
//! `ValueError`, a file that cannot be read an `OSError`, anything the GPU or the run itself
//! failed at a `RuntimeError`.

use body_tracker::BodyError;
use face_tracker::FaceError;
use pf_core::PfError;
use pf_gpu::GpuError;
use pyo3::PyErr;
use pyo3::exceptions::{PyOSError, PyRuntimeError, PyValueError};

pub fn value_error(message: impl Into<String>) -> PyErr {
    PyValueError::new_err(message.into())
}

/// A whole-number argument `name` in the type the library takes. The arguments are taken from
/// Python as any int (`i128`) and converted here, because PyO3's own conversion to an unsigned
/// type raises OverflowError ("can't convert negative int to unsigned") for `particles=-5`,
/// naming neither the argument nor what it takes; this raises the ValueError that every other
/// bad value gets.
pub fn whole<T: TryFrom<i128>>(name: &str, value: i128) -> pyo3::PyResult<T> {
    T::try_from(value).map_err(|_| match value < 0 {
        true => value_error(format!("{name} must be a whole number >= 0, got {value}")),
        false => value_error(format!("{name} is too large: {value}")),
    })
}

/// [`whole`] for an optional argument (None stays None).
pub fn whole_opt<T: TryFrom<i128>>(name: &str, value: Option<i128>) -> pyo3::PyResult<Option<T>> {
    value.map(|v| whole(name, v)).transpose()
}

pub fn runtime_error(message: impl Into<String>) -> PyErr {
    PyRuntimeError::new_err(message.into())
}

pub fn pf(e: PfError) -> PyErr {
    match e {
        PfError::InvalidConfig(_) | PfError::LengthMismatch { .. } => value_error(e.to_string()),
        other => runtime_error(other.to_string()),
    }
}

pub fn gpu(e: GpuError) -> PyErr {
    match e {
        GpuError::Shader { .. }
        | GpuError::InvalidConfig(_)
        | GpuError::LengthMismatch { .. }
        | GpuError::BufferTooLarge { .. } => value_error(e.to_string()),
        GpuError::Core(core) => pf(core),
        other => runtime_error(other.to_string()),
    }
}

pub fn face(e: FaceError) -> PyErr {
    match e {
        FaceError::InvalidInput(_) => value_error(e.to_string()),
        FaceError::File { .. } => PyOSError::new_err(e.to_string()),
        FaceError::Core(core) => pf(core),
        FaceError::Gpu(g) => gpu(g),
        other => runtime_error(other.to_string()),
    }
}

pub fn body(e: BodyError) -> PyErr {
    match e {
        BodyError::File { .. } | BodyError::SkeletonFile { .. } => {
            PyOSError::new_err(e.to_string())
        }
        BodyError::Core(core) => pf(core),
        BodyError::Gpu(g) => gpu(g),
        other => value_error(other.to_string()),
    }
}
