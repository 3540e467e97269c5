#![warn(missing_docs)]
//! # pf-gpu: the wgpu runtime of streampf
//!
//! The runtime that runs a whole filter step on the GPU for many targets at once: adapter choice
//! ([`list_adapters`], [`GpuContext`] with the adapter's real limits), typed device streams, WGSL
//! kernels from `shaders/`, the generic stages (diffuse, normalise, estimate, resample; [`filter`])
//! each with a CPU twin in `pf-core`, and the seam a model's likelihood plugs into
//! ([`GpuLikelihood`], or WGSL through [`model`]). The trackers' kernels are launched from their
//! own crates (`face_tracker::likelihood::gpu`, `body_tracker::likelihood::gpu`, …) through the
//! same [`Kernel`] and streams.
//!
//! Adapter choice honours `WGPU_BACKEND` and `WGPU_ADAPTER_NAME`.

pub mod adapters;
pub mod error;

pub use adapters::{AdapterSummary, list_adapters};
pub use error::{GpuError, NO_ADAPTER_HELP};
pub mod context;
pub mod engine;
pub mod filter;
pub mod image;
pub mod kernels;
pub mod load;
pub mod model;
pub mod random;
pub mod smooth;
pub mod stream;
pub mod timing;
pub mod toy;

pub use context::{CHECK_KERNELS_VAR, ContextOptions, GpuContext};
pub use filter::{
    DispatchTime, FUSED_DEFAULT_MAX_VALUES, GpuFilter, GpuLikelihood, GpuResampler, GpuStage,
    GpuStepReport, LagFrame, LaggedSummaries, LaggedTarget, LikelihoodInputs, LikelihoodPhase,
    LikelihoodReadbacks, MAX_LAG, MAX_LAG_PARTICLES, NoLikelihood, ParticlesBack, PendingStep,
    ReadbackSource, RecordingId, StepLayout, TargetStats, fused_layout_refusal,
    fused_workgroup_bytes,
};
pub use image::GrayTexture;
pub use kernels::Kernel;
pub use stream::{DeviceStream, Readback, ReadbackSet};
pub use timing::GpuTime;
/// The wgpu this crate is built on, for likelihoods that record their own dispatches.
pub use wgpu;
