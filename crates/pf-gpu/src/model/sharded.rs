//! A WGSL model's targets split over several GPUs: [`ShardedModelFilter`], the engine's
//! [`Sharded`] filter of a [`WgslModel`] (see `crate::engine::sharded` for how the split keeps one
//! GPU's results).

use bytemuck::Pod;
use pf_core::batch::BatchConfig;

use super::{ModelSource, WgslModel};
use crate::context::GpuContext;
use crate::engine::Sharded;
use crate::error::GpuError;
use crate::filter::GpuResampler;

/// A [`super::ModelFilter`] whose targets are split over several GPUs (one shard of targets
/// each).
pub type ShardedModelFilter<O, C> = Sharded<WgslModel<O, C>>;

impl<O: Pod, C: Pod> Sharded<WgslModel<O, C>> {
    /// The batch of `config` split over `contexts` (one shard each; with fewer targets than
    /// contexts, the extra contexts are not used), each shard's model compiled from `model`.
    /// `initial_states` in the whole batch's layout (`[(t·D + d)·M + m]`).
    pub fn new(
        contexts: Vec<GpuContext>,
        config: &BatchConfig,
        resampler: GpuResampler,
        initial_states: &[f32],
        model: ModelSource<'_>,
        constants: &C,
    ) -> Result<Self, GpuError> {
        Self::on_gpus(contexts, config, resampler, initial_states, |ctx, part| {
            WgslModel::new(ctx, model, &part.shape, constants)
        })
    }
}
