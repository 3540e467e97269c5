//! Building a [`super::GpuFilter`]: the checks, the frame parameters, every device stream, the
//! stage kernels and their bind groups, and the resample stage's dispatches. All of it happens
//! once, at construction; a frame allocates nothing.

use pf_core::Stage;
use pf_core::anneal::Annealing;
use pf_core::batch::{BatchConfig, BatchShape, LayerBeta, stage_keys};

use super::{FrameParams, GpuResampler, SINGLE_WORKGROUP_SCAN_LIMIT, TargetStats};
use crate::context::GpuContext;
use crate::error::GpuError;
use crate::kernels::{Kernel, sources, stage_source};
use crate::stream::DeviceStream;

/// The shape fits the adapter's grid and the initial states fit the shape.
pub(super) fn check_fits(
    ctx: &GpuContext,
    shape: &BatchShape,
    initial_states: &[f32],
) -> Result<(), GpuError> {
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
    Ok(())
}

impl FrameParams {
    /// The parameters of `config` at step 0.
    pub(super) fn for_config(config: &BatchConfig, resampler: GpuResampler) -> Self {
        let shape = config.shape;
        let angular_mask = config
            .angular
            .iter()
            .enumerate()
            .fold(0u32, |mask, (d, &a)| if a { mask | (1 << d) } else { mask });
        Self {
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
            beta: 1.0,
            survival_rate: 0.0,
            max_beta: 1.0,
            sigma_scale: 1.0,
            velocity_gain: config.motion.gain(),
            layer: 0,
        }
    }

    /// These parameters for annealing layer `layer` of a frame, drawing with step index `step`:
    /// its β rule and diffusion scale; layers after the first always resample.
    pub(super) fn for_layer(&self, annealing: &Annealing, layer: usize, step: u64) -> Self {
        let (beta, survival_rate, max_beta) = match LayerBeta::of_layer(annealing, layer) {
            LayerBeta::Fixed(beta) => (beta, 0.0, beta),
            LayerBeta::Survival { rate, max_beta } => (max_beta, rate, max_beta),
        };
        Self {
            step_lo: step as u32,
            step_hi: (step >> 32) as u32,
            ess_threshold: if layer == 0 {
                self.ess_threshold
            } else {
                f32::MAX
            },
            beta,
            survival_rate,
            max_beta,
            sigma_scale: annealing.sigma_scale(layer),
            layer: layer as u32,
            ..*self
        }
    }
}

/// The parameter blocks of a frame's annealing layers, one per layer, `stride` bytes apart: each
/// copied into the uniform buffer before its layer's dispatches (the staged step), or bound where
/// it lies (the fused step), so that one submission runs every layer.
pub(super) fn layer_params_buffer(
    ctx: &GpuContext,
    layers: usize,
    stride: u64,
) -> Result<wgpu::Buffer, GpuError> {
    ctx.scoped("creating the layer parameter buffer", || {
        ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("annealing layer params"),
            size: layers as u64 * stride,
            usage: wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST
                | wgpu::BufferUsages::UNIFORM,
            mapped_at_creation: false,
        })
    })
}

/// The uniform buffer of the frame parameters, holding `params`.
pub(super) fn uniform_buffer(
    ctx: &GpuContext,
    params: &FrameParams,
) -> Result<wgpu::Buffer, GpuError> {
    crate::stream::uniform_buffer(ctx, "frame params", params)
}

/// Every device stream of a filter, created once.
pub(super) struct Streams {
    pub states: DeviceStream<f32>,
    pub selected: DeviceStream<f32>,
    pub log_weights: DeviceStream<f32>,
    pub log_likelihood: DeviceStream<f32>,
    pub weights: DeviceStream<f32>,
    pub cdf: DeviceStream<f32>,
    pub ancestors: DeviceStream<u32>,
    pub stats: DeviceStream<TargetStats>,
    pub estimates: DeviceStream<f32>,
    pub best_estimates: DeviceStream<f32>,
    pub spreads: DeviceStream<f32>,
    /// The constant-velocity drift per target, `[t·D + d]`, and the estimates it comes from.
    pub velocity: DeviceStream<f32>,
    pub previous_estimates: DeviceStream<f32>,
    pub sigma: DeviceStream<f32>,
    pub lower: DeviceStream<f32>,
    pub upper: DeviceStream<f32>,
    pub diffusion_keys: DeviceStream<[u32; 2]>,
    pub resampling_keys: DeviceStream<[u32; 2]>,
    pub block_sums: DeviceStream<f32>,
}

impl Streams {
    /// The initial states with equal weights, fresh statistics and the configuration's σ,
    /// bounds and random keys.
    pub(super) fn new(
        ctx: &GpuContext,
        config: &BatchConfig,
        initial_states: &[f32],
    ) -> Result<Self, GpuError> {
        let shape = config.shape;
        let n = shape.particle_len();
        let uniform_log_weight = -(shape.particles as f32).ln();
        let (lo, hi) = match &config.bounds {
            Some((lo, hi)) => (lo.clone(), hi.clone()),
            None => (vec![0.0; shape.dims], vec![0.0; shape.dims]),
        };
        let keys = |stage| stage_keys(config.seed, shape.targets, stage);
        Ok(Self {
            states: DeviceStream::from_slice(ctx, "states", initial_states)?,
            selected: DeviceStream::zeroed(ctx, "selected states", shape.state_len())?,
            log_weights: DeviceStream::from_slice(
                ctx,
                "log-weights",
                &vec![uniform_log_weight; n],
            )?,
            log_likelihood: DeviceStream::zeroed(ctx, "log-likelihood", n)?,
            weights: DeviceStream::from_slice(
                ctx,
                "weights",
                &vec![1.0 / shape.particles as f32; n],
            )?,
            cdf: DeviceStream::zeroed(ctx, "cdf", n)?,
            ancestors: DeviceStream::zeroed(ctx, "ancestors", n)?,
            stats: DeviceStream::from_slice(
                ctx,
                "target stats",
                &vec![TargetStats::initial(shape.particles); shape.targets],
            )?,
            estimates: DeviceStream::zeroed(ctx, "estimates", shape.targets * shape.dims)?,
            best_estimates: DeviceStream::zeroed(
                ctx,
                "best-M' estimates",
                shape.targets * shape.dims,
            )?,
            spreads: DeviceStream::zeroed(ctx, "spreads", shape.targets * shape.dims)?,
            velocity: DeviceStream::zeroed(ctx, "velocity", shape.targets * shape.dims)?,
            previous_estimates: DeviceStream::from_slice(
                ctx,
                "previous estimates",
                &vec![f32::NAN; shape.targets * shape.dims],
            )?,
            // [layer · D + d]: each annealing layer's σ (0 where a partitioned layer keeps a
            // dimension still).
            sigma: DeviceStream::from_slice(
                ctx,
                "sigma per layer",
                &(0..config.annealing.layers)
                    .flat_map(|layer| config.annealing.layer_sigma(layer, &config.sigma))
                    .collect::<Vec<f32>>(),
            )?,
            lower: DeviceStream::from_slice(ctx, "lower bounds", &lo)?,
            upper: DeviceStream::from_slice(ctx, "upper bounds", &hi)?,
            diffusion_keys: DeviceStream::from_slice(
                ctx,
                "diffusion keys",
                &keys(Stage::Diffusion),
            )?,
            resampling_keys: DeviceStream::from_slice(
                ctx,
                "resampling keys",
                &keys(Stage::Resampling),
            )?,
            block_sums: DeviceStream::zeroed(
                ctx,
                "resampling block sums",
                shape.targets * shape.particles.div_ceil(RESAMPLE_BLOCK),
            )?,
        })
    }

    /// The streams the resample stage binds.
    pub(super) fn resample_bindings<'a>(
        &'a self,
        params: &'a wgpu::Buffer,
    ) -> ResampleBindings<'a> {
        ResampleBindings {
            params,
            weights: &self.weights,
            cdf: &self.cdf,
            ancestors: &self.ancestors,
            stats: &self.stats,
            keys: &self.resampling_keys,
            block_sums: &self.block_sums,
        }
    }
}

/// The kernels of the generic stages.
pub(super) struct Stages {
    pub gather: Kernel,
    pub diffuse: Kernel,
    pub normalise: Kernel,
    pub estimate: Kernel,
    pub best_mean: Option<Kernel>,
}

/// Each stage kernel's bind group.
pub(super) struct BindGroups {
    pub gather: wgpu::BindGroup,
    pub diffuse: wgpu::BindGroup,
    pub normalise: wgpu::BindGroup,
    pub estimate: wgpu::BindGroup,
    pub best_mean: Option<wgpu::BindGroup>,
}

impl Stages {
    /// Builds the gather, diffuse, normalise and estimate kernels (and the best-M′ mean).
    pub(super) fn new(ctx: &GpuContext, with_best: bool) -> Result<Self, GpuError> {
        let kernel =
            |source: &str, entry: &str| Kernel::trusted(ctx, entry, &stage_source(source), entry);
        Ok(Self {
            gather: kernel(sources::GATHER, "gather")?,
            diffuse: kernel(sources::DIFFUSE, "diffuse")?,
            normalise: kernel(sources::NORMALISE, "normalise")?,
            estimate: kernel(sources::ESTIMATE, "weighted_mean")?,
            best_mean: if with_best {
                Some(kernel(sources::ESTIMATE, "best_mean")?)
            } else {
                None
            },
        })
    }
}

impl BindGroups {
    /// Binds each stage to its streams, by the `@binding` numbers of its WGSL file.
    pub(super) fn new(
        ctx: &GpuContext,
        stages: &Stages,
        s: &Streams,
        params: &wgpu::Buffer,
    ) -> Result<Self, GpuError> {
        let p = || params.as_entire_binding();
        Ok(Self {
            gather: stages.gather.bind(
                ctx,
                &[
                    (0, p()),
                    (1, s.states.binding()),
                    (2, s.selected.binding()),
                    (3, s.ancestors.binding()),
                    (4, s.stats.binding()),
                    (5, s.log_weights.binding()),
                ],
            )?,
            diffuse: stages.diffuse.bind(
                ctx,
                &[
                    (0, p()),
                    (1, s.states.binding()),
                    (2, s.sigma.binding()),
                    (3, s.lower.binding()),
                    (4, s.upper.binding()),
                    (5, s.diffusion_keys.binding()),
                    (6, s.velocity.binding()),
                ],
            )?,
            normalise: stages.normalise.bind(
                ctx,
                &[
                    (0, p()),
                    (1, s.log_weights.binding()),
                    (2, s.log_likelihood.binding()),
                    (3, s.weights.binding()),
                    (4, s.stats.binding()),
                ],
            )?,
            estimate: stages.estimate.bind(
                ctx,
                &[
                    (0, p()),
                    (1, s.states.binding()),
                    (2, s.weights.binding()),
                    (3, s.estimates.binding()),
                    (5, s.spreads.binding()),
                    (6, s.velocity.binding()),
                    (7, s.previous_estimates.binding()),
                ],
            )?,
            best_mean: match &stages.best_mean {
                Some(k) => Some(k.bind(
                    ctx,
                    &[
                        (0, p()),
                        (1, s.states.binding()),
                        (2, s.weights.binding()),
                        (4, s.best_estimates.binding()),
                    ],
                )?),
                None => None,
            },
        })
    }
}

pub(super) fn groups_for(count: usize, size: usize) -> u32 {
    count.div_ceil(size) as u32
}

/// Weights per block of the device-wide scan (`BLOCK` in `resample.wgsl`).
const RESAMPLE_BLOCK: usize = 1024;

/// A kernel, its bind group and its grid, prepared once.
pub(super) struct Dispatch {
    pub kernel: Kernel,
    pub group: wgpu::BindGroup,
    pub groups: [u32; 3],
}

pub(super) struct ResampleBindings<'a> {
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
pub(super) fn resample_dispatches(
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
        let kernel = Kernel::trusted(ctx, entry, &source, entry)?;
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
    /// The resampler's cumulative sums (the staged step's; the fused step keeps its CDF in
    /// workgroup memory).
    pub cdf: &'a DeviceStream<f32>,
    /// Ancestor indices, `[t·M + m]`.
    pub ancestors: &'a DeviceStream<u32>,
    /// Per-target statistics.
    pub stats: &'a DeviceStream<TargetStats>,
}
