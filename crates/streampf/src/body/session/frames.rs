//! The frame loop of `body track`: frames read and prepared on a thread of their own, stepped
//! one at a time or two in flight, written as they finish, skipped when unreadable.

use std::collections::VecDeque;

use anyhow::Context;
use body_tracker::{BodyTracker, PreparedFrame, Skeleton};
use nalgebra::Vector3;

use super::super::MAX_BODY_FRAMES_IN_FLIGHT;
use super::super::args::TrackArgs;
use super::super::inputs::Source;
use super::super::overlay::BodyOverlay;
use super::super::record::BodyFiles;
use super::LoopEnd;
use super::run::BodyRun;
use crate::recording::Recording;
use crate::run_output;

/// A frame's points and what the tracker prepared of them, or why they could not be read.
type ReadFrame = anyhow::Result<(Vec<Vector3<f32>>, PreparedFrame)>;

/// What the frame loop steps, and where it writes.
pub(super) struct FrameLoop<'a> {
    pub(super) args: &'a TrackArgs,
    pub(super) skeleton: &'a Skeleton,
    pub(super) tracker: &'a mut BodyTracker,
    pub(super) run: &'a mut BodyRun,
    pub(super) files: &'a mut BodyFiles,
    pub(super) overlay: Option<&'a mut BodyOverlay>,
    pub(super) recording: Option<&'a Recording>,
    pub(super) truth: Option<&'a [Vec<f32>]>,
    /// Frames before it are tracked again but not written (`--resume`).
    pub(super) resume_from: usize,
    /// A generated sequence: a frame that fails is a bug or a bad setting, not one to skip.
    pub(super) synthetic: bool,
    /// Two frames in flight on the GPU.
    pub(super) streaming: bool,
    pub(super) in_flight: VecDeque<(usize, Vec<Vector3<f32>>)>,
}

impl FrameLoop<'_> {
    /// Tracks `frames` frames of `source`, the first already read; how the loop ended.
    pub(super) fn run(
        mut self,
        source: &Source,
        frames: usize,
        first_points: Vec<Vector3<f32>>,
        bar: &indicatif::ProgressBar,
    ) -> LoopEnd {
        let mut end = LoopEnd::Done;
        // Frames in flight: the next frames are read (or rendered) and prepared for the tracker
        // (their rays, and on a GPU their order and cones) on a thread of their own, up to two
        // ahead of the tracker, in order, so that the host's share of a frame overlaps the GPU's.
        let preparer = self.tracker.preparer();
        let prepare = |points: anyhow::Result<Vec<Vector3<f32>>>| -> ReadFrame {
            points.and_then(|points| {
                let prepared = preparer.prepare(&points)?;
                Ok((points, prepared))
            })
        };
        let first = prepare(Ok(first_points));
        let skeleton = self.skeleton;
        std::thread::scope(|scope| {
            let (send, frames_ahead) = std::sync::mpsc::sync_channel(2);
            let prepare = &prepare;
            scope.spawn(move || {
                for frame in 1..frames {
                    // A closed channel: the loop below stopped early.
                    if send.send(prepare(source.points(skeleton, frame))).is_err() {
                        break;
                    }
                }
            });
            let mut first = Some(first);
            for frame in 0..frames {
                let points = first.take().unwrap_or_else(|| {
                    frames_ahead.recv().unwrap_or_else(|_| {
                        Err(anyhow::anyhow!(
                            "the frame reader thread stopped unexpectedly"
                        ))
                    })
                });
                if let Err(e) = self.step(frame, points) {
                    end = LoopEnd::Failed(e);
                    break;
                }
                if let Some(error) = self.run.errors.last() {
                    bar.set_message(format!("joint error {:.1} cm", 100.0 * error));
                }
                bar.set_position(self.run.frames as u64);
                if run_output::stop_requested() {
                    end = LoopEnd::Interrupted;
                    break;
                }
            }
            // The frames still in flight are finished and written however the loop ended (after
            // a frame that failed to finish, none are left): a failure loses only what cannot be
            // finished.
            if let (Err(e), LoopEnd::Done | LoopEnd::Interrupted) = (self.finish_in_flight(), &end)
            {
                end = LoopEnd::Failed(e);
            }
            // Dropping the receiver ends the reader at its next frame.
            drop(frames_ahead);
        });
        end
    }

    /// Steps frame `frame`, writes what it can, or skips it when it could not be read.
    fn step(&mut self, frame: usize, read: ReadFrame) -> anyhow::Result<()> {
        match read {
            // Each error names its frame (with frames in flight, the one that failed).
            Ok((points, prepared)) if self.streaming => self.submit(frame, points, prepared),
            Ok((points, prepared)) => {
                let resumed = frame >= self.resume_from;
                let save = self.args.save_particles.as_deref().filter(|_| resumed);
                let overlay = self.overlay.as_deref_mut().filter(|_| resumed);
                self.run
                    .track_one(
                        save,
                        (overlay, self.recording),
                        self.tracker,
                        self.skeleton,
                        self.files,
                        frame,
                        (&points, &prepared),
                        self.truth,
                    )
                    .map_err(|e| e.context(format!("frame {frame}")))
            }
            Err(e) if self.args.strict => Err(e
                .context("unreadable frame (--strict)")
                .context(format!("frame {frame}"))),
            Err(e) if self.synthetic => Err(e.context(format!("frame {frame}"))),
            Err(e) => {
                self.finish_in_flight()?;
                self.run
                    .skip_one(frame, e)
                    .and_then(|()| match self.overlay.as_deref_mut() {
                        Some(overlay) => overlay.skip(frame),
                        None => Ok(()),
                    })
                    .map_err(|e| e.context(format!("frame {frame}")))
            }
        }
    }

    /// Submits a frame; with two in flight, finishes and writes the older.
    fn submit(
        &mut self,
        frame: usize,
        points: Vec<Vector3<f32>>,
        prepared: PreparedFrame,
    ) -> anyhow::Result<()> {
        self.tracker
            .submit_prepared(prepared)
            .with_context(|| format!("frame {frame}"))?;
        self.in_flight.push_back((frame, points));
        if self.in_flight.len() < MAX_BODY_FRAMES_IN_FLIGHT {
            return Ok(());
        }
        self.run.finish_oldest(
            &mut self.in_flight,
            self.overlay.as_deref_mut(),
            self.tracker,
            self.skeleton,
            self.files,
            self.resume_from,
            self.truth,
        )
    }

    /// Finishes and writes every frame in flight, oldest first.
    fn finish_in_flight(&mut self) -> anyhow::Result<()> {
        self.run.finish_in_flight(
            &mut self.in_flight,
            self.overlay.as_deref_mut(),
            self.tracker,
            self.skeleton,
            self.files,
            self.resume_from,
            self.truth,
        )
    }
}
