//! The plain `#[repr(C)]` mirrors of `shaders/engine/common.wgsl`'s `Params` and `TargetStats`,
//! checked field by field against naga's layout of their WGSL twins.

use bytemuck::{Pod, Zeroable};
use pf_core::PfError;

/// The per-frame parameters, `Params` in `shaders/engine/common.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct FrameParams {
    /// Targets T.
    pub targets: u32,
    /// Particles per target M.
    pub particles: u32,
    /// State dimensions D.
    pub dims: u32,
    /// Bit d set: dimension d is an angle.
    pub angular_mask: u32,
    /// The step index, low 32 bits (the counter of the random streams).
    pub step_lo: u32,
    /// The step index, high 32 bits.
    pub step_hi: u32,
    /// 1: clamp diffused states to the bounds.
    pub has_bounds: u32,
    /// Steps of the Metropolis resampler.
    pub metropolis_steps: u32,
    /// Resample a target when its ESS is below this × M.
    pub ess_threshold: f32,
    /// M′ of the best-M′ estimate (0: none).
    pub best: u32,
    /// This annealing layer's fixed β (used when `survival_rate` is 0).
    pub beta: f32,
    /// > 0: choose β so that ESS = this × M (the survival rule), at most `max_beta`.
    pub survival_rate: f32,
    /// The cap of the survival rule's β.
    pub max_beta: f32,
    /// This layer's diffusion scale (σ_d × it).
    pub sigma_scale: f32,
    /// The constant-velocity gain (0: the random walk alone).
    pub velocity_gain: f32,
    /// The annealing layer (the drift is added in layer 0 only).
    pub layer: u32,
}

/// Per-target results, `TargetStats` in `shaders/engine/common.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, Pod, Zeroable)]
pub struct TargetStats {
    /// The largest log-weight before normalisation.
    pub max_log_weight: f32,
    /// log Σ exp(log w − max).
    pub log_sum_shifted: f32,
    /// The effective sample size.
    pub ess: f32,
    /// 0 ok, 1 every weight zero, 2 NaN log-weight, 3 +inf log-weight.
    pub status: u32,
    /// The first particle with a NaN or +∞ log-weight (`u32::MAX` when none).
    pub bad_particle: u32,
    /// 1 when the target resampled at the start of the step (its last annealing layer).
    pub resampled: u32,
    /// The exponent β of the last layer's weighing (1 without annealing).
    pub beta: f32,
    /// The frame's log evidence, log Σ exp(lw + ℓ) at β = 1 taken in layer 0
    /// (`pf_core::batch::frame_log_evidence`).
    pub log_evidence: f32,
}

impl TargetStats {
    /// A target's statistics before its first step: every weight equal.
    pub fn initial(particles: usize) -> Self {
        Self {
            ess: particles as f32,
            bad_particle: u32::MAX,
            beta: 1.0,
            ..Self::zeroed()
        }
    }

    /// The status as pf-core's typed error.
    pub fn result(&self, particles: usize) -> Result<(), PfError> {
        match self.status {
            0 => Ok(()),
            1 => Err(PfError::AllWeightsZero { particles }),
            2 => Err(PfError::NanLogWeight {
                particle: self.bad_particle as usize,
            }),
            _ => Err(PfError::InfiniteLogWeight {
                particle: self.bad_particle as usize,
            }),
        }
    }
}

#[cfg(test)]
mod layout_tests {
    use std::mem::{offset_of, size_of};

    use super::{FrameParams, TargetStats};
    use crate::kernels::{assert_mirrors_wgsl, sources, stage_source};

    #[test]
    fn frame_params_and_target_stats_mirror_their_wgsl_layouts() {
        macro_rules! fields {
            ($t:ty: $($f:ident),*) => { [$((stringify!($f), offset_of!($t, $f))),*] };
        }
        // common.wgsl reads `params`, which each stage declares: lay it out inside one.
        let common = stage_source(sources::DIFFUSE);
        assert_mirrors_wgsl(
            &common,
            "Params",
            size_of::<FrameParams>(),
            &fields!(FrameParams: targets, particles, dims, angular_mask, step_lo, step_hi,
                has_bounds, metropolis_steps, ess_threshold, best, beta, survival_rate, max_beta,
                sigma_scale, velocity_gain, layer),
        );
        assert_mirrors_wgsl(
            &common,
            "TargetStats",
            size_of::<TargetStats>(),
            &fields!(TargetStats: max_log_weight, log_sum_shifted, ess, status, bad_particle,
                resampled, beta, log_evidence),
        );
    }
}
