//! Where a fused step's GPU time goes, dispatch by dispatch ([`GpuFilter::profile_dispatches`]):
//! each dispatch of the step gets a compute pass of its own with a timestamp at its beginning and
//! its end, so a step reports every dispatch's time and the gaps between them (the barriers and
//! launches), the lag window's dispatch last where the filter keeps one ("lag window: the step
//! kept", or "lag window: summary and the step kept" once the window is full). The particles
//! are the same as without profiling: only the passes' boundaries move.
//! For measuring, not for tracking: the profiled step pays a pass per dispatch.

use std::time::Duration;

use super::GpuFilter;
use crate::context::GpuContext;
use crate::error::GpuError;
use crate::stream::Readback;

/// The most dispatches a profiled step times (the rest run untimed).
const MAX_TIMED_DISPATCHES: u32 = 128;

/// One dispatch of a profiled step.
#[derive(Debug, Clone, PartialEq)]
pub struct DispatchTime {
    /// What the dispatch does ("layer 2: select", "layer 2: move", "layer 2: likelihood", ...).
    pub label: String,
    /// From the beginning of the step's first timed pass to this pass's beginning.
    pub start: Duration,
    /// From this pass's beginning to its end.
    pub duration: Duration,
}

/// The query set and buffers of a profiled step, and the labels of the last one recorded.
pub(super) struct DispatchProfiler {
    query_set: wgpu::QuerySet,
    resolved: wgpu::Buffer,
    readback: Readback<u64>,
    labels: Vec<String>,
    period_ns: f64,
}

impl DispatchProfiler {
    fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        let count = 2 * MAX_TIMED_DISPATCHES;
        let (query_set, resolved) = ctx.scoped("creating the dispatch profiler", || {
            let query_set = ctx.device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("dispatch timestamps"),
                ty: wgpu::QueryType::Timestamp,
                count,
            });
            let resolved = ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("resolved dispatch timestamps"),
                size: u64::from(count) * 8,
                usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            });
            (query_set, resolved)
        })?;
        Ok(Self {
            query_set,
            resolved,
            readback: Readback::new(ctx, "dispatch timestamps", count as usize)?,
            labels: Vec::new(),
            period_ns: f64::from(ctx.queue.get_timestamp_period()),
        })
    }

    /// Forgets the last profiled step's dispatches (a step that was not fused, or only some
    /// stages, has none to report).
    pub(super) fn forget(&mut self) {
        self.labels.clear();
    }

    /// Records `record` in a compute pass of its own, timed and named `label` (untimed past
    /// [`MAX_TIMED_DISPATCHES`]).
    pub(super) fn dispatch(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        label: impl FnOnce() -> String,
        record: impl FnOnce(&mut wgpu::ComputePass<'_>),
    ) {
        let index = self.labels.len() as u32;
        let timed = index < MAX_TIMED_DISPATCHES;
        let writes = timed.then(|| wgpu::ComputePassTimestampWrites {
            query_set: &self.query_set,
            beginning_of_pass_write_index: Some(2 * index),
            end_of_pass_write_index: Some(2 * index + 1),
        });
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("profiled dispatch"),
            timestamp_writes: writes,
        });
        record(&mut pass);
        drop(pass);
        if timed {
            self.labels.push(label());
        }
    }

    /// Resolves the step's timestamps for reading back, once every timed pass of the step is
    /// recorded.
    pub(super) fn resolve(&mut self, encoder: &mut wgpu::CommandEncoder) {
        let count = 2 * self.labels.len() as u32;
        if count > 0 {
            encoder.resolve_query_set(&self.query_set, 0..count, &self.resolved, 0);
            self.readback.record_raw_copy(encoder, &self.resolved);
        }
    }

    /// The times of the last profiled step's dispatches (waits for the queue).
    fn times(&self, ctx: &GpuContext) -> Result<Vec<DispatchTime>, GpuError> {
        let ticks = self.readback.read(ctx, None)?;
        let first = ticks.first().copied().unwrap_or(0);
        let at = |tick: u64| {
            Duration::from_nanos((tick.saturating_sub(first) as f64 * self.period_ns) as u64)
        };
        Ok(self
            .labels
            .iter()
            .zip(ticks.chunks_exact(2))
            .map(|(label, pair)| DispatchTime {
                label: label.clone(),
                start: at(pair[0]),
                duration: at(pair[1]).saturating_sub(at(pair[0])),
            })
            .collect())
    }
}

/// Where a step's dispatches are recorded: all into one compute pass (a normal step), or each
/// into a pass of its own with timestamps (a profiled one).
pub(super) enum Passes<'e> {
    /// Boxed: a pass is large beside the profiled variant's two references.
    One(Box<wgpu::ComputePass<'e>>),
    Each {
        encoder: &'e mut wgpu::CommandEncoder,
        profiler: &'e mut DispatchProfiler,
    },
}

impl<'e> Passes<'e> {
    /// One pass for the whole step, or a pass per dispatch when `profiler` is given.
    pub(super) fn begin(
        encoder: &'e mut wgpu::CommandEncoder,
        profiler: Option<&'e mut DispatchProfiler>,
        label: &str,
    ) -> Self {
        match profiler {
            Some(profiler) => {
                profiler.labels.clear();
                Passes::Each { encoder, profiler }
            }
            None => Passes::One(Box::new(encoder.begin_compute_pass(
                &wgpu::ComputePassDescriptor {
                    label: Some(label),
                    timestamp_writes: None,
                },
            ))),
        }
    }

    /// Records one dispatch (or a likelihood's phase), named `label` in a profile.
    pub(super) fn dispatch(
        &mut self,
        label: impl FnOnce() -> String,
        record: impl FnOnce(&mut wgpu::ComputePass<'_>),
    ) {
        match self {
            Passes::One(pass) => record(pass),
            Passes::Each { encoder, profiler } => profiler.dispatch(encoder, label, record),
        }
    }
}

impl GpuFilter {
    /// Turns dispatch profiling on or off. While on, each fused step records every dispatch in
    /// a compute pass of its own with timestamps, read by [`Self::dispatch_times`]. Refused where
    /// the adapter has no timestamp queries, or for a staged step (whose stages
    /// [`Self::run_stages`] already times one by one).
    pub fn profile_dispatches(&mut self, ctx: &GpuContext, on: bool) -> Result<(), GpuError> {
        self.forget_prerecorded();
        if !on {
            self.profiler = None;
            return Ok(());
        }
        if !ctx.has_timestamps() {
            return Err(GpuError::InvalidConfig(format!(
                "{} has no timestamp queries: dispatches cannot be profiled",
                ctx.adapter().name
            )));
        }
        if self.fused.is_none() || self.layout != super::StepLayout::Fused {
            return Err(GpuError::InvalidConfig(
                "dispatch profiling times the fused step: set StepLayout::Fused first".into(),
            ));
        }
        self.profiler = Some(DispatchProfiler::new(ctx)?);
        Ok(())
    }

    /// Each dispatch's time in the last profiled step, once that step was finished (steps run
    /// one at a time: refused while a submitted step is in flight, whose timestamps would
    /// overwrite these). Empty when profiling is off (setting a staged layout turns it off).
    pub fn dispatch_times(&self, ctx: &GpuContext) -> Result<Vec<DispatchTime>, GpuError> {
        if self.in_flight > 0 {
            return Err(GpuError::InvalidConfig(
                "a submitted step is in flight: finish it before reading the dispatch times".into(),
            ));
        }
        match &self.profiler {
            Some(profiler) => profiler.times(ctx),
            None => Ok(Vec::new()),
        }
    }
}
