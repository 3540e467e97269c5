//! What a smoother takes from the face tracker: the dynamics' density, and each tracked face's
//! particles with their lineage (`pf_core::smooth_tracks::TrackSmoother`).

use pf_core::smooth::GaussianTransition;
use pf_core::smooth_tracks::TrackCloud;

use super::{ANGULAR, FaceEstimate, FaceTracker, TrackStatus};
use crate::error::FaceError;
use crate::projection::DIMS;

impl FaceTracker {
    /// The dynamics' density for smoothing (`pf_core::smooth`): the random walk of a whole
    /// frame's annealing layers per state value, the roll the one angle the filter wraps.
    pub fn transition(&self) -> GaussianTransition {
        GaussianTransition {
            sigma: self.config.annealing.frame_sigma(&self.config.diffusion),
            angular: ANGULAR.to_vec(),
        }
    }

    /// The annealing layers of a frame (each resamples).
    pub fn annealing_layers(&self) -> usize {
        self.config.annealing.layers
    }

    /// Keeps each frame's lineage from the next step on (the GPU composes it; the CPU engine
    /// always does): what smoothing with a lag traces back ([`Self::track_clouds`]).
    pub fn keep_lineage(&mut self) -> Result<(), FaceError> {
        for shard in &mut self.shards {
            shard.filter.engine_mut().keep_lineage()?;
        }
        Ok(())
    }

    /// Times each dispatch of the first GPU's fused step from the next step on, or stops
    /// (`pf_gpu::GpuFilter::profile_dispatches`): where a step's GPU time goes.
    pub fn profile_dispatches(&mut self, on: bool) -> Result<(), FaceError> {
        if let Some(shard) = self.shards.first_mut() {
            shard.filter.engine_mut().profile_dispatches(on)?;
        }
        Ok(())
    }

    /// The first GPU's dispatches in the last profiled step, and their times.
    pub fn dispatch_times(&self) -> Result<Vec<pf_gpu::DispatchTime>, FaceError> {
        self.check_nothing_in_flight("the dispatch times are read")?;
        match self.shards.first() {
            Some(shard) => Ok(shard.filter.engine().dispatch_times()?),
            None => Ok(Vec::new()),
        }
    }

    /// Every slot's lineage after the last step, `[slot·M + m]` (each particle's ancestor among
    /// its slot's particles of the frame before); `None` on a GPU that does not keep it.
    pub fn lineage(&self) -> Result<Option<Vec<u32>>, FaceError> {
        self.check_nothing_in_flight("the lineage is read")?;
        let mut joined = Vec::new();
        for shard in &self.shards {
            match shard.filter.engine().lineage()? {
                Some(lineage) => joined.extend(lineage),
                None => return Ok(None),
            }
        }
        Ok(Some(joined))
    }

    /// Each face being tracked among `estimates` (the last step's) with its slot's particles:
    /// the track, its states `[d·M + m]`, normalised log-weights `[m]` and lineage (where kept),
    /// what a smoother takes. On the GPU this reads the particles back.
    pub fn track_clouds(&self, estimates: &[FaceEstimate]) -> Result<Vec<TrackCloud>, FaceError> {
        self.check_nothing_in_flight("the particles are read")?;
        // Every shard's particles and lineage in one readback each; slots follow one another.
        let (mut states, mut log_weights, mut lineage) = (Vec::new(), Vec::new(), Some(Vec::new()));
        let mut particles = 0;
        for shard in &self.shards {
            let (shape, back) = shard.filter.engine().particles_and_lineage()?;
            particles = shape.particles;
            states.extend(back.states);
            log_weights.extend(back.log_weights);
            lineage = match (lineage, back.lineage) {
                (Some(mut all), Some(more)) => {
                    all.extend(more);
                    Some(all)
                }
                _ => None,
            };
        }
        let (m, block) = (particles, DIMS * particles);
        Ok((estimates.iter())
            .filter(|e| e.status == TrackStatus::Tracking)
            .filter_map(|e| {
                let slot = e.slot * m..(e.slot + 1) * m;
                Some(TrackCloud {
                    track: e.track,
                    states: states.get(e.slot * block..(e.slot + 1) * block)?.to_vec(),
                    log_weights: log_weights.get(slot.clone())?.to_vec(),
                    lineage: match &lineage {
                        Some(all) => Some(all.get(slot)?.to_vec()),
                        None => None,
                    },
                })
            })
            .collect())
    }
}
