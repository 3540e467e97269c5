//! Recording the next step while the GPU runs this one. A lone step (one submitted with none in
//! flight, then waited for: the benchmarks', Python's and the CLI's single steps) used to spend
//! as much host time before its GPU work began as the GPU then took for one face: the frame's
//! upload, recording the dispatches, and wgpu encoding them at the encoder's `finish`
//! (docs/BENCHMARKS.md, "Where a lone step's host time goes"). The commands of a whole step read
//! everything that changes from step to step (the layers' parameters, the frame) from buffers,
//! so after submitting a lone step the filter records and encodes the next one while the GPU is
//! busy, and the next step only writes its parameters and submits.
//!
//! A prerecorded step is used only if nothing it recorded has changed since: the filter drops it
//! in every method that changes its own recording (`forget_prerecorded`), and keeps it only for
//! the same likelihood in the same state ([`GpuLikelihood::recording_id`]; a likelihood without
//! one is recorded anew every step) and the same staging set. Not prerecorded: steps with a lag
//! window (its dispatches follow the frame's place in the window) or with profiled dispatches.
//! Stepping with and without prerecording gives the same particles, bit for bit
//! (`tests/prerecorded_step.rs`).

use super::{GpuFilter, GpuLikelihood, GpuStage, RecordingId, STEP_BACK_TICKS};
use crate::context::GpuContext;

/// A whole step's commands, recorded and encoded ahead.
pub(super) struct Prerecorded {
    commands: wgpu::CommandBuffer,
    /// The likelihood's recording it holds.
    likelihood: RecordingId,
    /// The staging set it copies its results into.
    back: usize,
}

/// The filter's prerecording: whether it prerecords, the step it holds, and how many steps were
/// submitted from one.
pub(super) struct Prerecording {
    enabled: bool,
    next: Option<Prerecorded>,
    used: u64,
}

impl Default for Prerecording {
    fn default() -> Self {
        Self {
            enabled: true,
            next: None,
            used: 0,
        }
    }
}

impl GpuFilter {
    /// Whether a lone whole step records the next one while the GPU runs it (on by default).
    /// Off, every step is recorded when it is submitted; the particles are the same either way.
    pub fn set_prerecording(&mut self, on: bool) {
        self.prerecording.enabled = on;
        self.forget_prerecorded();
    }

    /// How many steps were submitted from commands recorded a step ahead.
    pub fn prerecorded_steps(&self) -> u64 {
        self.prerecording.used
    }

    /// Drops the step recorded ahead: called by every method that changes what a step records.
    pub(super) fn forget_prerecorded(&mut self) {
        self.prerecording.next = None;
    }

    /// The commands recorded ahead for this step, if they still hold: a whole step, the same
    /// likelihood in the same state, the staging set it is due to copy into. Whatever was held
    /// is dropped either way.
    pub(super) fn take_prerecorded(
        &mut self,
        stages: &[GpuStage],
        likelihood: &dyn GpuLikelihood,
    ) -> Option<wgpu::CommandBuffer> {
        let held = self.prerecording.next.take()?;
        let whole_step = GpuStage::ALL.iter().all(|s| stages.contains(s));
        let holds = whole_step
            && held.back == self.next_back
            && likelihood.recording_id() == Some(held.likelihood);
        holds.then(|| {
            self.prerecording.used += 1;
            held.commands
        })
    }

    /// Records and encodes the next whole step's commands, to be submitted by the next
    /// [`GpuFilter::submit_stages`] (`take_prerecorded`). Called right after a step was
    /// submitted with none before it in flight, so this runs while the GPU works. An error in
    /// recording is not reported here: the step is then recorded anew, and reports it.
    pub(super) fn prerecord_next(&mut self, ctx: &GpuContext, likelihood: &dyn GpuLikelihood) {
        self.forget_prerecorded();
        let Some(id) = likelihood.recording_id() else {
            return;
        };
        if !self.prerecording.enabled || self.lag_window.is_some() || self.profiler.is_some() {
            return;
        }
        let back = self.next_back;
        let encoded = ctx.scoped("recording the next filter step ahead", || {
            self.encode_commands(ctx, &GpuStage::ALL, likelihood).0
        });
        if let Ok(commands) = encoded {
            self.prerecording.next = Some(Prerecorded {
                commands,
                likelihood: id,
                back,
            });
        }
    }

    /// A step's commands (without its parameters: [`GpuFilter::write_layer_params`]) between the
    /// step timer's timestamps, copied into the staging set due next, encoded. Also returns
    /// whether the step summarises a lagged frame.
    pub(super) fn encode_commands(
        &mut self,
        ctx: &GpuContext,
        stages: &[GpuStage],
        likelihood: &dyn GpuLikelihood,
    ) -> (wgpu::CommandBuffer, bool) {
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("filter step"),
            });
        if let Some(timer) = &self.timer {
            timer.begin(&mut encoder);
        }
        let lagged = self.record_commands(ctx, &mut encoder, stages, likelihood);
        if let Some(timer) = &self.timer {
            timer.end(&mut encoder);
            self.step_backs[self.next_back].record_copy(
                &mut encoder,
                STEP_BACK_TICKS,
                timer.resolved(),
            );
        }
        (encoder.finish(), lagged)
    }
}
