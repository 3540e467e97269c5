//! The GPU filter driver: a frame's whole step — resample → gather → diffuse → likelihood →
//! normalise → estimate — for T targets × M particles, recorded into one command submission. The
//! host uploads nothing but the per-frame parameters (and what the likelihood needs) and reads
//! back only the estimates and the per-target statistics.
//!
//! CPU twin: `pf_core::batch::BatchFilter` (same layout, same counter-based random numbers).

use bytemuck::{Pod, Zeroable};
use pf_core::batch::{BatchConfig, BatchShape, stage_keys};
use pf_core::{PfError, Stage};

use crate::context::GpuContext;
use crate::error::GpuError;
use crate::kernels::{Kernel, sources, stage_source};
use crate::stream::{DeviceStream, ReadbackSet};
use crate::timing::{GpuTime, StepTimer};

/// The per-frame parameters, `Params` in `shaders/common.wgsl`.
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
    /// Padding to 16 bytes.
    pub _pad: [u32; 2],
}

/// Per-target results, `TargetStats` in `shaders/common.wgsl`.
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
    /// 1 when the target resampled at the start of the step.
    pub resampled: u32,
    /// Padding to 16 bytes.
    pub _pad: [u32; 2],
}

impl TargetStats {
    /// A target's statistics before its first step: every weight equal.
    pub fn initial(particles: usize) -> Self {
        Self {
            ess: particles as f32,
            bad_particle: u32::MAX,
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

/// The streams a likelihood reads and writes, handed to [`GpuLikelihood::prepare`].
pub struct LikelihoodInputs<'a> {
    /// Targets × particles × dimensions.
    pub shape: BatchShape,
    /// The frame parameters (uniform buffer, `Params` of `shaders/common.wgsl`).
    pub params: &'a wgpu::Buffer,
    /// States, `[(t·D + d)·M + m]`, already diffused when the likelihood runs.
    pub states: &'a DeviceStream<f32>,
    /// Where the likelihood writes `log p(z | x)`, `[t·M + m]`.
    pub log_likelihood: &'a DeviceStream<f32>,
    /// The step's estimate per target, `[t·D + d]`: the best-M′ weighted mean where the filter
    /// computes one, else the weighted mean (written by the Estimate stage).
    pub estimates: &'a DeviceStream<f32>,
    /// The per-target Philox keys of the diffusion stream (`counter_gaussian(key_t, m, d,
    /// step)`), for a likelihood that brings its own dynamics ([`GpuLikelihood::propagates`]).
    pub diffusion_keys: &'a DeviceStream<[u32; 2]>,
}

/// An observation model on the GPU. A tracker builds its pipelines and bind groups once in
/// `prepare`, uploads each frame's observation before the step, and records its dispatches.
pub trait GpuLikelihood {
    /// Binds the filter's streams (once, after construction); builds its bind groups.
    fn prepare(&mut self, ctx: &GpuContext, inputs: &LikelihoodInputs<'_>) -> Result<(), GpuError>;
    /// Records the likelihood's dispatches into the step's compute pass.
    fn record(&self, pass: &mut wgpu::ComputePass<'_>);

    /// Whether `prepare` has bound it; a step with an unprepared likelihood is an error rather
    /// than a step that weighs stale values.
    fn is_prepared(&self) -> bool {
        true
    }

    /// Whether it brings its own dynamics, recorded by [`GpuLikelihood::record_propagate`] in
    /// place of the filter's Gaussian random walk.
    fn propagates(&self) -> bool {
        false
    }

    /// The dynamics' dispatches (the Diffuse stage) when [`GpuLikelihood::propagates`].
    fn record_propagate(&self, _pass: &mut wgpu::ComputePass<'_>) {}

    /// Work on the step's estimates (a tracker's check of its estimate, say), recorded after
    /// the Estimate stage in the same pass.
    fn record_after_estimate(&self, _pass: &mut wgpu::ComputePass<'_>) {}

    /// Copies into the likelihood's own readbacks, recorded at the end of a step that ran the
    /// Estimate stage; [`GpuLikelihood::request_maps`] follows before the step's one wait.
    fn record_readbacks(&self, _encoder: &mut wgpu::CommandEncoder) {}

    /// Asks for the likelihood's readbacks to be mapped, so that they share the step's wait.
    fn request_maps(&self) {}
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
    /// The step's duration: GPU timestamps where the adapter has them, else wall clock.
    pub time: GpuTime,
}

struct Stages {
    gather: Kernel,
    diffuse: Kernel,
    normalise: Kernel,
    estimate: Kernel,
    best_mean: Option<Kernel>,
}

struct BindGroups {
    gather: wgpu::BindGroup,
    diffuse: wgpu::BindGroup,
    normalise: wgpu::BindGroup,
    estimate: wgpu::BindGroup,
    best_mean: Option<wgpu::BindGroup>,
}

/// T targets × M particles on one GPU.
pub struct GpuFilter {
    shape: BatchShape,
    params: FrameParams,
    params_buffer: wgpu::Buffer,
    states: DeviceStream<f32>,
    selected: DeviceStream<f32>,
    log_weights: DeviceStream<f32>,
    log_likelihood: DeviceStream<f32>,
    weights: DeviceStream<f32>,
    cdf: DeviceStream<f32>,
    ancestors: DeviceStream<u32>,
    stats: DeviceStream<TargetStats>,
    estimates: DeviceStream<f32>,
    best_estimates: DeviceStream<f32>,
    // Kept alive for the bind groups.
    _sigma: DeviceStream<f32>,
    _lower: DeviceStream<f32>,
    _upper: DeviceStream<f32>,
    _diffusion_keys: DeviceStream<[u32; 2]>,
    _resampling_keys: DeviceStream<[u32; 2]>,
    stages: Stages,
    groups: BindGroups,
    /// The resample stage: one to five dispatches depending on the resampler and M.
    resample_steps: Vec<Dispatch>,
    _block_sums: DeviceStream<f32>,
    /// The step's readbacks in one staging buffer: estimates, statistics, best-M′ estimates
    /// (empty without them) and the timestamps (empty without a timer).
    step_back: ReadbackSet,
    has_best: bool,
    timer: Option<StepTimer>,
    step: u64,
}

fn groups_for(count: usize, size: usize) -> u32 {
    count.div_ceil(size) as u32
}

/// The sections of a step's readback.
const STEP_BACK_ESTIMATES: usize = 0;
const STEP_BACK_STATS: usize = 1;
const STEP_BACK_BEST: usize = 2;
const STEP_BACK_TICKS: usize = 3;

/// Above this many particles per target, systematic and stratified resampling scan the weights
/// device-wide (four dispatches) instead of in one workgroup per target.
pub const SINGLE_WORKGROUP_SCAN_LIMIT: usize = 4096;

/// Weights per block of the device-wide scan (`BLOCK` in `resample.wgsl`).
const RESAMPLE_BLOCK: usize = 1024;

/// A kernel, its bind group and its grid, prepared once.
struct Dispatch {
    kernel: Kernel,
    group: wgpu::BindGroup,
    groups: [u32; 3],
}

struct ResampleBindings<'a> {
    params: &'a wgpu::Buffer,
    weights: &'a DeviceStream<f32>,
    cdf: &'a DeviceStream<f32>,
    ancestors: &'a DeviceStream<u32>,
    stats: &'a DeviceStream<TargetStats>,
    keys: &'a DeviceStream<[u32; 2]>,
    block_sums: &'a DeviceStream<f32>,
}

/// The dispatches of the resample stage. Auto layouts keep only the bindings an entry point uses,
/// so each entry point is bound with exactly those.
fn resample_dispatches(
    ctx: &GpuContext,
    resampler: GpuResampler,
    shape: &BatchShape,
    b: &ResampleBindings<'_>,
) -> Result<Vec<Dispatch>, GpuError> {
    let source = stage_source(sources::RESAMPLE);
    let (t, m) = (shape.targets as u32, shape.particles);
    let per_particle = [groups_for(m, 64), t, 1];
    let blocks = [groups_for(m, RESAMPLE_BLOCK), t, 1];
    let make = |entry: &str, bindings: &[u32], groups: [u32; 3]| -> Result<Dispatch, GpuError> {
        let kernel = Kernel::new(ctx, entry, &source, entry)?;
        let entries: Vec<(u32, wgpu::BindingResource<'_>)> = bindings
            .iter()
            .map(|&i| {
                let resource = match i {
                    0 => b.params.as_entire_binding(),
                    1 => b.weights.binding(),
                    2 => b.cdf.binding(),
                    3 => b.ancestors.binding(),
                    4 => b.stats.binding(),
                    5 => b.keys.binding(),
                    _ => b.block_sums.binding(),
                };
                (i, resource)
            })
            .collect();
        let group = kernel.bind(ctx, &entries)?;
        Ok(Dispatch {
            kernel,
            group,
            groups,
        })
    };
    let mark = || {
        make(
            "mark_resampled",
            &[0, 4],
            [groups_for(shape.targets, 64), 1, 1],
        )
    };
    let large = m > SINGLE_WORKGROUP_SCAN_LIMIT;
    Ok(match resampler {
        GpuResampler::Metropolis(_) => {
            vec![mark()?, make("metropolis", &[0, 1, 3, 4, 5], per_particle)?]
        }
        GpuResampler::Systematic | GpuResampler::Stratified if large => {
            let search = if resampler == GpuResampler::Systematic {
                "search_systematic"
            } else {
                "search_stratified"
            };
            vec![
                mark()?,
                make("block_sums_kernel", &[0, 1, 6], blocks)?,
                make("scan_block_sums", &[0, 6], [1, t, 1])?,
                make("block_cdf", &[0, 1, 2, 6], blocks)?,
                make(search, &[0, 1, 2, 3, 4, 5], per_particle)?,
            ]
        }
        GpuResampler::Systematic => vec![make("systematic", &[0, 1, 2, 3, 4, 5], [1, t, 1])?],
        GpuResampler::Stratified => vec![make("stratified", &[0, 1, 2, 3, 4, 5], [1, t, 1])?],
    })
}

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
        if initial_states.len() != shape.state_len() {
            return Err(GpuError::LengthMismatch {
                what: "initial states".into(),
                expected: shape.state_len(),
                got: initial_states.len(),
            });
        }
        let max_groups = ctx.limits().max_compute_workgroups_per_dimension as usize;
        if shape.targets > max_groups || shape.particles.div_ceil(64) > max_groups {
            return Err(GpuError::InvalidConfig(format!(
                "{} targets x {} particles exceed the adapter's {max_groups} workgroups per dimension",
                shape.targets, shape.particles
            )));
        }
        let n = shape.particle_len();
        let angular_mask = config
            .angular
            .iter()
            .enumerate()
            .fold(0u32, |mask, (d, &a)| if a { mask | (1 << d) } else { mask });
        let params = FrameParams {
            targets: shape.targets as u32,
            particles: shape.particles as u32,
            dims: shape.dims as u32,
            angular_mask,
            step_lo: 0,
            step_hi: 0,
            has_bounds: u32::from(config.bounds.is_some()),
            metropolis_steps: match resampler {
                GpuResampler::Metropolis(b) => b,
                _ => 0,
            },
            // f32::MAX stands for "every step": ESS is always below it.
            ess_threshold: if config.ess_threshold.is_finite() {
                config.ess_threshold as f32
            } else {
                f32::MAX
            },
            best: config.best as u32,
            _pad: [0; 2],
        };
        let params_buffer = ctx.scoped("creating the parameter buffer", || {
            ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("frame params"),
                size: std::mem::size_of::<FrameParams>() as u64,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        })?;
        ctx.queue
            .write_buffer(&params_buffer, 0, bytemuck::bytes_of(&params));

        let uniform_lw = -(shape.particles as f32).ln();
        let states = DeviceStream::from_slice(ctx, "states", initial_states)?;
        let selected = DeviceStream::zeroed(ctx, "selected states", shape.state_len())?;
        let log_weights = DeviceStream::from_slice(ctx, "log-weights", &vec![uniform_lw; n])?;
        let log_likelihood = DeviceStream::zeroed(ctx, "log-likelihood", n)?;
        let weights =
            DeviceStream::from_slice(ctx, "weights", &vec![1.0 / shape.particles as f32; n])?;
        let cdf = DeviceStream::zeroed(ctx, "cdf", n)?;
        let ancestors = DeviceStream::zeroed(ctx, "ancestors", n)?;
        let stats = DeviceStream::from_slice(
            ctx,
            "target stats",
            &vec![TargetStats::initial(shape.particles); shape.targets],
        )?;
        let estimates = DeviceStream::zeroed(ctx, "estimates", shape.targets * shape.dims)?;
        let best_estimates =
            DeviceStream::zeroed(ctx, "best-M' estimates", shape.targets * shape.dims)?;
        let sigma = DeviceStream::from_slice(ctx, "sigma", &config.sigma)?;
        let (lo, hi) = match &config.bounds {
            Some((lo, hi)) => (lo.clone(), hi.clone()),
            None => (vec![0.0; shape.dims], vec![0.0; shape.dims]),
        };
        let lower = DeviceStream::from_slice(ctx, "lower bounds", &lo)?;
        let upper = DeviceStream::from_slice(ctx, "upper bounds", &hi)?;
        let diffusion_keys = DeviceStream::from_slice(
            ctx,
            "diffusion keys",
            &stage_keys(config.seed, shape.targets, Stage::Diffusion),
        )?;
        let resampling_keys = DeviceStream::from_slice(
            ctx,
            "resampling keys",
            &stage_keys(config.seed, shape.targets, Stage::Resampling),
        )?;

        let stages = Stages {
            gather: Kernel::new(ctx, "gather", &stage_source(sources::GATHER), "gather")?,
            diffuse: Kernel::new(ctx, "diffuse", &stage_source(sources::DIFFUSE), "diffuse")?,
            normalise: Kernel::new(
                ctx,
                "normalise",
                &stage_source(sources::NORMALISE),
                "normalise",
            )?,
            estimate: Kernel::new(
                ctx,
                "weighted_mean",
                &stage_source(sources::ESTIMATE),
                "weighted_mean",
            )?,
            best_mean: if config.best > 0 {
                Some(Kernel::new(
                    ctx,
                    "best_mean",
                    &stage_source(sources::ESTIMATE),
                    "best_mean",
                )?)
            } else {
                None
            },
        };
        let p = || params_buffer.as_entire_binding();
        let block_sums = DeviceStream::zeroed(
            ctx,
            "resampling block sums",
            shape.targets * shape.particles.div_ceil(RESAMPLE_BLOCK),
        )?;
        let resample_steps = resample_dispatches(
            ctx,
            resampler,
            &shape,
            &ResampleBindings {
                params: &params_buffer,
                weights: &weights,
                cdf: &cdf,
                ancestors: &ancestors,
                stats: &stats,
                keys: &resampling_keys,
                block_sums: &block_sums,
            },
        )?;
        let groups = BindGroups {
            gather: stages.gather.bind(
                ctx,
                &[
                    (0, p()),
                    (1, states.binding()),
                    (2, selected.binding()),
                    (3, ancestors.binding()),
                    (4, stats.binding()),
                    (5, log_weights.binding()),
                ],
            )?,
            diffuse: stages.diffuse.bind(
                ctx,
                &[
                    (0, p()),
                    (1, states.binding()),
                    (2, sigma.binding()),
                    (3, lower.binding()),
                    (4, upper.binding()),
                    (5, diffusion_keys.binding()),
                ],
            )?,
            normalise: stages.normalise.bind(
                ctx,
                &[
                    (0, p()),
                    (1, log_weights.binding()),
                    (2, log_likelihood.binding()),
                    (3, weights.binding()),
                    (4, stats.binding()),
                ],
            )?,
            estimate: stages.estimate.bind(
                ctx,
                &[
                    (0, p()),
                    (1, states.binding()),
                    (2, weights.binding()),
                    (3, estimates.binding()),
                ],
            )?,
            best_mean: match &stages.best_mean {
                Some(k) => Some(k.bind(
                    ctx,
                    &[
                        (0, p()),
                        (1, states.binding()),
                        (2, weights.binding()),
                        (4, best_estimates.binding()),
                    ],
                )?),
                None => None,
            },
        };
        let estimate_bytes = (shape.targets * shape.dims * 4) as u64;
        let timer = StepTimer::new(ctx)?;
        Ok(Self {
            shape,
            params,
            params_buffer,
            step_back: ReadbackSet::new(
                ctx,
                "step readback",
                &[
                    estimate_bytes,
                    (shape.targets * std::mem::size_of::<TargetStats>()) as u64,
                    if config.best > 0 { estimate_bytes } else { 0 },
                    if timer.is_some() { 16 } else { 0 },
                ],
            )?,
            has_best: config.best > 0,
            timer,
            states,
            selected,
            log_weights,
            log_likelihood,
            weights,
            cdf,
            ancestors,
            stats,
            estimates,
            best_estimates,
            _sigma: sigma,
            _lower: lower,
            _upper: upper,
            _diffusion_keys: diffusion_keys,
            _resampling_keys: resampling_keys,
            stages,
            groups,
            resample_steps,
            _block_sums: block_sums,
            step: 0,
        })
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
            states: &self.states,
            log_likelihood: &self.log_likelihood,
            estimates: if self.has_best {
                &self.best_estimates
            } else {
                &self.estimates
            },
            diffusion_keys: &self._diffusion_keys,
        }
    }

    /// Records a frame's whole step into `encoder` (no submission).
    pub fn record_step(
        &mut self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        likelihood: &dyn GpuLikelihood,
    ) {
        use GpuStage::*;
        self.record_stages(
            ctx,
            encoder,
            &[Resample, Gather, Diffuse, Likelihood, Normalise, Estimate],
            likelihood,
        );
    }

    /// Records the given stages, in the step's order, with the next step index.
    fn record_stages(
        &mut self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        stages: &[GpuStage],
        likelihood: &dyn GpuLikelihood,
    ) {
        let step = self.step;
        self.step += 1;
        self.params.step_lo = step as u32;
        self.params.step_hi = (step >> 32) as u32;
        ctx.queue
            .write_buffer(&self.params_buffer, 0, bytemuck::bytes_of(&self.params));

        let (t, m) = (self.shape.targets, self.shape.particles);
        let per_particle = [groups_for(m, 64), t as u32, 1];
        let per_target = [1, t as u32, 1];
        let wants = |s: GpuStage| stages.contains(&s);
        if wants(GpuStage::Resample) || wants(GpuStage::Gather) {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("select"),
                timestamp_writes: None,
            });
            if wants(GpuStage::Resample) {
                for step in &self.resample_steps {
                    step.kernel.record(&mut pass, &step.group, step.groups);
                }
            }
            if wants(GpuStage::Gather) {
                self.stages
                    .gather
                    .record(&mut pass, &self.groups.gather, per_particle);
            }
        }
        if wants(GpuStage::Gather) {
            let bytes = (self.shape.state_len() * 4) as u64;
            encoder.copy_buffer_to_buffer(
                self.selected.buffer(),
                0,
                self.states.buffer(),
                0,
                bytes,
            );
        }
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("diffuse, measure, normalise, estimate"),
                timestamp_writes: None,
            });
            if wants(GpuStage::Diffuse) {
                if likelihood.propagates() {
                    likelihood.record_propagate(&mut pass);
                } else {
                    self.stages
                        .diffuse
                        .record(&mut pass, &self.groups.diffuse, per_particle);
                }
            }
            if wants(GpuStage::Likelihood) {
                likelihood.record(&mut pass);
            }
            if wants(GpuStage::Normalise) {
                self.stages
                    .normalise
                    .record(&mut pass, &self.groups.normalise, per_target);
            }
            if wants(GpuStage::Estimate) {
                self.stages
                    .estimate
                    .record(&mut pass, &self.groups.estimate, per_target);
                if let (Some(k), Some(g)) = (&self.stages.best_mean, &self.groups.best_mean) {
                    k.record(&mut pass, g, per_target);
                }
                likelihood.record_after_estimate(&mut pass);
            }
        }
        if wants(GpuStage::Estimate) {
            likelihood.record_readbacks(encoder);
        }
        self.step_back
            .record_copy(encoder, STEP_BACK_ESTIMATES, self.estimates.buffer());
        self.step_back
            .record_copy(encoder, STEP_BACK_STATS, self.stats.buffer());
        self.step_back
            .record_copy(encoder, STEP_BACK_BEST, self.best_estimates.buffer());
    }

    /// Runs only `stages` (in the step's order) as one submission: the stage-by-stage tests.
    /// Stages that are left out keep their streams as they are.
    pub fn run_stages(
        &mut self,
        ctx: &GpuContext,
        stages: &[GpuStage],
        likelihood: &dyn GpuLikelihood,
    ) -> Result<GpuStepReport, GpuError> {
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
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("filter step"),
            });
        let started = std::time::Instant::now();
        let submission = ctx.scoped("recording filter stages", || {
            if let Some(timer) = &self.timer {
                timer.begin(&mut encoder);
            }
            self.record_stages(ctx, &mut encoder, stages, likelihood);
            if let Some(timer) = &self.timer {
                timer.end(&mut encoder);
                self.step_back
                    .record_copy(&mut encoder, STEP_BACK_TICKS, timer.resolved());
            }
            ctx.queue.submit([encoder.finish()])
        })?;
        // Every readback is mapped behind one wait: one poll a frame.
        let step_map = self.step_back.request_map();
        if stages.contains(&GpuStage::Estimate) {
            likelihood.request_maps();
        }
        ctx.wait(Some(submission), "the filter step")?;
        let wall = started.elapsed();
        let sections = self.step_back.collect(step_map)?;
        let estimates = bytemuck::pod_collect_to_vec(&sections[STEP_BACK_ESTIMATES]);
        let stats = bytemuck::pod_collect_to_vec(&sections[STEP_BACK_STATS]);
        let best_estimates = bytemuck::pod_collect_to_vec(&sections[STEP_BACK_BEST]);
        let time = match &self.timer {
            Some(timer) => GpuTime::Timestamps(
                timer.elapsed(&bytemuck::pod_collect_to_vec(&sections[STEP_BACK_TICKS])),
            ),
            None => GpuTime::WallClock(wall),
        };
        Ok(GpuStepReport {
            estimates,
            stats,
            best_estimates,
            time,
        })
    }

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
        self.states.upload_at(ctx, t * block, states)?;
        self.log_weights
            .upload_at(ctx, t * m, &vec![-(m as f32).ln(); m])?;
        self.weights
            .upload_at(ctx, t * m, &vec![1.0 / m as f32; m])?;
        self.stats.upload_at(ctx, t, &[TargetStats::initial(m)])
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
        use GpuStage::*;
        self.run_stages(
            ctx,
            &[Resample, Gather, Diffuse, Likelihood, Normalise, Estimate],
            likelihood,
        )
    }

    /// Reads the particle states back (tests and debugging; allocates).
    pub fn download_states(&self, ctx: &GpuContext) -> Result<Vec<f32>, GpuError> {
        self.states.download(ctx)
    }

    /// The normalised weights, `[t·M + m]`.
    pub fn download_weights(&self, ctx: &GpuContext) -> Result<Vec<f32>, GpuError> {
        self.weights.download(ctx)
    }

    /// The normalised log-weights, `[t·M + m]`.
    pub fn download_log_weights(&self, ctx: &GpuContext) -> Result<Vec<f32>, GpuError> {
        self.log_weights.download(ctx)
    }

    /// The last Likelihood stage's `log p(z | x)`, `[t·M + m]` (tests and model checks).
    pub fn download_log_likelihood(&self, ctx: &GpuContext) -> Result<Vec<f32>, GpuError> {
        self.log_likelihood.download(ctx)
    }

    /// The last resampling's ancestor indices, `[t·M + m]`.
    pub fn download_ancestors(&self, ctx: &GpuContext) -> Result<Vec<u32>, GpuError> {
        self.ancestors.download(ctx)
    }

    /// The streams of the stages, for stage-by-stage tests.
    pub fn streams(&self) -> FilterStreams<'_> {
        FilterStreams {
            states: &self.states,
            log_weights: &self.log_weights,
            log_likelihood: &self.log_likelihood,
            weights: &self.weights,
            cdf: &self.cdf,
            ancestors: &self.ancestors,
            stats: &self.stats,
        }
    }
}

/// A likelihood that records nothing (the log-likelihood stream keeps its contents).
pub struct NoLikelihood;

impl GpuLikelihood for NoLikelihood {
    fn prepare(&mut self, _: &GpuContext, _: &LikelihoodInputs<'_>) -> Result<(), GpuError> {
        Ok(())
    }
    fn record(&self, _: &mut wgpu::ComputePass<'_>) {}
}

/// Borrowed views of a filter's device streams.
pub struct FilterStreams<'a> {
    /// States, `[(t·D + d)·M + m]`.
    pub states: &'a DeviceStream<f32>,
    /// Normalised log-weights, `[t·M + m]`.
    pub log_weights: &'a DeviceStream<f32>,
    /// The likelihood's output, `[t·M + m]`.
    pub log_likelihood: &'a DeviceStream<f32>,
    /// Normalised weights, `[t·M + m]`.
    pub weights: &'a DeviceStream<f32>,
    /// The resampler's cumulative sums.
    pub cdf: &'a DeviceStream<f32>,
    /// Ancestor indices, `[t·M + m]`.
    pub ancestors: &'a DeviceStream<u32>,
    /// Per-target statistics.
    pub stats: &'a DeviceStream<TargetStats>,
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
                has_bounds, metropolis_steps, ess_threshold, best),
        );
        assert_mirrors_wgsl(
            &common,
            "TargetStats",
            size_of::<TargetStats>(),
            &fields!(TargetStats: max_log_weight, log_sum_shifted, ess, status, bad_particle,
                resampled),
        );
    }
}
