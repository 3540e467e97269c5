//! Writes to one target of a running filter between steps: a restart in a slot another target
//! left (`reset_target`), and the motion of a target restarted on something already seen moving
//! (`set_target_motion`). Queued before the next step's submission; the other targets are
//! untouched. CPU twins: `pf_core::batch::BatchFilter::reset_target` and `set_target_motion`.

use super::GpuFilter;
use super::params::TargetStats;
use crate::context::GpuContext;
use crate::error::GpuError;

impl GpuFilter {
    /// Restarts target `t` from `states` (its `D·M` values, `[d·M + m]`) with equal weights and
    /// fresh statistics: a new track in a slot another target left. The writes are queued before
    /// the next step's submission; the other targets are untouched.
    pub fn reset_target(&self, ctx: &GpuContext, t: usize, states: &[f32]) -> Result<(), GpuError> {
        let shape = self.shape;
        if t >= shape.targets {
            return Err(GpuError::InvalidConfig(format!(
                "target {t} of a batch of {}",
                shape.targets
            )));
        }
        let block = shape.dims * shape.particles;
        if states.len() != block {
            return Err(GpuError::LengthMismatch {
                what: "a target's states".into(),
                expected: block,
                got: states.len(),
            });
        }
        let m = shape.particles;
        if let Some(lineage) = &self.lineage {
            lineage.mark_restart(ctx, t)?;
        }
        self.streams.states.upload_at(ctx, t * block, states)?;
        self.streams
            .log_weights
            .upload_at(ctx, t * m, &vec![-(m as f32).ln(); m])?;
        self.streams
            .weights
            .upload_at(ctx, t * m, &vec![1.0 / m as f32; m])?;
        let d = shape.dims;
        self.streams.velocity.upload_at(ctx, t * d, &vec![0.0; d])?;
        self.streams
            .previous_estimates
            .upload_at(ctx, t * d, &vec![f32::NAN; d])?;
        self.streams
            .stats
            .upload_at(ctx, t, &[TargetStats::initial(m)])
    }

    /// Sets target `t` moving, as if its last two estimates had been `estimate − motion` and
    /// `estimate` (NaN in `estimate`: no earlier estimate of that value): the twin of
    /// `pf_core::batch::BatchFilter::set_target_motion` (queued before the next step's
    /// submission, like `reset_target`).
    pub fn set_target_motion(
        &self,
        ctx: &GpuContext,
        t: usize,
        estimate: &[f32],
        motion: &[f32],
    ) -> Result<(), GpuError> {
        pf_core::batch::check_target_motion(&self.shape, t, estimate, motion)?;
        let gain = self.params.velocity_gain;
        if gain <= 0.0 {
            return Ok(());
        }
        let d = self.shape.dims;
        let angular: Vec<bool> = (0..d)
            .map(|k| self.params.angular_mask & (1 << k) != 0)
            .collect();
        let drift = pf_core::batch::motion_drift(gain, &angular, motion);
        self.streams.velocity.upload_at(ctx, t * d, &drift)?;
        self.streams
            .previous_estimates
            .upload_at(ctx, t * d, estimate)
    }
}
