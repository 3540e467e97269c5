//! The one error type of face-tracker.

use thiserror::Error;

#[derive(Debug, Error)]
#[non_exhaustive]
pub enum FaceError {
    /// An image, template, face rectangle or parameter is out of its domain.
    #[error("invalid input: {0}")]
    InvalidInput(String),

    /// A file could not be read, decoded or written.
    #[error("{path}: {message}")]
    File { path: String, message: String },

    #[error(transparent)]
    Core(#[from] pf_core::PfError),

    #[error(transparent)]
    Gpu(#[from] pf_gpu::GpuError),
}

pub(crate) fn file_error(path: &std::path::Path, message: impl ToString) -> FaceError {
    FaceError::File {
        path: path.display().to_string(),
        message: message.to_string(),
    }
}
