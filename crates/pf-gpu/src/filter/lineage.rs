//! The particles' lineage through a frame, kept when asked ([`super::GpuFilter::keep_lineage`]):
//! after each layer's resampling `shaders/engine/lineage.wgsl` composes the layer's ancestors
//! into each particle's index among the previous frame's particles, in two buffers used in turn
//! (a layer reads the one the layer before wrote). A target restarted since the last frame
//! (`reset_target`) has no ancestors there ([`pf_core::smooth::ancestry::NO_ANCESTOR`]): its
//! flag is read by the first layer and cleared by a dispatch of its own after it. The fused
//! step composes the same values in each layer's select instead (`layer.wgsl`,
//! `select_*_keeping_lineage`, the flag cleared by the target's own workgroup) where the adapter
//! binds the select's storage buffers and the lineage's: no dispatch of its own
//! ([`super::GpuFilter::set_lineage_in_select`]).
//!
//! CPU twin: `pf_core::smooth::ancestry::compose`, as `pf_core::batch::BatchFilter` keeps it.

use pf_core::batch::BatchShape;

use super::setup::{Streams, groups_for};
use crate::context::GpuContext;
use crate::error::GpuError;
use crate::kernels::{Kernel, sources, stage_source};
use crate::stream::DeviceStream;

/// The lineage's kernels, buffers and bind groups.
pub(super) struct Lineage {
    first: Kernel,
    later: Kernel,
    clear: Kernel,
    /// The two lineage buffers: layer l writes `buffers[l % 2]`.
    buffers: [DeviceStream<u32>; 2],
    /// Each target's restart flag (1 after `reset_target`, until the next frame's first layer).
    restarts: DeviceStream<u32>,
    first_group: wgpu::BindGroup,
    /// `later_groups[l % 2]`: layer l reads `buffers[1 - l % 2]` and writes `buffers[l % 2]`.
    later_groups: [wgpu::BindGroup; 2],
    clear_group: wgpu::BindGroup,
}

impl Lineage {
    /// The lineage of `shape`'s particles, composed from `streams`' ancestors; `params` is the
    /// buffer whose `targets` and `particles` the kernels read.
    pub(super) fn new(
        ctx: &GpuContext,
        shape: &BatchShape,
        streams: &Streams,
        params: &wgpu::Buffer,
    ) -> Result<Self, GpuError> {
        let source = stage_source(sources::LINEAGE);
        let first = Kernel::trusted(ctx, "lineage (first layer)", &source, "first_layer")?;
        let later = Kernel::trusted(ctx, "lineage (later layer)", &source, "later_layer")?;
        let clear = Kernel::trusted(ctx, "lineage (clear restarts)", &source, "clear_restarts")?;
        let n = shape.particle_len();
        let buffers = [
            DeviceStream::zeroed(ctx, "lineage (even layers)", n)?,
            DeviceStream::zeroed(ctx, "lineage (odd layers)", n)?,
        ];
        let restarts = DeviceStream::zeroed(ctx, "restarted targets", shape.targets)?;
        let params = || params.as_entire_binding();
        let first_group = first.bind(
            ctx,
            &[
                (0, params()),
                (1, streams.ancestors.binding()),
                (2, restarts.binding()),
                (3, buffers[0].binding()),
            ],
        )?;
        let later_group = |write: usize| {
            later.bind(
                ctx,
                &[
                    (0, params()),
                    (1, streams.ancestors.binding()),
                    (2, buffers[1 - write].binding()),
                    (3, buffers[write].binding()),
                ],
            )
        };
        let later_groups = [later_group(0)?, later_group(1)?];
        let clear_group = clear.bind(ctx, &[(0, params()), (4, restarts.binding())])?;
        Ok(Self {
            first,
            later,
            clear,
            buffers,
            restarts,
            first_group,
            later_groups,
            clear_group,
        })
    }

    /// Records layer `layer`'s composition into `pass` (after the layer's resampling).
    pub(super) fn record(
        &self,
        pass: &mut wgpu::ComputePass<'_>,
        shape: &BatchShape,
        layer: usize,
    ) {
        let per_particle = [groups_for(shape.particles, 64), shape.targets as u32, 1];
        if layer == 0 {
            self.first.record(pass, &self.first_group, per_particle);
            let per_target = [groups_for(shape.targets, 64), 1, 1];
            self.clear.record(pass, &self.clear_group, per_target);
        } else {
            self.later
                .record(pass, &self.later_groups[layer % 2], per_particle);
        }
    }

    /// The lineage's bindings in the fused select that composes it (`layer.wgsl`,
    /// `select_*_keeping_lineage`): layer `layer` reads the buffer the layer before wrote (layer
    /// 0 reads none; it is bound to the other buffer) and writes `buffers[layer % 2]`, as the
    /// dispatches do.
    pub(super) fn select_bindings(&self, layer: usize) -> [(u32, wgpu::BindingResource<'_>); 3] {
        let write = layer % 2;
        [
            (15, self.buffers[1 - write].binding()),
            (16, self.buffers[write].binding()),
            (17, self.restarts.binding()),
        ]
    }

    /// The buffer holding the frame's lineage after `layers` layers.
    pub(super) fn result(&self, layers: usize) -> &DeviceStream<u32> {
        &self.buffers[(layers.max(1) - 1) % 2]
    }

    /// Marks target `t` restarted: the next frame's lineage gives its particles no ancestors.
    pub(super) fn mark_restart(&self, ctx: &GpuContext, t: usize) -> Result<(), GpuError> {
        self.restarts.upload_at(ctx, t, &[1])
    }
}

impl super::GpuFilter {
    /// Keeps each frame's lineage from the next step on: each particle's ancestor among the
    /// previous frame's particles, every layer's resampling composed (in the fused step's select
    /// where the adapter binds its buffers, else a dispatch more per layer; what smoothing from
    /// the ancestry needs, `pf_core::smooth::ancestry`).
    pub fn keep_lineage(&mut self, ctx: &GpuContext) -> Result<(), GpuError> {
        self.forget_prerecorded();
        if self.lineage.is_none() {
            self.lineage = Some(Lineage::new(
                ctx,
                &self.shape,
                &self.streams,
                &self.params_buffer,
            )?);
        }
        if let (Some(fused), Some(lineage)) = (&mut self.fused, &self.lineage) {
            let layers = super::fused::LayerParams {
                buffer: &self.layer_params,
                stride: self.layer_stride,
                count: self.annealing.layers,
            };
            let bindings = |layer| lineage.select_bindings(layer);
            fused.keep_lineage(ctx, &self.shape, &self.streams, &layers, &bindings)?;
        }
        Ok(())
    }

    /// Whether the fused step composes the lineage in each layer's select (`on`, the default
    /// where the adapter binds the select's storage buffers and the lineage's three) or in a
    /// dispatch of its own per layer (`lineage.wgsl`, as the staged step does: the reference).
    /// The same values either way; refused where the adapter cannot bind them, or where the
    /// fused step does not fit this filter.
    pub fn set_lineage_in_select(&mut self, ctx: &GpuContext, on: bool) -> Result<(), GpuError> {
        self.forget_prerecorded();
        match &mut self.fused {
            Some(fused) => fused.set_lineage_in_select(ctx, on),
            None if !on => Ok(()),
            None => Err(GpuError::InvalidConfig(
                "the fused step does not fit this filter: its lineage has dispatches of its own"
                    .into(),
            )),
        }
    }

    /// Whether a step now composes the lineage in the fused select ([`Self::set_lineage_in_select`]):
    /// the filter keeps the lineage and records fused steps with that select.
    pub fn lineage_in_select(&self) -> bool {
        self.lineage.is_some()
            && self.layout == super::StepLayout::Fused
            && self.fused.as_ref().is_some_and(|f| f.composes_lineage())
    }

    /// Whether the filter keeps the lineage ([`Self::keep_lineage`]).
    pub fn keeps_lineage(&self) -> bool {
        self.lineage.is_some()
    }

    /// The last step's lineage, `[t·M + m]` (the twin of `pf_core::batch::BatchFilter::lineage`;
    /// `NO_ANCESTOR` for a target restarted before it and before the first step kept); `None`
    /// when the filter does not keep it.
    pub fn download_lineage(&self, ctx: &GpuContext) -> Result<Option<Vec<u32>>, GpuError> {
        match &self.lineage {
            Some(lineage) => Ok(Some(lineage.result(self.annealing.layers).download(ctx)?)),
            None => Ok(None),
        }
    }

    /// Records layer `layer`'s lineage into `pass` when the filter keeps it.
    pub(super) fn record_lineage(&self, pass: &mut wgpu::ComputePass<'_>, layer: usize) {
        if let Some(lineage) = &self.lineage {
            lineage.record(pass, &self.shape, layer);
        }
    }
}

/// The particles after a step, read back together ([`super::GpuFilter::download_particles`]).
#[derive(Debug, Clone, PartialEq)]
pub struct ParticlesBack {
    /// The states, `[(t·D + d)·M + m]`.
    pub states: Vec<f32>,
    /// The normalised log-weights, `[t·M + m]`.
    pub log_weights: Vec<f32>,
    /// The lineage, `[t·M + m]`, where the filter keeps it.
    pub lineage: Option<Vec<u32>>,
}

impl super::GpuFilter {
    /// The states, log-weights and (where kept) lineage after the last step, in one copy and
    /// one wait (what a smoother reads each frame; three downloads would wait three times).
    pub fn download_particles(&self, ctx: &GpuContext) -> Result<ParticlesBack, GpuError> {
        let n = self.shape.particle_len() as u64;
        let lineage = self
            .lineage
            .as_ref()
            .map(|l| l.result(self.annealing.layers));
        let mut sections = vec![4 * self.shape.state_len() as u64, 4 * n];
        if lineage.is_some() {
            sections.push(4 * n);
        }
        let back = crate::stream::ReadbackSet::new(ctx, "particles readback", &sections)?;
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("particles readback"),
            });
        back.record_copy(&mut encoder, 0, self.streams.states.buffer());
        back.record_copy(&mut encoder, 1, self.streams.log_weights.buffer());
        if let Some(lineage) = lineage {
            back.record_copy(&mut encoder, 2, lineage.buffer());
        }
        let submission = ctx.queue.submit([encoder.finish()]);
        let map = back.request_map();
        ctx.wait(Some(submission), "reading the particles back")?;
        let mut sections = back.collect(map)?.into_iter();
        let mut next = || sections.next().unwrap_or_default();
        Ok(ParticlesBack {
            states: bytemuck::pod_collect_to_vec(&next()),
            log_weights: bytemuck::pod_collect_to_vec(&next()),
            lineage: lineage.map(|_| bytemuck::pod_collect_to_vec(&next())),
        })
    }
}
