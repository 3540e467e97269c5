//! The one error type of body-tracker.

use thiserror::Error;

#[derive(Debug, Error)]
#[non_exhaustive]
pub enum BodyError {
    /// A skeleton description is inconsistent (unknown parent, cycle, bad axis, bad limits...).
    #[error("invalid skeleton: {0}")]
    InvalidSkeleton(String),

    /// A skeleton file could not be read or parsed.
    #[error("reading skeleton {path}: {message}")]
    SkeletonFile { path: String, message: String },

    /// A pose vector has the wrong length or a non-finite value.
    #[error("invalid pose: {0}")]
    InvalidPose(String),

    /// A joint name that the skeleton does not have.
    #[error("unknown joint {name:?}; the skeleton has: {known}")]
    UnknownJoint { name: String, known: String },

    /// A likelihood parameter or an input point is out of its domain.
    #[error("invalid input: {0}")]
    InvalidInput(String),

    #[error(transparent)]
    Core(#[from] pf_core::PfError),

    #[error(transparent)]
    Gpu(#[from] pf_gpu::GpuError),

    /// A frame, sequence or output file could not be read or written.
    #[error("{path}: {message}")]
    File { path: String, message: String },
}
