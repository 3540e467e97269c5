//! Recording a frame into a command encoder: every annealing layer's selection, moving, measuring
//! and weighing stages (each layer's parameter block copied into the uniform buffer first), then
//! the estimate and the copies into the step's staging buffer.

use super::lag_window::LagStep;
use super::profile::Passes;
use super::{
    FrameParams, GpuFilter, GpuLikelihood, GpuStage, LikelihoodPhase, STEP_BACK_BEST,
    STEP_BACK_ESTIMATES, STEP_BACK_OWN, STEP_BACK_SPREADS, STEP_BACK_STATS, StepLayout, groups_for,
};
use crate::context::GpuContext;

impl GpuFilter {
    /// Writes the frame's layer parameters, then records the given stages, in the step's order:
    /// the selection, moving, measuring and weighing stages once per annealing layer (each
    /// layer with the next step index), then the estimate, and for a whole step the lag window
    /// (where kept). Returns whether the step summarises a lagged frame.
    pub(super) fn record_stages(
        &mut self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        stages: &[GpuStage],
        likelihood: &dyn GpuLikelihood,
    ) -> bool {
        self.write_layer_params(ctx, stages);
        self.record_commands(ctx, encoder, stages, likelihood)
    }

    /// [`Self::record_stages`] but the parameters: the commands alone, which read the
    /// parameters from their buffers when they run (so that they can be recorded a step ahead:
    /// `prerecord.rs`).
    pub(super) fn record_commands(
        &mut self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        stages: &[GpuStage],
        likelihood: &dyn GpuLikelihood,
    ) -> bool {
        let whole_step = GpuStage::ALL.iter().all(|s| stages.contains(s));
        let lag_step = whole_step.then(|| self.prepare_lag_step(ctx)).flatten();
        self.record_frame(encoder, stages, likelihood, lag_step);
        let lagged = lag_step.is_some_and(|step| self.record_lag_readback(encoder, step));
        if let Some(profiler) = &mut self.profiler {
            profiler.resolve(encoder);
        }
        lagged
    }

    /// Whether `stages` run as the fused step (a whole step, where the fused layers fit).
    fn runs_fused(&self, stages: &[GpuStage]) -> bool {
        let whole_step = GpuStage::ALL.iter().all(|s| stages.contains(s));
        whole_step && self.layout == StepLayout::Fused && self.fused.is_some()
    }

    /// The frame's parameter block per layer (keyed by the next step indices, which it
    /// advances) into `layer_params`; for the fused step also the first layer's into
    /// `params_buffer`, the likelihood's view of the parameters (the frame's shape, and the step a
    /// likelihood's own dynamics draw with). The staged step copies each layer's block there in
    /// its commands.
    pub(super) fn write_layer_params(&mut self, ctx: &GpuContext, stages: &[GpuStage]) {
        let layers = self.annealing.layers;
        let blocks: Vec<FrameParams> = (0..layers)
            .map(|layer| {
                self.params
                    .for_layer(&self.annealing, layer, self.step + layer as u64)
            })
            .collect();
        self.step += layers as u64;
        let mut strided = vec![0u8; layers * self.layer_stride as usize];
        for (layer, block) in blocks.iter().enumerate() {
            let at = layer * self.layer_stride as usize;
            strided[at..at + std::mem::size_of::<FrameParams>()]
                .copy_from_slice(bytemuck::bytes_of(block));
        }
        ctx.queue.write_buffer(&self.layer_params, 0, &strided);
        if self.runs_fused(stages) {
            ctx.queue
                .write_buffer(&self.params_buffer, 0, bytemuck::bytes_of(&blocks[0]));
        }
    }

    /// The frame's commands, and the lag window's dispatches at its end for a whole step
    /// (`lag_step`; in the fused step's own pass).
    fn record_frame(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        stages: &[GpuStage],
        likelihood: &dyn GpuLikelihood,
        lag_step: Option<LagStep>,
    ) {
        if let (true, Some(fused)) = (self.runs_fused(stages), &self.fused) {
            let mut profiler = self.profiler.take();
            self.record_fused(encoder, fused, likelihood, profiler.as_mut(), lag_step);
            self.profiler = profiler;
            return;
        }
        // Not the fused step: nothing of it to report as profiled.
        if let Some(profiler) = &mut self.profiler {
            profiler.forget();
        }
        let block_bytes = std::mem::size_of::<FrameParams>() as u64;
        for layer in 0..self.annealing.layers {
            encoder.copy_buffer_to_buffer(
                &self.layer_params,
                layer as u64 * self.layer_stride,
                &self.params_buffer,
                0,
                block_bytes,
            );
            self.record_layer(encoder, stages, likelihood, layer);
        }

        if stages.contains(&GpuStage::Estimate) {
            self.record_estimate(encoder, likelihood);
        }
        if let Some(step) = lag_step {
            let mut passes = Passes::begin(encoder, None, "lag window");
            self.record_lag_dispatches(&mut passes, step);
            drop(passes);
        }
        self.record_copies_back(encoder, likelihood);
    }

    /// The estimate's pass: the weighted (and best-M′) means, then the likelihood's work on them.
    fn record_estimate(&self, encoder: &mut wgpu::CommandEncoder, likelihood: &dyn GpuLikelihood) {
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("estimate"),
            timestamp_writes: None,
        });
        self.record_estimate_into(&mut pass, likelihood);
    }

    /// The estimate's dispatches into `pass`.
    pub(super) fn record_estimate_into(
        &self,
        pass: &mut wgpu::ComputePass<'_>,
        likelihood: &dyn GpuLikelihood,
    ) {
        // One workgroup per value and target: a target's values are independent sums.
        let per_value = [self.shape.dims as u32, self.shape.targets as u32, 1];
        self.stages
            .estimate
            .record(pass, &self.groups.estimate, per_value);
        if let (Some(k), Some(g)) = (&self.stages.best_mean, &self.groups.best_mean) {
            k.record(pass, g, per_value);
        }
        likelihood.record(LikelihoodPhase::AfterEstimate, pass);
    }

    /// The step's results copied into its staging buffer: the likelihood's named readbacks, the
    /// estimates, statistics, best-M′ estimates and spreads.
    pub(super) fn record_copies_back(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        likelihood: &dyn GpuLikelihood,
    ) {
        let back = &self.step_backs[self.next_back];
        // Only into sections the staging buffer was fitted with (`run_stages` fits it first; a
        // bare `record_step` of a likelihood it was never fitted for copies nothing).
        let fitted = likelihood
            .readbacks()
            .into_iter()
            .zip(&self.likelihood_sections);
        for (k, (source, &(name, bytes))) in fitted.enumerate() {
            if source.name == name && source.bytes == bytes {
                back.record_copy(encoder, STEP_BACK_OWN + k, source.buffer);
            }
        }
        back.record_copy(
            encoder,
            STEP_BACK_ESTIMATES,
            self.streams.estimates.buffer(),
        );
        back.record_copy(encoder, STEP_BACK_STATS, self.streams.stats.buffer());
        back.record_copy(
            encoder,
            STEP_BACK_BEST,
            self.streams.best_estimates.buffer(),
        );
        back.record_copy(encoder, STEP_BACK_SPREADS, self.streams.spreads.buffer());
    }

    /// One annealing layer's stages (the whole frame but the estimate without annealing): the
    /// first layer moves particles with the likelihood's own dynamics when it has them, later
    /// layers with the (scaled) random walk.
    fn record_layer(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        stages: &[GpuStage],
        likelihood: &dyn GpuLikelihood,
        layer: usize,
    ) {
        let (t, m) = (self.shape.targets, self.shape.particles);
        let per_particle = [groups_for(m, 64), t as u32, 1];
        let per_target = [1, t as u32, 1];
        let wants = |s: GpuStage| stages.contains(&s);
        if wants(GpuStage::Resample) || wants(GpuStage::Gather) {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("select"),
                timestamp_writes: None,
            });
            if wants(GpuStage::Resample) {
                for step in &self.resample_steps {
                    step.kernel.record(&mut pass, &step.group, step.groups);
                }
            }
            if wants(GpuStage::Gather) {
                self.stages
                    .gather
                    .record(&mut pass, &self.groups.gather, per_particle);
            }
            if wants(GpuStage::Resample) {
                self.record_lineage(&mut pass, layer);
            }
        }
        if wants(GpuStage::Gather) {
            let bytes = (self.shape.state_len() * 4) as u64;
            encoder.copy_buffer_to_buffer(
                self.streams.selected.buffer(),
                0,
                self.streams.states.buffer(),
                0,
                bytes,
            );
        }
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("diffuse, measure, normalise"),
            timestamp_writes: None,
        });
        if wants(GpuStage::Diffuse) {
            if layer == 0 && likelihood.propagates() {
                likelihood.record(LikelihoodPhase::Propagate, &mut pass);
            } else {
                self.stages
                    .diffuse
                    .record(&mut pass, &self.groups.diffuse, per_particle);
            }
        }
        if wants(GpuStage::Likelihood) {
            likelihood.record(LikelihoodPhase::Measure { layer }, &mut pass);
        }
        if wants(GpuStage::Normalise) {
            self.stages
                .normalise
                .record(&mut pass, &self.groups.normalise, per_target);
        }
    }
}
