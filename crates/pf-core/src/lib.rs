#![warn(missing_docs)]
//! # pf-core: the Condensation engine
//!
//! A generic particle filter (Isard & Blake's Condensation: select, diffuse, measure) over a
//! fixed-size `f32` state, with everything the GPU runtime (`pf-gpu`) mirrors:
//!
//! - [`ParticleSet`]: struct-of-arrays storage, one dimension-major buffer per target, laid out as
//!   the GPU buffers are;
//! - [`weights`]: log-domain weights, log-sum-exp normalisation, effective sample size;
//! - [`resample`]: multinomial, stratified, systematic, residual, Metropolis and rejection
//!   resamplers behind one trait that takes its uniforms from the caller;
//! - [`estimate`]: weighted mean, best-M′ weighted mean, maximum weight, with angle dimensions
//!   averaged on the circle;
//! - [`random`]: seeded xoshiro256++ streams per (target, stage) and counter-based Philox
//!   uniforms, all reproducible from one seed;
//! - [`anneal`]: annealed particle filtering (layers of tempered weighing and shrinking
//!   diffusion per frame), run by the batch filter and its GPU twin;
//! - [`ParticleFilter`]: the loop, with an ESS-triggered or every-step resampling policy, typed
//!   errors for degenerate weights and a recovery helper.
//!
//! ```
//! use nalgebra::{vector, SVector};
//! use pf_core::{FilterConfig, GaussianDiffusion, GaussianObservation, ParticleFilter, StateSpace};
//! use pf_core::resample::Systematic;
//!
//! let dynamics = GaussianDiffusion::new(vector![0.1, 0.1])?;
//! let mut filter = ParticleFilter::new(
//!     FilterConfig::new(500, 42), dynamics, Systematic, &vector![0.0, 0.0], &vector![1.0, 1.0])?;
//! let observation = GaussianObservation {
//!     observed: vector![0.5, -0.2], sigma: vector![0.2, 0.2], space: StateSpace::euclidean() };
//! let report = filter.step(&observation)?;
//! assert!((report.estimate - vector![0.5, -0.2]).norm() < 0.2);
//! # Ok::<(), pf_core::PfError>(())
//! ```
//!
//! pf-core has no GPU type and does no file or image I/O.

pub mod anneal;
pub mod batch;
pub mod error;
pub mod estimate;
pub mod filter;
pub mod islands;
pub mod model;
pub mod particles;
pub mod plugin;
pub mod random;
pub mod resample;
pub mod weights;

pub use error::PfError;
pub use estimate::StateSpace;
pub use filter::{FilterConfig, ParticleFilter, ResamplePolicy, StepReport};
pub use model::{Dynamics, GaussianDiffusion, GaussianObservation, Likelihood, LinearGaussian};
pub use particles::ParticleSet;
pub use random::{CounterUniforms, RandomStream, RandomStreams, Stage, UniformSource};
pub use resample::{Resampler, ResamplerKind};
