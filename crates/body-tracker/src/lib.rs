//! # body-tracker
//!
//! The stereo articulated body tracker of Friborg, Hauberg & Erleben ("GPU accelerated
//! likelihoods for stereo-based articulated tracking"), rebuilt on `pf-core`:
//!
//! - [`skeleton`]: a tree of rigid bones with 0–3 joint angles and limits, a root pose, forward
//!   kinematics to capsules, a JSON file form; [`human`]: the default human with 19–96 capsules;
//! - [`capsule`]: the ray–capsule intersection of the paper's Appendix A and the truncated metric
//!   (eq. 6);
//! - [`likelihood`]: the log-likelihood (eq. 3) with Listing 1.2's single-thread loop (the
//!   reference and speed baseline) and a rayon version over samples (beside it its GPU launcher
//!   [`likelihood::gpu`]; the kinematics' in [`skeleton::gpu`], fed by [`Skeleton::gpu_bones`]);
//! - [`camera`], [`ply`], [`sequence`]: depth cameras and 16-bit depth PNGs, PLY point clouds,
//!   sequence directories with ground truth, CSV output;
//! - [`benchmark_scene`]: the points and pose samples of the paper's speed figures;
//! - [`synth`]: synthetic sequences (walking, arm waving) with noise, dropout, outliers and
//!   self-occlusion;
//! - [`tracker`]: the particle filter over θ on the CPU, one GPU, or several GPUs ([`tracker::islands`]:
//!   one island of the samples per GPU).

pub mod benchmark_scene;
pub mod camera;
pub mod capsule;
pub mod error;
pub mod frame;
pub mod human;
pub mod likelihood;
pub mod overlay;
pub mod ply;
pub mod sequence;
pub mod skeleton;
pub mod synth;
pub mod tracker;

pub use capsule::{Capsule, ray_capsule, truncated_distance};
pub use error::BodyError;
pub use frame::{FramePreparer, PreparedFrame};
pub use human::human_skeleton;
pub use likelihood::{CapsuleLikelihoodParams, Rays, listing_1_2, parallel_over_samples};
pub use skeleton::{Skeleton, SkeletonSpec};
pub use tracker::{
    Backend, BodyTracker, FrameResult, TrackerConfig, Weighing, mean_joint_error,
    partitioned_schedule,
};
