//! `face track` with two frames in flight: while the GPU steps frame t + 1, the host reads back
//! frame t and writes its results. Used where nothing between two frames needs the filters:
//! faces from rectangles (no detector starting or restarting tracks), no particles read back
//! (`--save-particles`, `--rerun`), a GPU backend. The results are those of one frame at a
//! time, bit for bit ([`face_tracker::tracker::in_flight`]).

use std::collections::VecDeque;
use std::time::Instant;

use anyhow::Context;
use face_tracker::tracker::in_flight::MAX_FRAMES_IN_FLIGHT;
use face_tracker::{FaceTracker, GrayImage};

use super::super::args::TrackArgs;
use super::super::runner::Runner;
use super::FaceRun;
use crate::run_output;

/// The frames submitted and not yet written, oldest first: each one's index and image (the
/// overlay and the recording draw it when it is written).
pub(super) struct InFlight(VecDeque<(usize, GrayImage)>);

impl InFlight {
    /// Frames in flight for this run, when it allows them (see the module's doc).
    pub(super) fn for_run(runner: &Runner, args: &TrackArgs) -> Option<Self> {
        let allowed = matches!(runner, Runner::Fixed(tracker) if tracker.gpu_context().is_some())
            && args.save_particles.is_none()
            && args.smoothing.mode().is_none()
            && args.rerun.is_none();
        allowed.then(|| Self(VecDeque::with_capacity(MAX_FRAMES_IN_FLIGHT)))
    }
}

/// The tracker of a run with frames in flight (which [`InFlight::for_run`] allows only for
/// faces from rectangles).
fn tracker(runner: &mut Runner) -> anyhow::Result<&mut FaceTracker> {
    match runner {
        Runner::Fixed(tracker) => Ok(tracker),
        Runner::Auto(_) => anyhow::bail!("frames in flight with the detector on"),
    }
}

impl FaceRun<'_> {
    /// Submits frame `frame` and, once two are in flight, finishes and writes the oldest.
    pub(super) fn submit_one(
        &mut self,
        runner: &mut Runner,
        in_flight: &mut InFlight,
        frame: usize,
        image: GrayImage,
        bar: &indicatif::ProgressBar,
    ) -> anyhow::Result<()> {
        let started = Instant::now();
        let submitted = tracker(runner)?.submit(&image);
        self.record.tracking_time += started.elapsed().as_secs_f64();
        submitted.with_context(|| format!("frame {frame}"))?;
        in_flight.0.push_back((frame, image));
        if in_flight.0.len() == MAX_FRAMES_IN_FLIGHT {
            self.finish_oldest(runner, in_flight, bar)?;
        }
        Ok(())
    }

    /// Finishes and writes every frame in flight, oldest first (none after one that fails).
    pub(super) fn finish_in_flight(
        &mut self,
        runner: &mut Runner,
        in_flight: Option<&mut InFlight>,
        bar: &indicatif::ProgressBar,
    ) -> anyhow::Result<()> {
        let Some(in_flight) = in_flight else {
            return Ok(());
        };
        while !in_flight.0.is_empty() {
            self.finish_oldest(runner, in_flight, bar)?;
        }
        Ok(())
    }

    fn finish_oldest(
        &mut self,
        runner: &mut Runner,
        in_flight: &mut InFlight,
        bar: &indicatif::ProgressBar,
    ) -> anyhow::Result<()> {
        let Some((frame, image)) = in_flight.0.pop_front() else {
            return Ok(());
        };
        let mut finish_and_write = || -> anyhow::Result<()> {
            // A device fault (simulated for the tests) shows when a frame is read back.
            run_output::maybe_simulate_gpu_fault(frame, runner.tracker().gpu_context());
            let started = Instant::now();
            let finished = tracker(runner)?.finish();
            self.record.tracking_time += started.elapsed().as_secs_f64();
            self.record.gpu_time += crate::gpu::gpu_seconds(runner.tracker().last_gpu_time());
            let estimates = finished?.context("the frame was not in flight")?;
            self.write_frame(runner, frame, &image, estimates, Vec::new())
        };
        let written = finish_and_write().with_context(|| format!("frame {frame}"));
        match written {
            Ok(()) => self.written(bar),
            // The frames after a failed one are not written: the files would have a gap.
            Err(_) => in_flight.0.clear(),
        }
        written
    }
}
