//! # face-tracker
//!
//! The sparse-template 3D face tracker of Lozano & Otsuka ("Real-time visual tracker by stream
//! processing"), rebuilt on `pf-core` and `pf-gpu`:
//!
//! - [`projection`]: the 7-D state (Tx, Ty, S, Rx, Ry, Rz, α) and the weak-perspective projection
//!   with self-occlusion by rotated normals;
//! - [`template`]: feature points (P, N, J); [`extraction`]: the sparse template from the face
//!   sub-image at t0 (gray-level extrema and LoG boundary dipoles), a small face's taken in its
//!   region [`enlarge`]d; [`model`]: the face model (heightmap + normalmap) that gives each
//!   point its depth and normal;
//! - [`likelihood`]: the robust relative residual ε and π ∝ 1/ε on the CPU (one thread: the
//!   Fig. 6 baseline; and rayon) and beside it its GPU launcher, [`likelihood::gpu`]
//!   (`shaders/face/likelihood.wgsl`);
//! - [`image`]: gray frames with bilinear sampling;
//! - [`synth`]: synthetic videos of textured heads with ground truth;
//! - [`tracker`]: several faces at once, each its own filter, on the CPU, a GPU or several GPUs
//!   ([`tracker::shards`]), with failure detection; slots free when a track is lost and take new faces;
//!   [`tracker::in_flight`]: two frames in flight on the GPUs (`submit` / `finish`);
//! - [`detect`]: Viola–Jones face detection with OpenCV's Haar cascades;
//! - [`landmarks`]: dlib's 68-point shape predictor, read and run in Rust; [`personal`]: the
//!   face model warped to a face's landmarks (the personalised model);
//! - [`auto`]: fully automatic tracking: the detector in its own thread starts tracks.

pub mod auto;
pub mod camera;
pub mod detect;
pub mod enlarge;
pub mod error;
pub mod extraction;
pub mod identity;
pub mod image;
pub mod landmarks;
pub mod lens;
pub mod likelihood;
mod mesh_head;
pub mod model;
pub mod mot;
pub mod openface;
pub mod personal;
pub mod projection;
pub mod scene_cut;
pub mod synth;
pub mod template;
pub mod tracker;
pub mod view;

pub use auto::{AutoConfig, AutoFrame, AutoTracker};
pub use error::FaceError;
pub use image::{FloatImage, GrayImage};
pub use projection::{DIMS, Pose, rotation};
pub use template::{FeaturePoint, Template};
pub use tracker::{FaceBackend, FaceEstimate, FaceTracker, FaceTrackerConfig, TrackStatus};
