//! Smoothing a lag behind on the GPU: every shard keeps its last frames on its device and
//! summarises each slot's frame a lag back after each step (`pf_gpu::GpuFilter::keep_lag_window`),
//! so that no particle is read back; `pf_core::smooth_tracks::LaggedTracks` turns the slots'
//! summaries into the tracks' rows, reading a slot's frames back only when its track ends or
//! restarts within the window ([`FaceTracker::lag_frames`]).

use pf_core::smooth::lag_window::{LagFrame, LaggedSummaries};
use pf_core::smooth_tracks::SlotTrack;

use super::shards::ShardStep;
use super::{FaceEstimate, FaceTracker, TrackStatus};
use crate::error::FaceError;

impl FaceTracker {
    /// Smooths every slot `lag` frames behind on its GPU from the next step on, with each
    /// lagged frame's filtered summary too when `compare_filtered` ([`Self::lagged`]). Refused
    /// on the CPU engine (whose particles are on the host: smooth them with
    /// `pf_core::smooth_tracks::TrackSmoother`) and while frames are in flight. A GPU that
    /// refuses it leaves no window on any GPU (one kept before included: the run smooths on the
    /// host), the refusal's error returned; the lineage stays kept.
    pub fn keep_lag_window(&mut self, lag: usize, compare_filtered: bool) -> Result<(), FaceError> {
        self.check_nothing_in_flight("a lag window is kept")?;
        for k in 0..self.shards.len() {
            let kept = (self.shards[k].filter.engine_mut()).keep_lag_window(lag, compare_filtered);
            if let Err(refused) = kept {
                // Every other GPU would summarise each step for a window the run cannot join.
                // A GPU that cannot drop its window is lost: the refusal says more.
                for shard in &mut self.shards {
                    let _ = shard.filter.engine_mut().drop_lag_window();
                }
                return Err(refused.into());
            }
        }
        Ok(())
    }

    /// The last step's slots a lag behind, smoothed on the GPUs (slots in order); `None` without
    /// a lag window, before it filled, or where a GPU did not summarise.
    pub fn lagged(&self) -> Option<&LaggedSummaries> {
        self.last_lagged.as_ref()
    }

    /// The faces being tracked among `estimates` (the last step's) as a lag smoother takes them:
    /// each one's slot, track, and whether its particles were started before this frame.
    pub fn slot_tracks(&self, estimates: &[FaceEstimate]) -> Vec<SlotTrack> {
        let stepped = self.frame_index.saturating_sub(1);
        (estimates.iter())
            .filter(|e| e.status == TrackStatus::Tracking)
            .map(|e| SlotTrack {
                slot: e.slot,
                track: e.track,
                restarted: (self.slots.get(e.slot).and_then(Option::as_ref))
                    .is_none_or(|t| t.started_before >= stepped),
            })
            .collect()
    }

    /// Slot `slot`'s frames `first_step ..` (`count` of them, oldest first) from its GPU's lag
    /// window, steps numbered from 1, the first step after [`Self::keep_lag_window`].
    pub fn lag_frames(
        &self,
        slot: usize,
        first_step: u64,
        count: usize,
    ) -> Result<Vec<LagFrame>, FaceError> {
        self.check_nothing_in_flight("the lag window is read")?;
        let shard = (self.shards.iter().find(|s| s.holds(slot)))
            .ok_or_else(|| FaceError::InvalidInput(format!("slot {slot} is in no shard")))?;
        Ok(shard
            .filter
            .engine()
            .lag_frames(slot - shard.first_slot, first_step, count)?)
    }
}

/// The shards' lagged summaries as one batch, slots in order, where every shard has them.
pub(super) fn joined(steps: &[ShardStep]) -> Option<LaggedSummaries> {
    let mut targets = Vec::new();
    let mut lag = 0;
    for step in steps {
        let part = step.lagged.as_ref()?;
        lag = part.lag;
        targets.extend(part.targets.iter().cloned());
    }
    Some(LaggedSummaries { lag, targets })
}
