//! What a smoother takes from the body tracker on a lag: each frame's lineage, and, on one GPU,
//! the lag window kept there (`pf_gpu::GpuFilter::keep_lag_window`), whose summaries come back
//! with each step so that no sample is read back (`pf_core::smooth_tracks::LaggedTracks`).

use pf_core::smooth::lag_window::{LagFrame, LaggedSummaries};

use super::BodyTracker;
use crate::error::BodyError;

impl BodyTracker {
    /// Keeps each frame's lineage from the next step on (what smoothing with a lag traces back;
    /// the GPU composes it, the CPU engine always does).
    pub fn keep_lineage(&mut self) -> Result<(), BodyError> {
        for filter in &mut self.filters {
            filter.engine_mut().keep_lineage()?;
        }
        Ok(())
    }

    /// The last step's lineage, `[j]` (each sample's ancestor among the frame before's); `None`
    /// where it is not kept, or with several islands (particles move between them).
    pub fn lineage(&self) -> Result<Option<Vec<u32>>, BodyError> {
        if !self.in_flight.is_empty() {
            return Err(BodyError::InvalidInput(
                "the lineage of a finished frame: frames are still in flight".into(),
            ));
        }
        match self.filters.as_slice() {
            [filter] => Ok(filter.engine().lineage()?),
            _ => Ok(None),
        }
    }

    /// Smooths the pose `lag` frames behind on the GPU from the next step on, with each lagged
    /// frame's filtered summary too when `compare_filtered` ([`Self::lagged`]). Refused on the
    /// CPU engine (whose samples are on the host), with several islands (which trade samples
    /// and keep no ancestry) and while frames are in flight.
    pub fn keep_lag_window(&mut self, lag: usize, compare_filtered: bool) -> Result<(), BodyError> {
        if !self.in_flight.is_empty() {
            return Err(BodyError::InvalidInput(
                "a lag window while frames are in flight: finish them first".into(),
            ));
        }
        match self.filters.as_mut_slice() {
            [filter] => Ok(filter.engine_mut().keep_lag_window(lag, compare_filtered)?),
            _ => Err(BodyError::InvalidInput(
                "islands over several GPUs trade samples and keep no ancestry to smooth on".into(),
            )),
        }
    }

    /// The last frame's pose a lag behind, smoothed on the GPU (one target, the body); `None`
    /// without a lag window or before it filled.
    pub fn lagged(&self) -> Option<&LaggedSummaries> {
        self.last_lagged.as_ref()
    }

    /// Frames `first_step ..` (`count` of them, oldest first) of the GPU's lag window, steps
    /// numbered from 1, the first step after [`Self::keep_lag_window`].
    pub fn lag_frames(&self, first_step: u64, count: usize) -> Result<Vec<LagFrame>, BodyError> {
        if !self.in_flight.is_empty() {
            return Err(BodyError::InvalidInput(
                "the lag window of a finished frame: frames are still in flight".into(),
            ));
        }
        match self.filters.as_slice() {
            [filter] => Ok(filter.engine().lag_frames(0, first_step, count)?),
            _ => Err(BodyError::InvalidInput(
                "several islands keep no lag window".into(),
            )),
        }
    }
}
