//! The seam between the filter and an observation model on the GPU: the streams a likelihood
//! binds, the trait it implements, and the likelihood that does nothing (stage tests).

use crate::context::GpuContext;
use crate::error::GpuError;
use crate::stream::DeviceStream;
use pf_core::batch::BatchShape;

/// The streams a likelihood reads and writes, handed to [`GpuLikelihood::prepare`].
pub struct LikelihoodInputs<'a> {
    /// Targets × particles × dimensions.
    pub shape: BatchShape,
    /// The frame parameters (uniform buffer, `Params` of `shaders/common.wgsl`).
    pub params: &'a wgpu::Buffer,
    /// States, `[(t·D + d)·M + m]`, already diffused when the likelihood runs.
    pub states: &'a DeviceStream<f32>,
    /// Where the likelihood writes `log p(z | x)`, `[t·M + m]`.
    pub log_likelihood: &'a DeviceStream<f32>,
    /// The step's estimate per target, `[t·D + d]`: the best-M′ weighted mean where the filter
    /// computes one, else the weighted mean (written by the Estimate stage).
    pub estimates: &'a DeviceStream<f32>,
    /// The per-target Philox keys of the diffusion stream (`counter_gaussian(key_t, m, d,
    /// step)`), for a likelihood that brings its own dynamics ([`GpuLikelihood::propagates`]).
    pub diffusion_keys: &'a DeviceStream<[u32; 2]>,
}

/// An observation model on the GPU. A tracker builds its pipelines and bind groups once in
/// `prepare`, uploads each frame's observation before the step, and records its dispatches.
pub trait GpuLikelihood {
    /// Binds the filter's streams (once, after construction); builds its bind groups.
    fn prepare(&mut self, ctx: &GpuContext, inputs: &LikelihoodInputs<'_>) -> Result<(), GpuError>;
    /// Records the likelihood's dispatches into the step's compute pass.
    fn record(&self, pass: &mut wgpu::ComputePass<'_>);

    /// Whether `prepare` has bound it; a step with an unprepared likelihood is an error rather
    /// than a step that weighs stale values.
    fn is_prepared(&self) -> bool {
        true
    }

    /// Whether it brings its own dynamics, recorded by [`GpuLikelihood::record_propagate`] in
    /// place of the filter's Gaussian random walk.
    fn propagates(&self) -> bool {
        false
    }

    /// The dynamics' dispatches (the Diffuse stage) when [`GpuLikelihood::propagates`].
    fn record_propagate(&self, _pass: &mut wgpu::ComputePass<'_>) {}

    /// Work on the step's estimates (a tracker's check of its estimate, say), recorded after
    /// the Estimate stage in the same pass.
    fn record_after_estimate(&self, _pass: &mut wgpu::ComputePass<'_>) {}

    /// Copies into the likelihood's own readbacks, recorded at the end of a step that ran the
    /// Estimate stage; [`GpuLikelihood::request_maps`] follows before the step's one wait.
    fn record_readbacks(&self, _encoder: &mut wgpu::CommandEncoder) {}

    /// Asks for the likelihood's readbacks to be mapped, so that they share the step's wait.
    fn request_maps(&self) {}
}

/// A likelihood that records nothing (the log-likelihood stream keeps its contents).
pub struct NoLikelihood;

impl GpuLikelihood for NoLikelihood {
    fn prepare(&mut self, _: &GpuContext, _: &LikelihoodInputs<'_>) -> Result<(), GpuError> {
        Ok(())
    }
    fn record(&self, _: &mut wgpu::ComputePass<'_>) {}
}
