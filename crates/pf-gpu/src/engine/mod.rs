//! The one filter every model is stepped by, [`Filter`], over a [`Model`] (a model's CPU twin and
//! its GPU side) on either engine ([`FilterEngine`]): the trackers' models, a researcher's WGSL
//! plug-in ([`crate::model::ModelFilter`] is a `Filter` of one) and the CPU-only models alike.
//! Both engines give the same [`EngineReport`], and a target is reset and the particles read the
//! same way.
//!
//! The CPU engine is pf-core's [`BatchFilter`] (the GPU driver's twin, drawing the same random
//! numbers); the GPU engine is [`GpuFilter`] with the context it runs on.

mod filter;
pub mod islands;
mod model;
pub mod sharded;

pub use filter::{Filter, InFlight};
pub use islands::{IslandReport, Islands};
pub use model::Model;
pub use sharded::{Sharded, ShardedPending, shard_ranges};

use pf_core::PfError;
use pf_core::batch::{BatchConfig, BatchFilter, BatchShape, Propagate};
use pf_core::resample::{Resampler, ResamplerKind};
use pf_core::smooth::lag_window::{LagFrame, LaggedSummaries};

use crate::context::GpuContext;
use crate::error::GpuError;
use crate::filter::{
    GpuFilter, GpuResampler, GpuStepReport, LikelihoodInputs, LikelihoodReadbacks, ParticlesBack,
};
use crate::timing::GpuTime;

/// Where a filter runs.
pub enum FilterEngine {
    /// pf-core's batch filter on the host (all cores for the measure).
    Cpu(Box<BatchFilter<Box<dyn Resampler>>>),
    /// The whole step on the GPU.
    Gpu(Box<GpuEngine>),
}

/// The GPU driver and the context it runs on.
pub struct GpuEngine {
    /// The device.
    pub ctx: GpuContext,
    /// The driver.
    pub filter: GpuFilter,
}

impl GpuEngine {
    /// The engine's report of a GPU step.
    fn report(&self, report: GpuStepReport) -> EngineReport {
        let particles = self.filter.shape().particles;
        EngineReport {
            ess: report.stats.iter().map(|s| f64::from(s.ess)).collect(),
            resampled: report.stats.iter().map(|s| s.resampled != 0).collect(),
            beta: report.stats.iter().map(|s| s.beta).collect(),
            log_evidence: (report.stats.iter())
                .map(|s| f64::from(s.log_evidence))
                .collect(),
            status: report.stats.iter().map(|s| s.result(particles)).collect(),
            estimates: report.estimates,
            best_estimates: report.best_estimates,
            spreads: report.spreads,
            gpu_time: Some(report.time),
            likelihood: report.likelihood,
            lagged: report.lagged,
        }
    }
}

/// What one step of either engine reports.
#[derive(Debug, Clone, PartialEq)]
pub struct EngineReport {
    /// The weighted means, `[t·D + d]`.
    pub estimates: Vec<f32>,
    /// The best-M′ weighted means, `[t·D + d]` (empty when the configuration's `best` is 0).
    pub best_estimates: Vec<f32>,
    /// The posterior's spread about the weighted means, `[t·D + d]`: the weighted standard
    /// deviation, circular for angles (`pf_core::batch::weighted_means_and_spreads`).
    pub spreads: Vec<f32>,
    /// Each target's effective sample size after weighing.
    pub ess: Vec<f64>,
    /// Whether each target resampled at the start of the step (of its last annealing layer).
    pub resampled: Vec<bool>,
    /// The exponent each target's last layer weighed with (1 without annealing).
    pub beta: Vec<f32>,
    /// Each target's log evidence of the frame, log p̂(z_t | z_1:t−1) up to the likelihood's
    /// constant (`pf_core::batch::frame_log_evidence`): summed over frames, the log likelihood
    /// of the whole sequence. −∞ when every weight was zero, NaN for a NaN weight.
    pub log_evidence: Vec<f64>,
    /// `Err` for a target whose measurement was degenerate (its weights were left uniform).
    pub status: Vec<Result<(), PfError>>,
    /// The step's GPU time (GPU engine only).
    pub gpu_time: Option<GpuTime>,
    /// What the GPU likelihood asked to read back (empty on the CPU engine).
    pub likelihood: LikelihoodReadbacks,
    /// The frame a lag behind, smoothed from the ancestry on the device, where the GPU engine
    /// keeps a lag window ([`FilterEngine::keep_lag_window`]).
    pub lagged: Option<LaggedSummaries>,
}

impl EngineReport {
    /// The estimates a tracker reports: the best-M′ means where computed, else the means.
    pub fn point_estimates(&self) -> &[f32] {
        if self.best_estimates.is_empty() {
            &self.estimates
        } else {
            &self.best_estimates
        }
    }
}

impl FilterEngine {
    /// The CPU engine over `initial_states` (`[(t·D + d)·M + m]`), resampling with `resampler`.
    pub fn cpu(
        config: &BatchConfig,
        resampler: ResamplerKind,
        initial_states: Vec<f32>,
    ) -> Result<Self, GpuError> {
        Ok(Self::Cpu(Box::new(BatchFilter::new(
            config,
            resampler.build(),
            initial_states,
        )?)))
    }

    /// The GPU engine on `ctx`, resampling with `resampler`.
    pub fn gpu(
        ctx: GpuContext,
        config: &BatchConfig,
        resampler: GpuResampler,
        initial_states: &[f32],
    ) -> Result<Self, GpuError> {
        let filter = GpuFilter::new(&ctx, config, resampler, initial_states)?;
        Ok(Self::Gpu(Box::new(GpuEngine { ctx, filter })))
    }

    /// Targets × particles × dimensions.
    pub fn shape(&self) -> BatchShape {
        match self {
            Self::Cpu(filter) => *filter.shape(),
            Self::Gpu(gpu) => *gpu.filter.shape(),
        }
    }

    /// The GPU context, on the GPU engine.
    pub fn context(&self) -> Option<&GpuContext> {
        match self {
            Self::Cpu(_) => None,
            Self::Gpu(gpu) => Some(&gpu.ctx),
        }
    }

    /// The streams a GPU likelihood binds once (`None` on the CPU engine).
    pub fn likelihood_inputs(&self) -> Option<(&GpuContext, LikelihoodInputs<'_>)> {
        match self {
            Self::Cpu(_) => None,
            Self::Gpu(gpu) => Some((&gpu.ctx, gpu.filter.likelihood_inputs())),
        }
    }

    /// One step on the CPU engine, moving with the model's dynamics when given (else the random
    /// walk) and measuring with `measure(shape, states, out)` (fill
    /// `out[t·M + m]` with log-likelihoods; called once per annealing layer). The measure's own
    /// error is returned as it is.
    fn step_on_cpu<E: From<GpuError>>(
        filter: &mut BatchFilter<Box<dyn Resampler>>,
        propagate: Option<&Propagate<'_>>,
        mut measure: impl FnMut(&BatchShape, &[f32], &mut [f32]) -> Result<(), E>,
    ) -> Result<EngineReport, E> {
        // BatchFilter takes a PfError; keep the measure's own error to return it as is.
        let mut failure = None;
        let report = filter.step_with(propagate, |shape, states, out| {
            measure(shape, states, out).map_err(|e| {
                failure = Some(e);
                PfError::InvalidConfig("the model's measurement failed".into())
            })
        });
        if let Some(e) = failure {
            return Err(e);
        }
        let report = report.map_err(GpuError::from)?;
        Ok(EngineReport {
            estimates: report.estimates,
            best_estimates: report.best_estimates,
            spreads: report.spreads,
            ess: report.ess,
            resampled: report.resampled,
            beta: report.beta,
            log_evidence: report.log_evidence,
            status: report.status,
            gpu_time: None,
            likelihood: LikelihoodReadbacks::default(),
            lagged: None,
        })
    }

    /// Makes this engine's targets targets `first ..` of a larger batch split over several
    /// engines (one per GPU), so that each draws the random numbers it draws in the whole
    /// batch and the parts step as the whole would.
    pub fn number_targets_from(&mut self, first: usize) -> Result<(), GpuError> {
        match self {
            Self::Cpu(filter) => Ok(filter.number_targets_from(first)?),
            Self::Gpu(gpu) => gpu.filter.number_targets_from(&gpu.ctx, first),
        }
    }

    /// Restarts target `t` from `states` (its `D·M` values, `[d·M + m]`) with equal weights.
    pub fn reset_target(&mut self, t: usize, states: &[f32]) -> Result<(), GpuError> {
        match self {
            Self::Cpu(filter) => Ok(filter.reset_target(t, states)?),
            Self::Gpu(gpu) => gpu.filter.reset_target(&gpu.ctx, t, states),
        }
    }

    /// Sets target `t` moving, as if its last two estimates had been `estimate − motion` and
    /// `estimate` (`pf_core::batch::BatchFilter::set_target_motion`).
    pub fn set_target_motion(
        &mut self,
        t: usize,
        estimate: &[f32],
        motion: &[f32],
    ) -> Result<(), GpuError> {
        match self {
            Self::Cpu(filter) => Ok(filter.set_target_motion(t, estimate, motion)?),
            Self::Gpu(gpu) => gpu.filter.set_target_motion(&gpu.ctx, t, estimate, motion),
        }
    }

    /// Keeps each frame's lineage from the next step on (the GPU composes it in a dispatch per
    /// layer; the CPU engine always keeps it).
    pub fn keep_lineage(&mut self) -> Result<(), GpuError> {
        match self {
            Self::Cpu(_) => Ok(()),
            Self::Gpu(gpu) => gpu.filter.keep_lineage(&gpu.ctx),
        }
    }

    /// Smooths from the ancestry on the GPU from the next step on, `lag` frames behind
    /// ([`GpuFilter::keep_lag_window`]: each report's `lagged`). The CPU engine has its particles
    /// on the host, where `pf_core::smooth::lag_window::LagWindow` (the twin) or
    /// `pf_core::smooth_tracks::TrackSmoother` smooths them: refused there.
    pub fn keep_lag_window(&mut self, lag: usize, compare_filtered: bool) -> Result<(), GpuError> {
        match self {
            Self::Cpu(_) => Err(GpuError::InvalidConfig(
                "the CPU engine keeps no lag window on a device: smooth its particles on the host \
                 (pf_core::smooth::lag_window::LagWindow)"
                    .into(),
            )),
            Self::Gpu(gpu) => gpu.filter.keep_lag_window(&gpu.ctx, lag, compare_filtered),
        }
    }

    /// Stops keeping the GPU's lag window ([`GpuFilter::drop_lag_window`]); nothing to drop on
    /// the CPU engine.
    pub fn drop_lag_window(&mut self) -> Result<(), GpuError> {
        match self {
            Self::Cpu(_) => Ok(()),
            Self::Gpu(gpu) => gpu.filter.drop_lag_window(&gpu.ctx),
        }
    }

    /// Target `t`'s frames `first_step ..` (`count` of them) in the GPU's lag window, oldest
    /// first, steps numbered from 1 ([`GpuFilter::download_lag_frames`]); the CPU engine keeps
    /// none.
    pub fn lag_frames(
        &self,
        t: usize,
        first_step: u64,
        count: usize,
    ) -> Result<Vec<LagFrame>, GpuError> {
        match self {
            Self::Cpu(_) => Err(GpuError::InvalidConfig(
                "the CPU engine keeps no lag window".into(),
            )),
            Self::Gpu(gpu) => gpu
                .filter
                .download_lag_frames(&gpu.ctx, t, first_step, count),
        }
    }

    /// Times each dispatch of the GPU's fused step from the next step on, or stops
    /// ([`GpuFilter::profile_dispatches`]); the CPU engine has no dispatches to time.
    pub fn profile_dispatches(&mut self, on: bool) -> Result<(), GpuError> {
        match self {
            Self::Cpu(_) if on => Err(GpuError::InvalidConfig(
                "the CPU engine has no dispatches to profile".into(),
            )),
            Self::Cpu(_) => Ok(()),
            Self::Gpu(gpu) => gpu.filter.profile_dispatches(&gpu.ctx, on),
        }
    }

    /// The last profiled step's dispatches and their times (empty when not profiling).
    pub fn dispatch_times(&self) -> Result<Vec<crate::filter::DispatchTime>, GpuError> {
        match self {
            Self::Cpu(_) => Ok(Vec::new()),
            Self::Gpu(gpu) => gpu.filter.dispatch_times(&gpu.ctx),
        }
    }

    /// The last step's lineage, `[t·M + m]`: each particle's ancestor among the previous frame's
    /// particles (`pf_core::smooth::ancestry`); `None` on a GPU that does not keep it
    /// ([`Self::keep_lineage`]). The GPU engine reads it back (a wait).
    pub fn lineage(&self) -> Result<Option<Vec<u32>>, GpuError> {
        match self {
            Self::Cpu(filter) => Ok(Some(filter.lineage().to_vec())),
            Self::Gpu(gpu) => gpu.filter.download_lineage(&gpu.ctx),
        }
    }

    /// The particles after the last step: the shape, the states (`[(t·D + d)·M + m]`) and the
    /// normalised log-weights (`[t·M + m]`). The GPU engine reads them back (a wait).
    pub fn particles(&self) -> Result<(BatchShape, Vec<f32>, Vec<f32>), GpuError> {
        let (shape, back) = self.particles_and_lineage()?;
        Ok((shape, back.states, back.log_weights))
    }

    /// [`Self::particles`] and [`Self::lineage`] together (on the GPU in one readback and one
    /// wait): the shape, states, log-weights and lineage (`None` where not kept).
    pub fn particles_and_lineage(&self) -> Result<(BatchShape, ParticlesBack), GpuError> {
        Ok(match self {
            Self::Cpu(filter) => (
                *filter.shape(),
                ParticlesBack {
                    states: filter.states.clone(),
                    log_weights: filter.log_weights.clone(),
                    lineage: Some(filter.lineage().to_vec()),
                },
            ),
            Self::Gpu(gpu) => (
                *gpu.filter.shape(),
                gpu.filter.download_particles(&gpu.ctx)?,
            ),
        })
    }
}
