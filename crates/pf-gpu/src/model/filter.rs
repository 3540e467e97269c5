//! A GPU filter built with its model: [`ModelFilter`] (typed observations and constants) and
//! [`RawModelFilter`] (f32 values sized at run time, the Python package's). Each steps a frame
//! at a time or keeps two frames in flight, as the trackers do: `submit` records and submits a
//! frame without waiting, `finish` waits for the oldest and reads it back, with the results of
//! stepping one at a time, bit for bit.

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

/// A GPU filter built with its model: the model is prepared against the filter's streams at
/// construction, so it can neither be forgotten nor bound to another filter.
pub struct ModelFilter<O: Pod, C: Pod> {
    filter: GpuFilter,
    model: WgslModel<O, C>,
}

impl<O: Pod, C: Pod> ModelFilter<O, C> {
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
        let mut model = WgslModel::new(ctx, model, &config.shape, constants)?;
        model.prepare(ctx, &filter.likelihood_inputs())?;
        Ok(Self { filter, model })
    }

    /// One frame: resample, propagate (or diffuse), measure against `observations` (one per
    /// target), normalise, estimate — one submission.
    pub fn step(
        &mut self,
        ctx: &GpuContext,
        observations: &[O],
    ) -> Result<GpuStepReport, GpuError> {
        self.model.set_observations(ctx, observations)?;
        self.filter.step(ctx, &self.model)
    }

    /// Submits a frame against `observations` without waiting for it: the GPU steps it while
    /// the host prepares the next frame or reads the one before. At most two frames are in
    /// flight; [`Self::finish`] them in the order submitted. (The next frame's observations
    /// may be set at once: the queue writes them after this frame's work.)
    pub fn submit(
        &mut self,
        ctx: &GpuContext,
        observations: &[O],
    ) -> Result<PendingStep, GpuError> {
        self.model.set_observations(ctx, observations)?;
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
    pub fn parts(&mut self) -> (&mut GpuFilter, &WgslModel<O, C>) {
        (&mut self.filter, &self.model)
    }

    /// The model (observations, constants, generated source).
    pub fn model(&self) -> &WgslModel<O, C> {
        &self.model
    }
}

/// [`ModelFilter`] for a [`RawWgslModel`]: observations and constants as f32 values.
pub struct RawModelFilter {
    filter: GpuFilter,
    model: RawWgslModel,
}

impl RawModelFilter {
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
        let mut model =
            RawWgslModel::new(ctx, model, &config.shape, observation_values, constants)?;
        model.prepare(ctx, &filter.likelihood_inputs())?;
        Ok(Self { filter, model })
    }

    /// One frame against `observations` (`[t·K + k]`), one submission.
    pub fn step(
        &mut self,
        ctx: &GpuContext,
        observations: &[f32],
    ) -> Result<GpuStepReport, GpuError> {
        self.model.set_observations(ctx, observations)?;
        self.filter.step(ctx, &self.model)
    }

    /// [`ModelFilter::submit`] for f32 observations (`[t·K + k]`).
    pub fn submit(
        &mut self,
        ctx: &GpuContext,
        observations: &[f32],
    ) -> Result<PendingStep, GpuError> {
        self.model.set_observations(ctx, observations)?;
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

    /// The model (constants, generated source).
    pub fn model(&self) -> &RawWgslModel {
        &self.model
    }
}
