//! The GPU filter driver: a frame's whole step — resample → gather → diffuse → likelihood →
//! normalise (once per annealing layer) → estimate — for T targets × M particles, recorded into
//! one command submission. The host uploads nothing but the per-frame parameters (and what the
//! likelihood needs) and reads back only the estimates, spreads and per-target statistics.
//!
//! CPU twin: `pf_core::batch::BatchFilter` (same layout, same counter-based random numbers).

use pf_core::ResamplerKind;
use pf_core::anneal::Annealing;
use pf_core::batch::{BatchConfig, BatchShape};

mod fused;
mod gathering;
mod lag_window;
mod layer_bindings;
mod likelihood;
mod lineage;
mod params;
mod prerecord;
mod profile;
mod record;
mod setup;
mod targets;

pub use fused::{
    FUSED_DEFAULT_MAX_VALUES, StepLayout, fused_layout_refusal, fused_workgroup_bytes,
};
pub use likelihood::{
    GpuLikelihood, LikelihoodInputs, LikelihoodPhase, LikelihoodReadbacks, NoLikelihood,
    ReadbackSource, RecordingId,
};
pub use params::{FrameParams, TargetStats};
pub use profile::DispatchTime;

pub use lag_window::{MAX_LAG, MAX_LAG_PARTICLES};
pub use lineage::ParticlesBack;
pub use pf_core::smooth::lag_window::{LagFrame, LaggedSummaries, LaggedTarget};
pub use setup::FilterStreams;
use setup::{
    BindGroups, Dispatch, Stages, Streams, check_fits, groups_for, layer_params_buffer,
    resample_dispatches, uniform_buffer,
};

use crate::context::GpuContext;
use crate::error::GpuError;
use crate::stream::ReadbackSet;
use crate::timing::{GpuTime, StepTimer};

/// The resamplers that run on the GPU.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GpuResampler {
    /// A prefix sum and one uniform for M evenly spaced points.
    Systematic,
    /// A prefix sum and one uniform per stratum.
    Stratified,
    /// Metropolis with this many steps.
    Metropolis(u32),
}

impl GpuResampler {
    /// The schemes of `pf_core::ResamplerKind` that the GPU runs: the one list that the command
    /// line, Python and the figures read.
    pub const KINDS: [ResamplerKind; 3] = [
        ResamplerKind::Systematic,
        ResamplerKind::Stratified,
        ResamplerKind::Metropolis,
    ];

    /// The GPU's twin of `kind` (Metropolis with its default steps, as `ResamplerKind::build`);
    /// an error naming the schemes the GPU runs for one it does not.
    pub fn for_kind(kind: ResamplerKind) -> Result<Self, GpuError> {
        match kind {
            ResamplerKind::Systematic => Ok(GpuResampler::Systematic),
            ResamplerKind::Stratified => Ok(GpuResampler::Stratified),
            ResamplerKind::Metropolis => Ok(GpuResampler::Metropolis(
                pf_core::resample::Metropolis::DEFAULT_STEPS,
            )),
            other => {
                let names = |kinds: &mut dyn Iterator<Item = ResamplerKind>| {
                    kinds
                        .map(ResamplerKind::name)
                        .collect::<Vec<_>>()
                        .join(", ")
                };
                Err(GpuError::InvalidConfig(format!(
                    "the GPU resamples with {}, not {other} (the CPU also has {})",
                    names(&mut Self::KINDS.into_iter()),
                    names(
                        &mut ResamplerKind::ALL
                            .into_iter()
                            .filter(|k| !Self::KINDS.contains(k))
                    )
                )))
            }
        }
    }
}

/// One stage of the step, for running stages alone ([`GpuFilter::run_stages`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GpuStage {
    /// Resampling (ancestor indices).
    Resample,
    /// Gathering the ancestors' states.
    Gather,
    /// Diffusion (or the likelihood's own `propagate`).
    Diffuse,
    /// The likelihood's dispatches.
    Likelihood,
    /// Normalisation: max, log-sum-exp, ESS.
    Normalise,
    /// The weighted mean (and the best-M′ mean).
    Estimate,
}

impl GpuStage {
    /// Every stage: a frame's whole step.
    pub const ALL: [GpuStage; 6] = [
        GpuStage::Resample,
        GpuStage::Gather,
        GpuStage::Diffuse,
        GpuStage::Likelihood,
        GpuStage::Normalise,
        GpuStage::Estimate,
    ];
}

/// What one GPU step read back.
#[derive(Debug, Clone, PartialEq)]
pub struct GpuStepReport {
    /// `[t·D + d]`.
    pub estimates: Vec<f32>,
    /// Per-target statistics (ESS, status, whether it resampled).
    pub stats: Vec<TargetStats>,
    /// The best-M′ weighted means, `[t·D + d]` (empty when the configuration's `best` is 0).
    pub best_estimates: Vec<f32>,
    /// The posterior's spread about the weighted mean, `[t·D + d]`: the weighted standard
    /// deviation, circular for angles (`pf_core::batch::weighted_means_and_spreads`).
    pub spreads: Vec<f32>,
    /// The step's duration: GPU timestamps where the adapter has them, else wall clock.
    pub time: GpuTime,
    /// What the likelihood asked to read back ([`GpuLikelihood::readbacks`]).
    pub likelihood: LikelihoodReadbacks,
    /// The frame `lag` steps back, smoothed from the ancestry on the device, where the filter
    /// keeps a lag window ([`GpuFilter::keep_lag_window`]) and has stepped `lag + 1` frames.
    pub lagged: Option<LaggedSummaries>,
}

/// A step submitted by [`GpuFilter::submit_stages`] and not yet read back.
#[must_use = "a submitted step must be finished (GpuFilter::finish_step)"]
pub struct PendingStep {
    submission: wgpu::SubmissionIndex,
    /// The staging set its results are copied into.
    back: usize,
    map: crate::stream::PendingMap,
    started: std::time::Instant,
    /// Whether the step summarised its lag window's first frame.
    lagged: bool,
}

/// T targets × M particles on one GPU.
pub struct GpuFilter {
    shape: BatchShape,
    params: FrameParams,
    params_buffer: wgpu::Buffer,
    /// The frame's annealing layers (one for plain Condensation).
    annealing: Annealing,
    /// One parameter block per layer, `layer_stride` bytes apart: copied into `params_buffer`
    /// before that layer runs (staged), or bound in place (fused).
    layer_params: wgpu::Buffer,
    layer_stride: u64,
    /// How a whole step is recorded, and the fused layer's kernels where it fits.
    layout: StepLayout,
    fused: Option<fused::FusedLayers>,
    /// Why the fused step does not fit (`None` when it does).
    fused_refusal: Option<String>,
    /// The particles' lineage through each frame, once asked for ([`Self::keep_lineage`]).
    lineage: Option<lineage::Lineage>,
    /// The last frames on the device, summarised a lag behind ([`Self::keep_lag_window`]).
    lag_window: Option<lag_window::LagWindow>,
    /// The byte lengths of the lag window's sections of `step_backs` (after the likelihood's).
    lag_sections: Vec<u64>,
    /// Every device stream, created once (some only for the bind groups).
    streams: Streams,
    stages: Stages,
    groups: BindGroups,
    /// The resample stage: one to five dispatches depending on the resampler and M.
    resample_steps: Vec<Dispatch>,
    /// The step's readbacks in one staging buffer: estimates, statistics, best-M′ estimates
    /// (empty without them), the timestamps (empty without a timer), then the likelihood's.
    /// Two of them, used in turn, so that a step can be submitted while the one before it still
    /// waits to be read ([`GpuFilter::submit_stages`], [`GpuFilter::finish_step`]).
    step_backs: [ReadbackSet; 2],
    /// The staging set the next submission copies into.
    next_back: usize,
    /// Steps submitted and not yet finished (at most two).
    in_flight: usize,
    /// The byte lengths of the filter's own sections of `step_backs`.
    own_sections: [u64; STEP_BACK_OWN],
    /// The likelihood sections `step_backs` were last built with (name, bytes).
    likelihood_sections: Vec<(&'static str, u64)>,
    has_best: bool,
    timer: Option<StepTimer>,
    /// Each dispatch timed in a pass of its own, when asked ([`Self::profile_dispatches`]).
    profiler: Option<profile::DispatchProfiler>,
    /// The next whole step's commands, recorded while the GPU ran this one (prerecord.rs).
    /// Every method that changes what a step records drops them (`forget_prerecorded`).
    prerecording: prerecord::Prerecording,
    step: u64,
    /// The configuration's seed (the targets' random keys derive from it).
    seed: u64,
}

/// The sections of a step's readback.
const STEP_BACK_ESTIMATES: usize = 0;
const STEP_BACK_STATS: usize = 1;
const STEP_BACK_BEST: usize = 2;
const STEP_BACK_TICKS: usize = 3;
const STEP_BACK_SPREADS: usize = 4;
/// The filter's own sections; the likelihood's follow.
const STEP_BACK_OWN: usize = 5;

/// Above this many particles per target, systematic and stratified resampling scan the weights
/// device-wide (four dispatches) instead of in one workgroup per target.
pub const SINGLE_WORKGROUP_SCAN_LIMIT: usize = 4096;

impl GpuFilter {
    /// Uploads `initial_states` (`[(t·D + d)·M + m]`) with equal weights and builds every stage.
    pub fn new(
        ctx: &GpuContext,
        config: &BatchConfig,
        resampler: GpuResampler,
        initial_states: &[f32],
    ) -> Result<Self, GpuError> {
        config.validate()?;
        let shape = config.shape;
        check_fits(ctx, &shape, initial_states)?;
        let params = FrameParams::for_config(config, resampler);
        let params_buffer = uniform_buffer(ctx, &params)?;
        let layer_stride = fused::layer_stride(ctx);
        let layer_params = layer_params_buffer(ctx, config.annealing.layers, layer_stride)?;
        let streams = Streams::new(ctx, config, initial_states)?;
        let stages = Stages::new(ctx, config.best > 0)?;
        let layers = fused::LayerParams {
            buffer: &layer_params,
            stride: layer_stride,
            count: config.annealing.layers,
        };
        let (fused, fused_refusal) =
            fused::FusedLayers::where_fits(ctx, &shape, resampler, &streams, &layers)?;
        let groups = BindGroups::new(ctx, &stages, &streams, &params_buffer)?;
        let resample_steps = resample_dispatches(
            ctx,
            resampler,
            &shape,
            &streams.resample_bindings(&params_buffer),
        )?;
        let timer = StepTimer::new(ctx)?;
        let estimate_bytes = (shape.targets * shape.dims * 4) as u64;
        let own_sections = [
            estimate_bytes,
            (shape.targets * std::mem::size_of::<TargetStats>()) as u64,
            if config.best > 0 { estimate_bytes } else { 0 },
            if timer.is_some() { 16 } else { 0 },
            estimate_bytes,
        ];
        let step_backs = [
            ReadbackSet::new(ctx, "step readback", &own_sections)?,
            ReadbackSet::new(ctx, "step readback (second)", &own_sections)?,
        ];
        Ok(Self {
            shape,
            params,
            params_buffer,
            annealing: config.annealing.clone(),
            layer_params,
            layer_stride,
            layout: fused::default_layout(&shape, fused.is_some()),
            fused,
            fused_refusal,
            lineage: None,
            lag_window: None,
            lag_sections: Vec::new(),
            step_backs,
            next_back: 0,
            in_flight: 0,
            own_sections,
            likelihood_sections: Vec::new(),
            has_best: config.best > 0,
            timer,
            profiler: None,
            prerecording: prerecord::Prerecording::default(),
            streams,
            stages,
            groups,
            resample_steps,
            step: 0,
            seed: config.seed,
        })
    }

    /// Makes this filter's targets targets `first ..` of a larger batch that is split over
    /// several filters (one per GPU): each target then draws the random numbers it draws in the
    /// whole batch, so that the parts step, bit for bit, as the whole would.
    pub fn number_targets_from(&mut self, ctx: &GpuContext, first: usize) -> Result<(), GpuError> {
        let targets = self.shape.targets;
        if first
            .checked_add(targets)
            .is_none_or(|end| end > u32::MAX as usize)
        {
            return Err(GpuError::InvalidConfig(format!(
                "targets {first} and on of a batch: the index of a target is 32 bits"
            )));
        }
        let keys = |stage| pf_core::batch::stage_keys_from(self.seed, first, targets, stage);
        self.streams
            .diffusion_keys
            .upload_at(ctx, 0, &keys(pf_core::Stage::Diffusion))?;
        self.streams
            .resampling_keys
            .upload_at(ctx, 0, &keys(pf_core::Stage::Resampling))
    }

    /// Targets × particles × dimensions.
    pub fn shape(&self) -> &BatchShape {
        &self.shape
    }

    /// The streams a likelihood binds; pass to [`GpuLikelihood::prepare`] once.
    pub fn likelihood_inputs(&self) -> LikelihoodInputs<'_> {
        LikelihoodInputs {
            shape: self.shape,
            params: &self.params_buffer,
            states: &self.streams.states,
            log_likelihood: &self.streams.log_likelihood,
            estimates: if self.has_best {
                &self.streams.best_estimates
            } else {
                &self.streams.estimates
            },
            diffusion_keys: &self.streams.diffusion_keys,
        }
    }

    /// Records a frame's whole step into `encoder` (no submission).
    pub fn record_step(
        &mut self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        likelihood: &dyn GpuLikelihood,
    ) {
        self.record_stages(ctx, encoder, &GpuStage::ALL, likelihood);
    }

    /// Runs only `stages` (in the step's order) as one submission: the stage-by-stage tests.
    /// Stages that are left out keep their streams as they are. Refused while submitted steps
    /// are in flight (finish them first): waiting for this one out of order would wedge them.
    pub fn run_stages(
        &mut self,
        ctx: &GpuContext,
        stages: &[GpuStage],
        likelihood: &dyn GpuLikelihood,
    ) -> Result<GpuStepReport, GpuError> {
        if self.in_flight > 0 {
            return Err(GpuError::InvalidConfig(
                "submitted steps are in flight: finish them before stepping one at a time".into(),
            ));
        }
        let pending = self.submit_stages(ctx, stages, likelihood)?;
        self.finish_step(ctx, pending)
    }

    /// Records and submits `stages` without waiting: the GPU works on this step while the host
    /// prepares the next one, or reads the one before ([`Self::finish_step`]). At most two steps
    /// are in flight; each must be finished, in the order submitted. Results are the same, bit
    /// for bit, as stepping one at a time: the steps run in order on the GPU, and each copies
    /// its results into a staging buffer of its own.
    pub fn submit_stages(
        &mut self,
        ctx: &GpuContext,
        stages: &[GpuStage],
        likelihood: &dyn GpuLikelihood,
    ) -> Result<PendingStep, GpuError> {
        if self.in_flight >= 2 {
            return Err(GpuError::InvalidConfig(
                "two filter steps are in flight already: finish the older one first".into(),
            ));
        }
        let uses_likelihood = stages.contains(&GpuStage::Likelihood)
            || (stages.contains(&GpuStage::Diffuse) && likelihood.propagates());
        if uses_likelihood && !likelihood.is_prepared() {
            return Err(GpuError::InvalidConfig(
                "the likelihood was never prepared: call its prepare(ctx, \
                 &filter.likelihood_inputs()) once before stepping (pf_gpu::model::ModelFilter \
                 does it for a WGSL model)"
                    .into(),
            ));
        }
        self.fit_likelihood_readbacks(ctx, &likelihood.readbacks())?;
        let started = std::time::Instant::now();
        let back = self.next_back;
        let (submission, lagged) = match self.take_prerecorded(stages, likelihood) {
            Some(commands) => {
                let submission = ctx.scoped("submitting the filter step recorded ahead", || {
                    self.write_layer_params(ctx, stages);
                    ctx.queue.submit([commands])
                })?;
                (submission, false)
            }
            None => ctx.scoped("recording filter stages", || {
                self.write_layer_params(ctx, stages);
                let (commands, lagged) = self.encode_commands(ctx, stages, likelihood);
                (ctx.queue.submit([commands]), lagged)
            })?,
        };
        // Every readback is mapped behind one wait: one poll a frame.
        let map = self.step_backs[back].request_map();
        self.next_back = 1 - back;
        self.in_flight += 1;
        if self.in_flight == 1 && GpuStage::ALL.iter().all(|s| stages.contains(s)) {
            // A lone whole step: the host would wait for the GPU next, so record the step after
            // it now (prerecord.rs).
            self.prerecord_next(ctx, likelihood);
        }
        Ok(PendingStep {
            submission,
            back,
            map,
            started,
            lagged,
        })
    }

    /// Waits for a step from [`Self::submit_stages`] (the oldest in flight) and reads its
    /// results back.
    pub fn finish_step(
        &mut self,
        ctx: &GpuContext,
        pending: PendingStep,
    ) -> Result<GpuStepReport, GpuError> {
        let PendingStep {
            submission,
            back,
            mut map,
            started,
            lagged,
        } = pending;
        let oldest = (self.next_back + 2 - self.in_flight) % 2;
        if self.in_flight == 0 || back != oldest {
            return Err(GpuError::InvalidConfig(
                "filter steps are finished in the order they were submitted".into(),
            ));
        }
        self.in_flight -= 1;
        if self.in_flight == 0 {
            // Nothing queued behind this step: its caller waits for it, so read it as it lands.
            map.wait_as_it_lands(ctx, submission, "the filter step")?;
        } else {
            // A step queued behind keeps the GPU busy: block, leaving the cores to the host's
            // next frame.
            ctx.wait(Some(submission), "the filter step")?;
        }
        let wall = started.elapsed();
        let sections = self.step_backs[back].collect(map)?;
        let estimates = bytemuck::pod_collect_to_vec(&sections[STEP_BACK_ESTIMATES]);
        let stats = bytemuck::pod_collect_to_vec(&sections[STEP_BACK_STATS]);
        let best_estimates = bytemuck::pod_collect_to_vec(&sections[STEP_BACK_BEST]);
        let spreads = bytemuck::pod_collect_to_vec(&sections[STEP_BACK_SPREADS]);
        let time = match &self.timer {
            Some(timer) => GpuTime::Timestamps(
                timer.elapsed(&bytemuck::pod_collect_to_vec(&sections[STEP_BACK_TICKS])),
            ),
            None => GpuTime::WallClock(wall),
        };
        let lagged = if lagged {
            self.lagged_from(&sections)
        } else {
            None
        };
        let likelihood = LikelihoodReadbacks::new(
            self.likelihood_sections
                .iter()
                .map(|&(name, _)| name)
                .zip(sections.into_iter().skip(STEP_BACK_OWN))
                .collect(),
        );
        Ok(GpuStepReport {
            estimates,
            stats,
            best_estimates,
            spreads,
            time,
            likelihood,
            lagged,
        })
    }

    /// Rebuilds the step's staging buffer when the likelihood's readbacks differ from the ones
    /// it holds sections for (the first step with a likelihood, or another likelihood).
    fn fit_likelihood_readbacks(
        &mut self,
        ctx: &GpuContext,
        sources: &[ReadbackSource<'_>],
    ) -> Result<(), GpuError> {
        let wanted: Vec<(&'static str, u64)> = sources.iter().map(|s| (s.name, s.bytes)).collect();
        if wanted == self.likelihood_sections {
            return Ok(());
        }
        for (k, (name, _)) in wanted.iter().enumerate() {
            if wanted[..k].iter().any(|(other, _)| other == name) {
                return Err(GpuError::InvalidConfig(format!(
                    "the likelihood asks to read back two sections named {name:?}"
                )));
            }
        }
        if self.in_flight > 0 {
            return Err(GpuError::InvalidConfig(
                "another likelihood's readbacks while a filter step is in flight".into(),
            ));
        }
        self.likelihood_sections = wanted;
        self.refit_step_backs(ctx)
    }

    /// Builds the step's two staging buffers for the filter's own sections, the likelihood's and
    /// the lag window's.
    fn refit_step_backs(&mut self, ctx: &GpuContext) -> Result<(), GpuError> {
        self.forget_prerecorded();
        let mut bytes = self.own_sections.to_vec();
        bytes.extend(self.likelihood_sections.iter().map(|&(_, b)| b));
        bytes.extend(&self.lag_sections);
        self.step_backs = [
            ReadbackSet::new(ctx, "step readback", &bytes)?,
            ReadbackSet::new(ctx, "step readback (second)", &bytes)?,
        ];
        Ok(())
    }

    /// Sets the index of the next step (it keys the step's random numbers).
    pub fn set_step(&mut self, step: u64) {
        self.step = step;
    }

    /// One frame: record, submit once, wait, read back the estimates and statistics.
    pub fn step(
        &mut self,
        ctx: &GpuContext,
        likelihood: &dyn GpuLikelihood,
    ) -> Result<GpuStepReport, GpuError> {
        self.run_stages(ctx, &GpuStage::ALL, likelihood)
    }

    /// Reads the particle states back (tests and debugging; allocates).
    pub fn download_states(&self, ctx: &GpuContext) -> Result<Vec<f32>, GpuError> {
        self.streams.states.download(ctx)
    }

    /// The normalised weights, `[t·M + m]`.
    pub fn download_weights(&self, ctx: &GpuContext) -> Result<Vec<f32>, GpuError> {
        self.streams.weights.download(ctx)
    }

    /// The normalised log-weights, `[t·M + m]`.
    pub fn download_log_weights(&self, ctx: &GpuContext) -> Result<Vec<f32>, GpuError> {
        self.streams.log_weights.download(ctx)
    }

    /// The last Likelihood stage's `log p(z | x)`, `[t·M + m]` (tests and model checks).
    pub fn download_log_likelihood(&self, ctx: &GpuContext) -> Result<Vec<f32>, GpuError> {
        self.streams.log_likelihood.download(ctx)
    }

    /// The last resampling's ancestor indices, `[t·M + m]`.
    pub fn download_ancestors(&self, ctx: &GpuContext) -> Result<Vec<u32>, GpuError> {
        self.streams.ancestors.download(ctx)
    }

    /// The streams of the stages, for stage-by-stage tests.
    pub fn streams(&self) -> FilterStreams<'_> {
        FilterStreams {
            states: &self.streams.states,
            log_weights: &self.streams.log_weights,
            log_likelihood: &self.streams.log_likelihood,
            weights: &self.streams.weights,
            cdf: &self.streams.cdf,
            ancestors: &self.streams.ancestors,
            stats: &self.streams.stats,
        }
    }
}
