//! Fixed-lag smoothing from the ancestry on the GPU ([`super::GpuFilter::keep_lag_window`]): the
//! filter keeps its last frames' particles, normalised log-weights and lineages in a ring on the
//! device, and after each step `shaders/engine/lag_summary.wgsl` summarises the frame `lag` steps
//! back by the newest frame's weights traced through the lineages. Only the summaries (a mean
//! and a 95 % interval per value and target) come back, in the step's own readback: reading
//! every particle back each frame for the host to trace added 40 % (4 faces) to 146 % (64 faces)
//! to a step that keeps the lineage (docs/POSTERIOR.md).
//!
//! A whole step ends with the window's one dispatch, in the step's own compute pass where the
//! step is fused: it summarises the lagged frame (once the window is full), reading the newest
//! frame from the step's own buffers, and keeps the step's particles, log-weights and lineage in
//! the ring. (Three buffer copies before, each a transfer between the step's pass and the
//! summary's, then a dispatch of their own before the summary's, which cost 6 µs and a barrier's
//! wait on an NVIDIA H200.)
//!
//! The ring holds `lag + 2` frames: the lag window, and one more, so that a host one step behind
//! the device (a step whose results it never took, a failure between the two) can still read
//! the frames of its own window back ([`super::GpuFilter::download_lag_frames`] addresses them by
//! step number): what it needs for a track that ends or restarts inside its window, which the
//! trace from the newest frame cannot reach.
//!
//! CPU twin: `pf_core::smooth::lag_window::LagWindow` (`ancestry::trace_back`, then
//! `summarise`), which gives the same [`LaggedSummaries`].

use bytemuck::{Pod, Zeroable};
use pf_core::batch::BatchShape;
use pf_core::smooth::Summary;
use pf_core::smooth::lag_window::{LagFrame, LaggedSummaries, LaggedTarget};

use super::GpuFilter;
use super::profile::Passes;
use crate::context::GpuContext;
use crate::error::GpuError;
use crate::kernels::{Kernel, sources, stage_source};
use crate::stream::DeviceStream;

/// `LagParams` of `lag_params.wgsl` (read by the summary kernel).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct LagParams {
    slots: u32,
    newest: u32,
    lag: u32,
    filtered: u32,
    summarise: u32,
    pad: [u32; 3],
}

/// The line of `lag_summary.wgsl` the driver sizes to the filter's particles.
const SORT_SIZE_LINE: &str = "const SORT_SIZE: u32 = 4096u;";

/// The kernel's sort size for `particles` a target: a power of two, at least its workgroup.
fn sort_size(particles: usize) -> usize {
    particles.next_power_of_two().max(256)
}

/// Workgroup memory the kernel needs for `particles` a target: values, weights and ancestors
/// (or traced weights) at the sort's size, the reductions' and the scan's partial sums (two
/// floats and a vec4 an invocation) and five flags.
fn workgroup_bytes(particles: usize) -> u64 {
    3 * 4 * sort_size(particles) as u64 + 256 * (2 * 4 + 16) + 5 * 4
}

/// The lag window's dispatch as a profiled step names it: summarising (once the window is full)
/// and keeping the step, or only keeping it.
const LAG_SUMMARY_LABEL: &str = "lag window: summary and the step kept";
/// See [`LAG_SUMMARY_LABEL`].
const LAG_KEEP_LABEL: &str = "lag window: the step kept";

/// The storage buffers `lag_summary.wgsl` binds: the ring's three, the summaries, the kept
/// shares, and the step's particles, log-weights and lineage.
const LAG_STORAGE_BUFFERS: u32 = 8;

/// Floats the kernel writes per target and value: smoothed and filtered mean, lower, upper.
const SUMMARY_FLOATS: usize = 6;

/// The lag window's ring on the device, its kernel and what it has recorded.
pub(super) struct LagWindow {
    lag: usize,
    slots: usize,
    compare_filtered: bool,
    states: DeviceStream<f32>,
    log_weights: DeviceStream<f32>,
    lineage: DeviceStream<u32>,
    summaries: DeviceStream<f32>,
    kept: DeviceStream<f32>,
    params: wgpu::Buffer,
    kernel: Kernel,
    /// The kernel's bindings for each of the lineage's two buffers (which holds a frame's
    /// lineage depends on the layers' parity: `Lineage::result`); set by
    /// [`GpuFilter::keep_lag_window`] once the lineage is kept.
    groups: Vec<wgpu::BindGroup>,
    /// Frames copied into the ring so far.
    recorded: u64,
}

/// What a whole step records for the lag window ([`GpuFilter::prepare_lag_step`]): which of
/// the kernel's bindings reads its lineage, and whether it summarises a lagged frame.
#[derive(Debug, Clone, Copy)]
pub(super) struct LagStep {
    group: usize,
    summarises: bool,
}

impl LagWindow {
    fn new(
        ctx: &GpuContext,
        shape: &BatchShape,
        lag: usize,
        compare_filtered: bool,
    ) -> Result<Self, GpuError> {
        check_fits(ctx.limits(), shape, lag)?;
        let slots = lag + 2;
        let source = stage_source(sources::LAG_SUMMARY);
        if !source.contains(SORT_SIZE_LINE) {
            return Err(GpuError::Shader {
                kernel: "lag summary".into(),
                message: format!("lag_summary.wgsl has no line `{SORT_SIZE_LINE}` to size"),
            });
        }
        let source = source.replace(
            SORT_SIZE_LINE,
            &format!("const SORT_SIZE: u32 = {}u;", sort_size(shape.particles)),
        );
        let kernel = Kernel::trusted(ctx, "lag summary", &source, "summarise_lagged")?;
        let states = DeviceStream::zeroed(ctx, "lag window states", slots * shape.state_len())?;
        let log_weights =
            DeviceStream::zeroed(ctx, "lag window log-weights", slots * shape.particle_len())?;
        let lineage =
            DeviceStream::zeroed(ctx, "lag window lineage", slots * shape.particle_len())?;
        let summaries = DeviceStream::zeroed(
            ctx,
            "lag summaries",
            shape.targets * shape.dims * SUMMARY_FLOATS,
        )?;
        let kept = DeviceStream::zeroed(ctx, "lag window kept share", shape.targets)?;
        let params = crate::stream::uniform_buffer(
            ctx,
            "lag window params",
            &LagParams {
                slots: slots as u32,
                newest: 0,
                lag: lag as u32,
                filtered: u32::from(compare_filtered),
                summarise: 0,
                pad: [0; 3],
            },
        )?;
        Ok(Self {
            lag,
            slots,
            compare_filtered,
            states,
            log_weights,
            lineage,
            summaries,
            kept,
            params,
            kernel,
            groups: Vec::new(),
            recorded: 0,
        })
    }

    /// The kernel's bindings: the frame's parameters, the ring, the summaries, and the step's
    /// particles, log-weights and each of `lineage_buffers`.
    fn bind(
        &mut self,
        ctx: &GpuContext,
        frame_params: &wgpu::Buffer,
        streams: &super::Streams,
        lineage_buffers: [&DeviceStream<u32>; 2],
    ) -> Result<(), GpuError> {
        self.groups = lineage_buffers
            .iter()
            .map(|lineage| {
                self.kernel.bind(
                    ctx,
                    &[
                        (0, frame_params.as_entire_binding()),
                        (1, self.params.as_entire_binding()),
                        (2, self.states.binding()),
                        (3, self.log_weights.binding()),
                        (4, self.lineage.binding()),
                        (5, self.summaries.binding()),
                        (6, self.kept.binding()),
                        (7, streams.states.binding()),
                        (8, streams.log_weights.binding()),
                        (9, lineage.binding()),
                    ],
                )
            })
            .collect::<Result<_, _>>()?;
        Ok(())
    }

    /// The byte lengths of the step readback's sections for the summaries and the kept shares.
    pub(super) fn readback_sections(&self) -> [u64; 2] {
        [4 * self.summaries.len() as u64, 4 * self.kept.len() as u64]
    }
}

/// Why a lag window of `lag` frames cannot run on an adapter of these limits for `shape`.
fn check_fits(limits: &wgpu::Limits, shape: &BatchShape, lag: usize) -> Result<(), GpuError> {
    if lag == 0 || lag > MAX_LAG {
        return Err(GpuError::InvalidConfig(format!(
            "a lag window of {lag} frames: the lag is 1 to {MAX_LAG}"
        )));
    }
    if shape.particles > MAX_LAG_PARTICLES {
        return Err(GpuError::InvalidConfig(format!(
            "summarising a lag window takes at most {MAX_LAG_PARTICLES} particles a target, not {} \
             (smooth on the host instead)",
            shape.particles
        )));
    }
    if limits.max_storage_buffers_per_shader_stage < LAG_STORAGE_BUFFERS {
        return Err(GpuError::InvalidConfig(format!(
            "summarising a lag window binds {LAG_STORAGE_BUFFERS} storage buffers; the adapter \
             binds at most {} a stage (smooth on the host instead)",
            limits.max_storage_buffers_per_shader_stage
        )));
    }
    let bytes = workgroup_bytes(shape.particles);
    if bytes > u64::from(limits.max_compute_workgroup_storage_size) {
        return Err(GpuError::InvalidConfig(format!(
            "summarising a lag window of {} particles a target needs {bytes} bytes of workgroup \
             memory; the adapter has {} (smooth on the host instead)",
            shape.particles, limits.max_compute_workgroup_storage_size
        )));
    }
    let ring = (lag as u64 + 2) * shape.state_len() as u64 * 4;
    if ring > limits.max_storage_buffer_binding_size {
        return Err(GpuError::InvalidConfig(format!(
            "a lag window of {lag} frames holds {ring} bytes of states; the adapter binds at most {}",
            limits.max_storage_buffer_binding_size
        )));
    }
    Ok(())
}

/// The most particles a target's lag window is summarised for on the device: the kernel's
/// invocations take at most `MAX_CHUNK` (16) consecutive particles each, 256 a workgroup.
pub const MAX_LAG_PARTICLES: usize = 16 * 256;

/// The longest lag a window keeps on the device.
pub const MAX_LAG: usize = 256;

impl GpuFilter {
    /// Smooths from the ancestry on the device from the next step on: each step's report then
    /// carries the frame `lag` steps back summarised ([`GpuStepReport::lagged`]), once `lag + 1`
    /// frames have been stepped, with the filtered summary of the same particles beside it when
    /// `compare_filtered`. Keeps the lineage. Refused while steps are in flight, for a lag of 0
    /// or above [`MAX_LAG`], or where the adapter's workgroup memory cannot hold a target.
    ///
    /// [`GpuStepReport::lagged`]: super::GpuStepReport::lagged
    pub fn keep_lag_window(
        &mut self,
        ctx: &GpuContext,
        lag: usize,
        compare_filtered: bool,
    ) -> Result<(), GpuError> {
        if self.in_flight > 0 {
            return Err(GpuError::InvalidConfig(
                "a lag window while a filter step is in flight: finish it first".into(),
            ));
        }
        self.forget_prerecorded();
        // Built before the lineage is kept, so that a window the adapter refuses leaves none.
        let mut window = LagWindow::new(ctx, &self.shape, lag, compare_filtered)?;
        self.keep_lineage(ctx)?;
        let lineage = self.lineage.as_ref().ok_or_else(|| {
            GpuError::InvalidConfig("the lag window needs the lineage, which is not kept".into())
        })?;
        let buffers = [lineage.result(1), lineage.result(2)];
        window.bind(ctx, &self.params_buffer, &self.streams, buffers)?;
        self.lag_sections = window.readback_sections().to_vec();
        self.lag_window = Some(window);
        self.refit_step_backs(ctx)
    }

    /// Stops keeping the lag window from the next step on (its frames are dropped; the lineage
    /// stays kept). Refused while a step is in flight. A tracker whose later GPU refuses a
    /// window takes it back from the earlier ones, so that no GPU summarises for nothing.
    pub fn drop_lag_window(&mut self, ctx: &GpuContext) -> Result<(), GpuError> {
        self.forget_prerecorded();
        if self.in_flight > 0 {
            return Err(GpuError::InvalidConfig(
                "dropping the lag window while a filter step is in flight: finish it first".into(),
            ));
        }
        if self.lag_window.take().is_some() {
            self.lag_sections.clear();
            self.refit_step_backs(ctx)?;
        }
        Ok(())
    }

    /// The lag of the window the filter keeps ([`Self::keep_lag_window`]).
    pub fn lag_window(&self) -> Option<usize> {
        self.lag_window.as_ref().map(|w| w.lag)
    }

    /// Readies the lag window for a whole step about to be recorded: its ring slot and whether
    /// it summarises (written to the window's parameters), counted as recorded. `None` without
    /// a window.
    pub(super) fn prepare_lag_step(&mut self, ctx: &GpuContext) -> Option<LagStep> {
        let layers = self.annealing.layers;
        let window = self.lag_window.as_mut()?;
        let slot = (window.recorded % window.slots as u64) as u32;
        window.recorded += 1;
        let summarises = window.recorded > window.lag as u64;
        let params = LagParams {
            slots: window.slots as u32,
            newest: slot,
            lag: window.lag as u32,
            filtered: u32::from(window.compare_filtered),
            summarise: u32::from(summarises),
            pad: [0; 3],
        };
        ctx.queue
            .write_buffer(&window.params, 0, bytemuck::bytes_of(&params));
        Some(LagStep {
            group: (layers.max(1) - 1) % 2,
            summarises,
        })
    }

    /// Records the lag window's dispatch at the end of a whole step, into the step's passes:
    /// (once the window is full) the summary of its first frame, and the step kept in the ring.
    pub(super) fn record_lag_dispatches(&self, passes: &mut Passes<'_>, step: LagStep) {
        let Some(window) = &self.lag_window else {
            return;
        };
        let (targets, dims) = (self.shape.targets as u32, self.shape.dims as u32);
        let label = if step.summarises {
            LAG_SUMMARY_LABEL
        } else {
            LAG_KEEP_LABEL
        };
        passes.dispatch(
            || label.into(),
            // A workgroup a value and target, and one more a target for its kept share (and its
            // log-weights and lineage kept).
            |pass| {
                window
                    .kernel
                    .record(pass, &window.groups[step.group], [dims + 1, targets, 1])
            },
        );
    }

    /// Copies a summarising step's summaries into its staging buffer; whether it summarises.
    pub(super) fn record_lag_readback(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        step: LagStep,
    ) -> bool {
        let Some(window) = self.lag_window.as_ref().filter(|_| step.summarises) else {
            return false;
        };
        let first_section = self.lag_section_index();
        let back = &self.step_backs[self.next_back];
        back.record_copy(encoder, first_section, window.summaries.buffer());
        back.record_copy(encoder, first_section + 1, window.kept.buffer());
        true
    }

    /// The index of the lag window's first section in the step readback (after the filter's own
    /// and the likelihood's).
    pub(super) fn lag_section_index(&self) -> usize {
        super::STEP_BACK_OWN + self.likelihood_sections.len()
    }

    /// The lag window's summaries from a step's readback sections.
    pub(super) fn lagged_from(&self, sections: &[Vec<u8>]) -> Option<LaggedSummaries> {
        let window = self.lag_window.as_ref()?;
        let first = self.lag_section_index();
        let floats: Vec<f32> = bytemuck::pod_collect_to_vec(sections.get(first)?);
        let kept: Vec<f32> = bytemuck::pod_collect_to_vec(sections.get(first + 1)?);
        let dims = self.shape.dims;
        if floats.len() < self.shape.targets * dims * SUMMARY_FLOATS {
            return None;
        }
        let summary = |at: usize| Summary {
            mean: floats[at],
            lower: floats[at + 1],
            upper: floats[at + 2],
        };
        let targets = (0..self.shape.targets)
            .map(|t| {
                let share = kept.get(t).copied().unwrap_or(f32::NAN);
                if share.is_nan() {
                    return None;
                }
                let at = |d: usize| (t * dims + d) * SUMMARY_FLOATS;
                Some(LaggedTarget {
                    smoothed: (0..dims).map(|d| summary(at(d))).collect(),
                    filtered: if window.compare_filtered {
                        (0..dims).map(|d| summary(at(d) + 3)).collect()
                    } else {
                        Vec::new()
                    },
                    kept: share,
                })
            })
            .collect();
        Some(LaggedSummaries {
            lag: window.lag,
            targets,
        })
    }

    /// How many frames the lag window has recorded: the step number of the newest (steps are
    /// numbered from 1, the first step after [`Self::keep_lag_window`]).
    pub fn lag_steps_recorded(&self) -> Option<u64> {
        self.lag_window.as_ref().map(|w| w.recorded)
    }

    /// Target `t`'s frames `first_step ..` (`count` of them, oldest first) from the lag window's
    /// ring, steps numbered from 1 as [`Self::lag_steps_recorded`] counts them: what the host needs
    /// to smooth a target that ended or restarted within its window. The ring keeps the last
    /// `lag + 2` steps; call it with no step in flight. Copies only those frames of that target,
    /// in one readback.
    pub fn download_lag_frames(
        &self,
        ctx: &GpuContext,
        t: usize,
        first_step: u64,
        count: usize,
    ) -> Result<Vec<LagFrame>, GpuError> {
        let window = self.lag_window.as_ref().ok_or_else(|| {
            GpuError::InvalidConfig("the filter keeps no lag window (keep_lag_window)".into())
        })?;
        if self.in_flight > 0 {
            return Err(GpuError::InvalidConfig(
                "reading the lag window while a step is in flight: finish it first".into(),
            ));
        }
        // Saturating: a count of 0 or a step 0 is refused below, not wrapped.
        let last_step = first_step.saturating_add(count as u64).saturating_sub(1);
        let oldest = window
            .recorded
            .saturating_sub(window.slots as u64 - 1)
            .max(1);
        if t >= self.shape.targets
            || count == 0
            || first_step < oldest
            || last_step > window.recorded
        {
            return Err(GpuError::InvalidConfig(format!(
                "steps {first_step} to {last_step} of target {t}: the window holds steps \
                 {oldest} to {} of {} targets",
                window.recorded, self.shape.targets
            )));
        }
        let (m, block) = (self.shape.particles, self.shape.dims * self.shape.particles);
        let (state_bytes, particle_bytes) = (4 * block as u64, 4 * m as u64);
        let sections: Vec<u64> = (0..count)
            .flat_map(|_| [state_bytes, particle_bytes, particle_bytes])
            .collect();
        let back = crate::stream::ReadbackSet::new(ctx, "lag window readback", &sections)?;
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("lag window readback"),
            });
        for k in 0..count {
            let slot = ((first_step - 1 + k as u64) % window.slots as u64) as usize;
            let target = (slot * self.shape.targets + t) as u64;
            back.record_copy_from(
                &mut encoder,
                3 * k,
                window.states.buffer(),
                target * state_bytes,
            );
            let at = target * particle_bytes;
            back.record_copy_from(&mut encoder, 3 * k + 1, window.log_weights.buffer(), at);
            back.record_copy_from(&mut encoder, 3 * k + 2, window.lineage.buffer(), at);
        }
        let submission = ctx.queue.submit([encoder.finish()]);
        let map = back.request_map();
        ctx.wait(Some(submission), "reading the lag window back")?;
        let sections = back.collect(map)?;
        Ok((sections.chunks(3))
            .map(|frame| LagFrame {
                states: bytemuck::pod_collect_to_vec(&frame[0]),
                log_weights: bytemuck::pod_collect_to_vec(&frame[1]),
                lineage: bytemuck::pod_collect_to_vec(&frame[2]),
            })
            .collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shape(particles: usize) -> BatchShape {
        BatchShape::new(4, particles, 7).unwrap()
    }

    fn refusal(limits: &wgpu::Limits, particles: usize, lag: usize) -> String {
        match check_fits(limits, &shape(particles), lag) {
            Err(GpuError::InvalidConfig(why)) => why,
            other => panic!("expected a refusal, got {other:?}"),
        }
    }

    /// A desktop adapter's limits: WebGPU's defaults with 32 KiB of workgroup memory (WebGPU's
    /// default of 16 KiB holds the summary of fewer than 1 000 particles).
    fn desktop() -> wgpu::Limits {
        wgpu::Limits {
            max_compute_workgroup_storage_size: 32 * 1024,
            ..wgpu::Limits::default()
        }
    }

    #[test]
    fn a_window_fits_a_desktop_adapter() {
        assert!(check_fits(&desktop(), &shape(1000), 8).is_ok());
        assert!(check_fits(&desktop(), &shape(2048), MAX_LAG).is_ok());
    }

    #[test]
    fn an_adapter_of_too_few_storage_buffers_is_refused_by_name() {
        // The downlevel limits bind four storage buffers a stage; the summary binds eight.
        let limits = wgpu::Limits {
            max_storage_buffers_per_shader_stage: wgpu::Limits::downlevel_defaults()
                .max_storage_buffers_per_shader_stage,
            ..desktop()
        };
        assert!(limits.max_storage_buffers_per_shader_stage < LAG_STORAGE_BUFFERS);
        let why = refusal(&limits, 1000, 8);
        assert!(why.contains("storage buffers"), "{why}");
        assert!(
            why.contains(&limits.max_storage_buffers_per_shader_stage.to_string()),
            "{why}"
        );
    }

    #[test]
    fn every_other_limit_is_refused_with_its_reason() {
        let limits = desktop();
        assert!(refusal(&limits, 1000, 0).contains("the lag is 1 to"));
        assert!(refusal(&limits, 1000, MAX_LAG + 1).contains("the lag is 1 to"));
        assert!(refusal(&limits, MAX_LAG_PARTICLES + 1, 8).contains("particles a target"));
        let small_memory = wgpu::Limits {
            max_compute_workgroup_storage_size: 1024,
            ..desktop()
        };
        assert!(refusal(&small_memory, 1000, 8).contains("workgroup memory"));
        let small_binding = wgpu::Limits {
            max_storage_buffer_binding_size: 1 << 16,
            ..desktop()
        };
        assert!(refusal(&small_binding, 1000, 8).contains("bytes of states"));
    }
}
