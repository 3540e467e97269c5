//! Frames in flight: [`FaceTracker::submit`] hands a frame to the GPUs without waiting, and
//! [`FaceTracker::finish`] waits for the oldest and returns its estimates. With two frames
//! submitted, each GPU works on the next frame while the host reads back the last one and
//! uploads the one after, so a stream's rate is bounded by the GPUs' work instead of by each
//! frame's round trip.
//!
//! The results are those of [`FaceTracker::step`], frame by frame and bit for bit: faces are
//! independent filters, and nothing that changes a filter (starting or restarting a face) is
//! allowed while frames are in flight. A track lost at frame t is still stepped with frame t+1
//! when that was submitted before t finished; its slot's results for t+1 are not reported, as
//! they are not after a lost track in one-at-a-time stepping. On the CPU engine a submitted frame
//! is kept and stepped when it is finished.

use pf_gpu::engine::InFlight;

use super::shards::FrameRef;
use super::{FaceEstimate, FaceTracker};
use crate::error::FaceError;
use crate::image::GrayImage;

/// The most frames in flight at once: the GPU filter has two sets of staging buffers.
pub const MAX_FRAMES_IN_FLIGHT: usize = 2;

/// A frame submitted and not yet finished.
pub(crate) enum FrameInFlight {
    /// Each shard's step, submitted to its GPU, in shard order; and the frame's size.
    Submitted {
        steps: Vec<InFlight>,
        size: (u32, u32),
    },
    /// On the CPU engine: the frame, stepped when it is finished.
    Held(GrayImage),
}

impl FaceTracker {
    /// Submits one frame for every running track without waiting for its results;
    /// [`FaceTracker::finish`] returns them, frames in the order they were submitted. At most
    /// [`MAX_FRAMES_IN_FLIGHT`] frames may be in flight, and while any is, faces cannot be
    /// started or restarted, nor a frame stepped with [`FaceTracker::step`]: finish them first.
    pub fn submit(&mut self, frame: &GrayImage) -> Result<(), FaceError> {
        if self.in_flight.len() >= MAX_FRAMES_IN_FLIGHT {
            return Err(FaceError::InvalidInput(format!(
                "{MAX_FRAMES_IN_FLIGHT} frames are in flight already: finish one first"
            )));
        }
        let size = (frame.width, frame.height);
        self.check_size(size)?;
        let mut steps = Vec::with_capacity(self.shards.len());
        for shard in 0..self.shards.len() {
            match self.shards[shard].submit(FrameRef::Image(frame)) {
                Ok(Some(step)) => steps.push(step),
                // The CPU engine (always the only shard) steps the frame when it is finished.
                Ok(None) => {
                    self.in_flight.push_back(FrameInFlight::Held(frame.clone()));
                    return Ok(());
                }
                Err(e) => {
                    // Wait for the shards already submitted, so that each GPU filter is left
                    // with nothing in flight and the tracker with no half-submitted frame.
                    for (shard, step) in self.shards.iter_mut().zip(steps) {
                        let _ = shard.finish(step);
                    }
                    return Err(e);
                }
            }
        }
        self.in_flight
            .push_back(FrameInFlight::Submitted { steps, size });
        Ok(())
    }

    /// The estimates of the oldest frame in flight, after waiting for it (those
    /// [`FaceTracker::step`] would have returned for it); `None` when no frame is in flight.
    pub fn finish(&mut self) -> Result<Option<Vec<FaceEstimate>>, FaceError> {
        let Some(frame) = self.in_flight.pop_front() else {
            return Ok(None);
        };
        match frame {
            FrameInFlight::Held(image) => self.step_now(FrameRef::Image(&image)).map(Some),
            FrameInFlight::Submitted { steps, size } => {
                // Every shard is waited for even when one fails, so that no GPU filter is left
                // with a step in flight.
                let finished: Vec<_> = (self.shards.iter_mut())
                    .zip(steps)
                    .map(|(shard, step)| shard.finish(step))
                    .collect();
                let steps = finished.into_iter().collect::<Result<Vec<_>, _>>()?;
                Ok(Some(self.conclude(steps, size)))
            }
        }
    }

    /// Frames submitted and not yet finished.
    pub fn frames_in_flight(&self) -> usize {
        self.in_flight.len()
    }

    /// An error naming `what` while frames are in flight.
    pub(crate) fn check_nothing_in_flight(&self, what: &str) -> Result<(), FaceError> {
        if self.in_flight.is_empty() {
            return Ok(());
        }
        Err(FaceError::InvalidInput(format!(
            "{} frames are in flight: finish them before {what}",
            self.in_flight.len()
        )))
    }
}
