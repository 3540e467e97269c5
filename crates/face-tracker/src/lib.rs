//! # face-tracker
//!
//! The sparse-template 3D face tracker of Lozano & Otsuka ("Real-time visual tracker by stream
//! processing"), rebuilt on `pf-core` and `pf-gpu`:
//!
//! - [`projection`]: the 7-D state (Tx, Ty, S, Rx, Ry, Rz, α) and the weak-perspective projection
//!   with self-occlusion by rotated normals;
//! - [`template`]: feature points (P, N, J);
//! - [`likelihood`]: the robust relative residual ε and π ∝ 1/ε on the CPU (one thread: the
//!   Fig. 6 baseline; and rayon); the GPU kernels are in `pf_gpu::faces`;
//! - [`image`]: gray frames with bilinear sampling.

pub mod error;
pub mod image;
pub mod likelihood;
pub mod projection;
pub mod template;

pub use error::FaceError;
pub use image::GrayImage;
pub use projection::{DIMS, Pose, rotation};
pub use template::{FeaturePoint, Template};
