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
//! - [`batch::BatchFilter`]: the loop for T targets at once (the twin of pf-gpu's driver, drawing
//!   the same counter-based random numbers): an ESS-triggered or every-step resampling policy,
//!   annealing layers, typed errors for degenerate weights, and each frame's log evidence;
//! - [`smooth`]: each frame's posterior given the later frames too (the marginal smoother, whole
//!   runs or a fixed lag), with 95 % credible intervals.
//!
//! ```
//! use pf_core::batch::{BatchConfig, BatchFilter, BatchShape, gaussian_clouds};
//! use pf_core::resample::Systematic;
//!
//! // One target, 500 particles, 2 dimensions, random-walk diffusion σ = 0.1.
//! let shape = BatchShape::new(1, 500, 2)?;
//! let config = BatchConfig::new(shape, 42, vec![0.1, 0.1]);
//! let start = gaussian_clouds(&shape, 42, &[0.0, 0.0], &[1.0, 1.0]);
//! let mut filter = BatchFilter::new(&config, Systematic, start)?;
//! let observed = [0.5f32, -0.2];
//! let report = filter.step(|_target, _particle, x| {
//!     -0.5 * x.iter().zip(observed).map(|(x, z)| ((x - z) / 0.2).powi(2)).sum::<f32>()
//! })?;
//! let error = report.estimates.iter().zip(observed).map(|(e, z)| (e - z).abs()).fold(0.0, f32::max);
//! assert!(error < 0.2);
//! assert!(report.log_evidence[0].is_finite());
//! # Ok::<(), pf_core::PfError>(())
//! ```
//!
//! pf-core has no GPU type and does no file or image I/O.

pub mod anneal;
pub mod batch;
pub mod error;
pub mod estimate;
pub mod islands;
pub mod kalman;
pub mod model;
pub mod particles;
pub mod plugin;
pub mod random;
pub mod resample;
pub mod smooth;
pub mod smooth_tracks;
pub mod weights;

pub use error::PfError;
pub use estimate::StateSpace;
pub use model::{GaussianObservation, Likelihood};
pub use particles::ParticleSet;
pub use random::{CounterUniforms, RandomStream, RandomStreams, Stage, UniformSource};
pub use resample::{Resampler, ResamplerKind};
