//! When the detector looks, and what a scene cut does: every `detect_every`-th frame, a cut's
//! first frame, and a shot's (or the video's) first frames one after another; at a cut the
//! running tracks wait for the detector to find their faces again, and those it does not end.

use std::sync::Arc;

use super::{AutoFrame, AutoTracker};
use crate::error::FaceError;
use crate::image::GrayImage;
use crate::scene_cut::PendingCut;

impl AutoTracker {
    /// Ends the tracks of a pending cut that a detection of `frame_index` (the cut's first
    /// frame or later) did not find again.
    pub(super) fn end_unfound_after_cut(
        &mut self,
        frame_index: usize,
        found: &[usize],
        out: &mut AutoFrame,
    ) -> Result<(), FaceError> {
        let Some(cut) = self.pending_cut.take_if(|cut| frame_index >= cut.frame) else {
            return Ok(());
        };
        for (track, _) in cut.unconfirmed {
            if !found.contains(&track) && self.tracker.is_running(track) {
                self.tracker.end_track(track)?;
                out.ended.push(track);
                self.ended_at_cuts += 1;
            }
        }
        Ok(())
    }

    /// Whether `frame` starts a new shot; if so, the running tracks wait for the detector to
    /// find their faces again, and the untracked candidates of the last shot are dropped.
    pub(super) fn look_for_cut(&mut self, frame: &GrayImage) -> bool {
        if !self.cuts.as_mut().is_some_and(|cuts| cuts.is_cut(frame)) {
            return false;
        }
        self.pending_cut = Some(PendingCut {
            frame: self.frame_index,
            sent: false,
            unconfirmed: self.tracked.iter().map(|t| (t.track, t.rect)).collect(),
        });
        self.candidates.clear();
        self.lost.clear();
        self.cuts_seen.push(self.frame_index);
        self.shot_start = self.frame_index;
        true
    }

    /// Whether this frame goes to the detector: its period, a cut's frame not yet sent, or one
    /// of the first frames of the video or of a shot. A shot's faces are all new: its first
    /// [`AutoConfig::confirmations`] frames go to the detector one after another, so that they
    /// are confirmed a frame after they are first seen instead of a period later (Megamind.avi's
    /// shots started their tracks 6–11 frames after the cut).
    pub(super) fn detect_now(&self) -> bool {
        self.frame_index.is_multiple_of(self.config.detect_every)
            || self.pending_cut.as_ref().is_some_and(|cut| !cut.sent)
            || self.frame_index < self.shot_start + self.config.confirmations
    }

    /// Hands this frame to the detector (a pending cut's frame is then sent).
    pub(super) fn send(&mut self, frame: &GrayImage) -> Result<(), FaceError> {
        self.detector
            .send(self.frame_index, Arc::new(frame.clone()))?;
        if let Some(cut) = &mut self.pending_cut {
            cut.sent = true;
        }
        Ok(())
    }
}
