//! A researcher's WGSL model as a [`Model`] of the one [`Filter`]: [`ModelFilter`] for a typed
//! model (observations and constants as `Pod` types) and [`RawModelFilter`] for one sized at run
//! time (f32 values: the Python package's). They step as every filter does, a frame at a time or
//! two frames in flight (`submit`, `finish`), with the engine's layers and drift, and over several
//! GPUs through [`super::ShardedModelFilter`].

use bytemuck::Pod;
use pf_core::batch::{BatchConfig, BatchShape};

use super::{ModelSource, RawWgslModel, WgslModel};
use crate::context::GpuContext;
use crate::engine::{Filter, Model};
use crate::error::GpuError;
use crate::filter::{GpuLikelihood, GpuResampler, LikelihoodInputs};

/// A [`Filter`] of a typed WGSL model ([`WgslModel`]); a frame is one observation per target.
pub type ModelFilter<O, C> = Filter<WgslModel<O, C>>;

/// A [`Filter`] of a WGSL model sized at run time ([`RawWgslModel`]: observations and constants
/// as f32 values); a frame is `[t·K + k]`, K values per target.
pub type RawModelFilter = Filter<RawWgslModel>;

/// What a WGSL model answers on the CPU engine: its CPU twin is a separate
/// `pf_core::plugin::CpuModel`, run by `BatchFilter::step_model` and checked against the WGSL
/// by [`super::check_against_cpu`].
fn no_cpu_side(name: &str) -> GpuError {
    GpuError::InvalidConfig(format!(
        "the WGSL model {name} runs on the GPU engine; its CPU twin is a \
         pf_core::plugin::CpuModel run by BatchFilter::step_model"
    ))
}

impl<O: Pod, C: Pod> Model for WgslModel<O, C> {
    type Frame<'f> = [O];
    type Error = GpuError;

    fn prepare_gpu(
        &mut self,
        ctx: &GpuContext,
        inputs: &LikelihoodInputs<'_>,
    ) -> Result<(), GpuError> {
        self.prepare(ctx, inputs)
    }

    fn upload_frame(
        &mut self,
        ctx: &GpuContext,
        frame: &[O],
    ) -> Result<&dyn GpuLikelihood, GpuError> {
        self.set_observations(ctx, frame)?;
        Ok(self)
    }

    fn measure_on_cpu(
        &self,
        _: &[O],
        _: &BatchShape,
        _: &[f32],
        _: &mut [f32],
    ) -> Result<(), GpuError> {
        Err(no_cpu_side(self.name()))
    }
}

impl Model for RawWgslModel {
    type Frame<'f> = [f32];
    type Error = GpuError;

    fn prepare_gpu(
        &mut self,
        ctx: &GpuContext,
        inputs: &LikelihoodInputs<'_>,
    ) -> Result<(), GpuError> {
        self.prepare(ctx, inputs)
    }

    fn upload_frame(
        &mut self,
        ctx: &GpuContext,
        frame: &[f32],
    ) -> Result<&dyn GpuLikelihood, GpuError> {
        self.set_observations(ctx, frame)?;
        Ok(self)
    }

    fn measure_on_cpu(
        &self,
        _: &[f32],
        _: &BatchShape,
        _: &[f32],
        _: &mut [f32],
    ) -> Result<(), GpuError> {
        Err(no_cpu_side(self.name()))
    }
}

impl<O: Pod, C: Pod> Filter<WgslModel<O, C>> {
    /// The model of `source` on the GPU of `ctx` (the filter keeps a handle to it);
    /// `initial_states` in the batch layout (`[(t·D + d)·M + m]`).
    pub fn new(
        ctx: &GpuContext,
        config: &BatchConfig,
        resampler: GpuResampler,
        initial_states: &[f32],
        source: ModelSource<'_>,
        constants: &C,
    ) -> Result<Self, GpuError> {
        let model = WgslModel::new(ctx, source, &config.shape, constants)?;
        Self::on_gpu(ctx.clone(), config, resampler, initial_states, model)
    }
}

impl Filter<RawWgslModel> {
    /// The model of `source` on the GPU of `ctx` (the filter keeps a handle to it);
    /// `initial_states` in the batch layout (`[(t·D + d)·M + m]`); `observation_values` 32-bit
    /// values make one target's `Observation`.
    pub fn new(
        ctx: &GpuContext,
        config: &BatchConfig,
        resampler: GpuResampler,
        initial_states: &[f32],
        source: ModelSource<'_>,
        observation_values: usize,
        constants: &[f32],
    ) -> Result<Self, GpuError> {
        let model = RawWgslModel::new(ctx, source, &config.shape, observation_values, constants)?;
        Self::on_gpu(ctx.clone(), config, resampler, initial_states, model)
    }
}
