//! GPU timing: timestamp queries around a recorded step where the adapter has them
//! (`TIMESTAMP_QUERY` + `TIMESTAMP_QUERY_INSIDE_ENCODERS`), the host's wall clock otherwise.

use std::time::Duration;

use crate::context::GpuContext;
use crate::error::GpuError;

/// How long a step took, and how that was measured.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum GpuTime {
    /// Between two GPU timestamps written at the start and the end of the step's commands.
    Timestamps(Duration),
    /// Host wall clock from submission to the end of the readback (includes the round trip).
    WallClock(Duration),
}

impl GpuTime {
    /// The step's duration.
    pub fn duration(&self) -> Duration {
        match *self {
            GpuTime::Timestamps(d) | GpuTime::WallClock(d) => d,
        }
    }

    /// "GPU timestamps" or "wall clock".
    pub fn source(&self) -> &'static str {
        match self {
            GpuTime::Timestamps(_) => "GPU timestamps",
            GpuTime::WallClock(_) => "wall clock",
        }
    }
}

/// Two timestamps around a step, resolved and copied for readback inside the same submission.
pub struct StepTimer {
    query_set: wgpu::QuerySet,
    resolved: wgpu::Buffer,
    period_ns: f64,
}

impl StepTimer {
    /// `None` when the adapter cannot write timestamps inside an encoder.
    pub fn new(ctx: &GpuContext) -> Result<Option<Self>, GpuError> {
        if !ctx.has_timestamps() {
            return Ok(None);
        }
        let (query_set, resolved) = ctx.scoped("creating the timestamp queries", || {
            let query_set = ctx.device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("step timestamps"),
                ty: wgpu::QueryType::Timestamp,
                count: 2,
            });
            let resolved = ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("resolved timestamps"),
                size: 16,
                usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            });
            (query_set, resolved)
        })?;
        Ok(Some(Self {
            query_set,
            resolved,
            period_ns: f64::from(ctx.queue.get_timestamp_period()),
        }))
    }

    /// Records the first timestamp.
    pub fn begin(&self, encoder: &mut wgpu::CommandEncoder) {
        encoder.write_timestamp(&self.query_set, 0);
    }

    /// Writes the end timestamp and resolves both into [`StepTimer::resolved`] (two u64 ticks),
    /// for the caller to copy into its readback.
    pub fn end(&self, encoder: &mut wgpu::CommandEncoder) {
        encoder.write_timestamp(&self.query_set, 1);
        encoder.resolve_query_set(&self.query_set, 0..2, &self.resolved, 0);
    }

    /// The resolved ticks (16 bytes).
    pub fn resolved(&self) -> &wgpu::Buffer {
        &self.resolved
    }

    /// The time between the two resolved ticks.
    pub fn elapsed(&self, ticks: &[u64]) -> Duration {
        let elapsed = match ticks {
            [start, end] => end.saturating_sub(*start) as f64 * self.period_ns,
            _ => 0.0,
        };
        Duration::from_nanos(elapsed as u64)
    }
}
