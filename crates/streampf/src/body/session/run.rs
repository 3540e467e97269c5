//! The frame loop of a body run (`BodyRun`): stepping, writing, skipping, finishing.

use super::super::args::TrackArgs;
use super::super::overlay::BodyOverlay;
use super::super::record::{BodyFiles, csv_row};
use crate::recording::{BodyFrame, Recording};
use crate::run_output::{self, CsvStream, SkipLog};
use anyhow::Context;
use body_tracker::sequence::joint_row;
use body_tracker::skeleton::ROOT_DOFS;
use body_tracker::{BodyTracker, FrameResult, PreparedFrame, Skeleton, mean_joint_error};
use nalgebra::Vector3;
use std::collections::VecDeque;
use std::path::Path;
use std::time::Instant;

/// What a body run has tracked so far.
pub(super) struct BodyRun {
    /// Frames finished and written (tracked or skipped).
    pub(super) frames: usize,
    pub(super) errors: Vec<f32>,
    /// Pose values (frames × values, with ground truth) whose true value lay within ±2 reported
    /// standard deviations of the estimate, and how many were checked.
    pub(super) within_two_sd: usize,
    pub(super) values_checked: usize,
    pub(super) skipped: SkipLog,
    pub(super) points_seen: usize,
    /// Seconds in the tracker's calls, and the GPU's own seconds for the frames: with frames in
    /// flight the GPU works while the host waits for the next frame, so the tracker's time is
    /// the longer of the two.
    pub(super) tracking_time: f64,
    pub(super) gpu_time: f64,
    /// Whether the frames were tracked with two in flight.
    pub(super) frames_in_flight: bool,
    /// `--smooth` / `--smooth-lag`: smoothed.csv.
    pub(super) smoothing: Option<super::smoothed::BodySmoothing>,
}

impl BodyRun {
    pub(super) fn new(
        out: &Path,
        smoothing: Option<super::smoothed::BodySmoothing>,
    ) -> anyhow::Result<Self> {
        Ok(Self {
            frames: 0,
            errors: Vec::new(),
            within_two_sd: 0,
            values_checked: 0,
            skipped: SkipLog::new(out)?,
            points_seen: 0,
            tracking_time: 0.0,
            gpu_time: 0.0,
            frames_in_flight: false,
            smoothing,
        })
    }

    #[allow(clippy::too_many_arguments)]
    pub(super) fn track_one(
        &mut self,
        save_particles: Option<&Path>,
        (overlay, recording): (Option<&mut BodyOverlay>, Option<&Recording>),
        tracker: &mut BodyTracker,
        skeleton: &Skeleton,
        files: &mut BodyFiles,
        frame: usize,
        (points, prepared): (&[Vector3<f32>], &PreparedFrame),
        truth: Option<&[Vec<f32>]>,
    ) -> anyhow::Result<()> {
        run_output::maybe_simulate_gpu_fault(frame, tracker.gpu_context());
        let step_started = Instant::now();
        let result = tracker.step_prepared(prepared)?;
        self.tracking_time += step_started.elapsed().as_secs_f64();
        self.gpu_time += crate::gpu::gpu_seconds(tracker.last_gpu_time());
        let outputs = (save_particles, (overlay, recording));
        self.write_frame(
            outputs, tracker, skeleton, files, frame, points, result, truth,
        )
    }

    /// Finishes the oldest of the frames in flight and writes it (see [`track`]).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn finish_oldest(
        &mut self,
        in_flight: &mut VecDeque<(usize, Vec<Vector3<f32>>)>,
        overlay: Option<&mut BodyOverlay>,
        tracker: &mut BodyTracker,
        skeleton: &Skeleton,
        files: &mut BodyFiles,
        resume_from: usize,
        truth: Option<&[Vec<f32>]>,
    ) -> anyhow::Result<()> {
        let Some((frame, points)) = in_flight.pop_front() else {
            return Ok(());
        };
        let finish_and_write = || -> anyhow::Result<()> {
            // A device fault (simulated for the tests) shows when a frame is read back.
            run_output::maybe_simulate_gpu_fault(frame, tracker.gpu_context());
            let started = Instant::now();
            let finished = tracker.finish();
            self.tracking_time += started.elapsed().as_secs_f64();
            self.gpu_time += crate::gpu::gpu_seconds(tracker.last_gpu_time());
            let result = finished?.context("the frame was not in flight")?;
            let overlay = overlay.filter(|_| frame >= resume_from);
            let outputs = (None, (overlay, None));
            self.write_frame(
                outputs, tracker, skeleton, files, frame, &points, result, truth,
            )
        };
        let written = finish_and_write().with_context(|| format!("frame {frame}"));
        if written.is_err() {
            // The frames after a failed one are not written: the files would have a gap.
            in_flight.clear();
        }
        written
    }

    /// Finishes and writes every frame in flight, oldest first (none after one that fails).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn finish_in_flight(
        &mut self,
        in_flight: &mut VecDeque<(usize, Vec<Vector3<f32>>)>,
        mut overlay: Option<&mut BodyOverlay>,
        tracker: &mut BodyTracker,
        skeleton: &Skeleton,
        files: &mut BodyFiles,
        resume_from: usize,
        truth: Option<&[Vec<f32>]>,
    ) -> anyhow::Result<()> {
        while !in_flight.is_empty() {
            self.finish_oldest(
                in_flight,
                overlay.as_deref_mut(),
                tracker,
                skeleton,
                files,
                resume_from,
                truth,
            )?;
        }
        Ok(())
    }

    /// Writes a tracked frame's results: the CSV rows, and the particles, the recording and the
    /// overlay when asked for.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn write_frame(
        &mut self,
        (save_particles, (overlay, recording)): (
            Option<&Path>,
            (Option<&mut BodyOverlay>, Option<&Recording>),
        ),
        tracker: &mut BodyTracker,
        skeleton: &Skeleton,
        files: &mut BodyFiles,
        frame: usize,
        points: &[Vector3<f32>],
        result: FrameResult,
        truth: Option<&[Vec<f32>]>,
    ) -> anyhow::Result<()> {
        if let Some(dir) = save_particles {
            let (shape, states, log_weights) = tracker.particles()?;
            pf_numpy::write_particles(dir, frame, &shape, &states, &log_weights)
                .context("--save-particles")?;
        }
        self.points_seen += result.points;
        let mut pose_row = result.pose.clone();
        pose_row.extend(&result.spread);
        pose_row.extend([
            result.ess as f32,
            result.log_evidence as f32,
            result.confidence,
        ]);
        files.poses.row(&csv_row(frame, &pose_row))?;
        let joints = joint_row(&skeleton.tracked_joint_positions(&result.pose)?);
        files.joints.row(&csv_row(frame, &joints))?;
        let mut joint_error = None;
        if let (Some(truth), Some(out)) = (truth, files.errors.as_mut()) {
            let error = mean_joint_error(skeleton, &result.pose, &truth[frame])?;
            joint_error = Some(error);
            out.row(&csv_row(frame, &[error]))?;
        }
        if let Some(recording) = recording {
            let (shape, states, _) = tracker.particles()?;
            let shown = BodyFrame {
                frame,
                points,
                pose: &result.pose,
                truth: truth.map(|t| t[frame].as_slice()),
                ess: result.ess,
                confidence: result.confidence,
                joint_error,
                samples: Some((&states, shape.particles)),
            };
            recording.body_frame(skeleton, shown).context("--rerun")?;
        }
        if let Some(overlay) = overlay {
            let truth = truth.map(|t| t[frame].as_slice());
            overlay.draw(frame, skeleton, points, &result.pose, truth)?;
        }
        match files.errors.as_mut() {
            Some(errors) => {
                CsvStream::end_frame_in_all(&mut [&mut files.poses, &mut files.joints, errors])?
            }
            None => CsvStream::end_frame_in_all(&mut [&mut files.poses, &mut files.joints])?,
        }
        if let Some(smoothing) = self.smoothing.as_mut() {
            smoothing.add(frame, tracker, truth).context("--smooth")?;
        }
        // Counted once the frame is in the files (a frame that failed to write is dropped).
        if let (Some(truth), Some(error)) = (truth, joint_error) {
            self.errors.push(error);
            self.count_coverage(&result.pose, &result.spread, &truth[frame]);
        }
        self.frames += 1;
        Ok(())
    }

    /// Counts the pose values whose truth lies within ±2 reported sd (the root's rotations, the
    /// filter's angles, wrapped).
    pub(super) fn count_coverage(&mut self, pose: &[f32], spread: &[f32], truth: &[f32]) {
        for (d, ((&estimate, &sd), &true_value)) in pose.iter().zip(spread).zip(truth).enumerate() {
            let mut miss = estimate - true_value;
            if (3..ROOT_DOFS).contains(&d) {
                miss = pf_core::batch::wrap_angle_floor(miss);
            }
            self.within_two_sd += usize::from(miss.abs() <= 2.0 * sd);
            self.values_checked += 1;
        }
    }

    /// A frame that cannot be read: a warning and a row in skipped.csv; the filter is not
    /// stepped (the pose holds), and poses.csv has no row for the frame.
    pub(super) fn skip_one(&mut self, frame: usize, error: anyhow::Error) -> anyhow::Result<()> {
        self.skipped.record(frame, &error)?;
        self.frames += 1;
        Ok(())
    }

    /// `written`: whether the run ended well (a stopped one says what it wrote in its error).
    pub(super) fn summary(&self, args: &TrackArgs, elapsed: f64, written: bool) {
        let tracked = self.frames - self.skipped.frames.len();
        outln!(
            "tracked {tracked} frames ({:.0} points a frame) in {elapsed:.2} s: {:.1} frames/s in the tracker{}{}",
            self.points_seen as f64 / tracked.max(1) as f64,
            tracked as f64 / self.tracking_time.max(self.gpu_time).max(1e-9),
            if self.frames_in_flight {
                " (two frames in flight)"
            } else {
                ""
            },
            self.skipped.note(),
        );
        if !self.errors.is_empty() {
            let mean =
                self.errors.iter().map(|&e| f64::from(e)).sum::<f64>() / self.errors.len() as f64;
            outln!(
                "mean joint position error: {mean:.4} m over {} frames",
                self.errors.len()
            );
            outln!(
                "truth within ±2 reported sd: {:.0}% of the pose values (about 95% for an honest spread)",
                100.0 * self.within_two_sd as f64 / self.values_checked.max(1) as f64
            );
        }
        if !written {
            return;
        }
        outln!(
            "wrote poses.csv, joints.csv{}{} to {}",
            if self.errors.is_empty() {
                ""
            } else {
                ", errors.csv"
            },
            if self.skipped.frames.is_empty() {
                ""
            } else {
                ", skipped.csv"
            },
            args.out.display()
        );
        if let Some(path) = &args.overlay {
            outln!("drew the frames to {}", path.display());
        }
    }
}
