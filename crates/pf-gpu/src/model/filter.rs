//! A GPU filter built with its model, [`PluginFilter`]: [`ModelFilter`] for a typed model
//! (observations and constants as `Pod` types) and [`RawModelFilter`] for one sized at run time
//! (f32 values: the Python package's). The two differ only in how they are built and what an
//! observation is; they step the same way, a frame at a time or two frames in flight, as the
//! trackers do: `submit` records and submits a frame without waiting, `finish` waits for the
//! oldest and reads it back, with the results of stepping one at a time, bit for bit.

use bytemuck::Pod;
use pf_core::batch::BatchConfig;

use super::{ModelSource, RawWgslModel, WgslModel};
use crate::context::GpuContext;
use crate::error::GpuError;
use crate::filter::{GpuFilter, GpuLikelihood, GpuResampler, GpuStage, GpuStepReport, PendingStep};

/// Every stage of a frame, in order.
const WHOLE_STEP: [GpuStage; 6] = [
    GpuStage::Resample,
    GpuStage::Gather,
    GpuStage::Diffuse,
    GpuStage::Likelihood,
    GpuStage::Normalise,
    GpuStage::Estimate,
];

/// What a [`PluginFilter`] needs of its model beyond the [`GpuLikelihood`]: how one frame's
/// observations (one per target) reach the GPU.
pub trait PluginModel: GpuLikelihood {
    /// One target's observation: the model's `Observation` type, or its f32 values.
    type Observation: Pod;

    /// Uploads one frame's observations (`[t]`, or `[t·K + k]` for f32 values).
    fn upload_observations(
        &self,
        ctx: &GpuContext,
        observations: &[Self::Observation],
    ) -> Result<(), GpuError>;
}

impl<O: Pod, C: Pod> PluginModel for WgslModel<O, C> {
    type Observation = O;

    fn upload_observations(&self, ctx: &GpuContext, observations: &[O]) -> Result<(), GpuError> {
        self.set_observations(ctx, observations)
    }
}

impl PluginModel for RawWgslModel {
    type Observation = f32;

    fn upload_observations(&self, ctx: &GpuContext, observations: &[f32]) -> Result<(), GpuError> {
        self.set_observations(ctx, observations)
    }
}

/// A GPU filter built with its model: the model is prepared against the filter's streams at
/// construction, so it can neither be forgotten nor bound to another filter.
pub struct PluginFilter<M: PluginModel> {
    filter: GpuFilter,
    model: M,
}

/// A [`PluginFilter`] of a typed model ([`WgslModel`]).
pub type ModelFilter<O, C> = PluginFilter<WgslModel<O, C>>;

/// A [`PluginFilter`] of a model sized at run time ([`RawWgslModel`]: observations and
/// constants as f32 values).
pub type RawModelFilter = PluginFilter<RawWgslModel>;

impl<O: Pod, C: Pod> PluginFilter<WgslModel<O, C>> {
    /// `initial_states` in the batch layout (`[(t·D + d)·M + m]`).
    pub fn new(
        ctx: &GpuContext,
        config: &BatchConfig,
        resampler: GpuResampler,
        initial_states: &[f32],
        model: ModelSource<'_>,
        constants: &C,
    ) -> Result<Self, GpuError> {
        let filter = GpuFilter::new(ctx, config, resampler, initial_states)?;
        let model = WgslModel::new(ctx, model, &config.shape, constants)?;
        Self::prepared(ctx, filter, model)
    }
}

impl PluginFilter<RawWgslModel> {
    /// `initial_states` in the batch layout (`[(t·D + d)·M + m]`); `observation_values` 32-bit
    /// values make one target's `Observation`.
    pub fn new(
        ctx: &GpuContext,
        config: &BatchConfig,
        resampler: GpuResampler,
        initial_states: &[f32],
        model: ModelSource<'_>,
        observation_values: usize,
        constants: &[f32],
    ) -> Result<Self, GpuError> {
        let filter = GpuFilter::new(ctx, config, resampler, initial_states)?;
        let model = RawWgslModel::new(ctx, model, &config.shape, observation_values, constants)?;
        Self::prepared(ctx, filter, model)
    }
}

impl<M: PluginModel> PluginFilter<M> {
    fn prepared(ctx: &GpuContext, filter: GpuFilter, mut model: M) -> Result<Self, GpuError> {
        model.prepare(ctx, &filter.likelihood_inputs())?;
        Ok(Self { filter, model })
    }

    /// One frame: resample, propagate (or diffuse), measure against `observations` (one per
    /// target), normalise, estimate — one submission.
    pub fn step(
        &mut self,
        ctx: &GpuContext,
        observations: &[M::Observation],
    ) -> Result<GpuStepReport, GpuError> {
        self.model.upload_observations(ctx, observations)?;
        self.filter.step(ctx, &self.model)
    }

    /// Submits a frame against `observations` without waiting for it: the GPU steps it while
    /// the host prepares the next frame or reads the one before. At most two frames are in
    /// flight; [`Self::finish`] them in the order submitted. (The next frame's observations
    /// may be set at once: the queue writes them after this frame's work.)
    pub fn submit(
        &mut self,
        ctx: &GpuContext,
        observations: &[M::Observation],
    ) -> Result<PendingStep, GpuError> {
        self.model.upload_observations(ctx, observations)?;
        self.filter.submit_stages(ctx, &WHOLE_STEP, &self.model)
    }

    /// Waits for the oldest frame in flight and reads its results back.
    pub fn finish(
        &mut self,
        ctx: &GpuContext,
        pending: PendingStep,
    ) -> Result<GpuStepReport, GpuError> {
        self.filter.finish_step(ctx, pending)
    }

    /// The filter (states, weights, downloads).
    pub fn filter(&self) -> &GpuFilter {
        &self.filter
    }

    /// The filter, to number its targets as a part of a larger batch
    /// ([`GpuFilter::number_targets_from`]).
    pub fn filter_mut(&mut self) -> &mut GpuFilter {
        &mut self.filter
    }

    /// The filter and its model, for running single stages ([`GpuFilter::run_stages`]).
    pub fn parts(&mut self) -> (&mut GpuFilter, &M) {
        (&mut self.filter, &self.model)
    }

    /// The model (observations, constants, generated source).
    pub fn model(&self) -> &M {
        &self.model
    }
}
