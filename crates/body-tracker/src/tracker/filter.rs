//! One particle filter over the pose θ on one engine (the CPU, or one GPU) and how it weighs:
//! the piece the tracker runs once, or once per island with several GPUs. A frame reaches it
//! prepared ([`crate::frame`]); on a GPU only the rays are uploaded.

use crate::skeleton::gpu::{BodyLikelihoodConfig, BodyLikelihoodGpu};
use pf_core::batch::{BatchConfig, BatchShape, gaussian_clouds};
use pf_core::random::part_seed;
use pf_core::resample::ResamplerKind;
use pf_gpu::engine::{EngineReport, Filter as EngineFilter, FilterEngine, InFlight, Model};
use pf_gpu::{GpuContext, GpuLikelihood, GpuResampler, LikelihoodInputs, NoLikelihood};
use rayon::prelude::*;

use super::TrackerConfig;
use crate::error::BodyError;
use crate::likelihood::{CapsuleLikelihoodParams, Rays, culled_sum_of_squared_distances};
use crate::skeleton::{ROOT_DOFS, Skeleton};

/// The body likelihood as a [`Model`] of the engine's one filter: eq. 3 over the frame's rays,
/// on the host (all cores, culled capsules) or on the GPU ([`BodyLikelihoodGpu`]).
pub(crate) struct BodyModel {
    /// The GPU side (GPU engines only).
    gpu: Option<Box<BodyLikelihoodGpu>>,
}

/// What one step weighs: the frame, and the skeleton the host poses.
pub(crate) struct BodyFrame<'a> {
    skeleton: &'a Skeleton,
    frame: &'a Frame<'a>,
}

impl Model for BodyModel {
    type Frame<'f> = BodyFrame<'f>;
    type Error = BodyError;

    fn prepare_gpu(
        &mut self,
        ctx: &GpuContext,
        inputs: &LikelihoodInputs<'_>,
    ) -> Result<(), BodyError> {
        if let Some(gpu) = &mut self.gpu {
            GpuLikelihood::prepare(&mut **gpu, ctx, inputs)?;
        }
        Ok(())
    }

    /// Uploads the frame's prepared rays and σ; a flat frame is weighed by nothing.
    fn upload_frame(
        &mut self,
        ctx: &GpuContext,
        frame: &BodyFrame<'_>,
    ) -> Result<&dyn GpuLikelihood, BodyError> {
        let gpu = self.gpu.as_deref_mut().ok_or_else(|| {
            BodyError::InvalidInput("a body model built for the CPU was put on a GPU".into())
        })?;
        let rays = frame.frame.gpu_rays.ok_or_else(|| {
            BodyError::InvalidInput("a GPU filter got a frame prepared for the CPU".into())
        })?;
        gpu.upload_prepared_rays(ctx, rays)?;
        let mut sigmas = vec![frame.frame.sigma];
        sigmas.extend(frame.frame.coarse.as_ref().map(|c| c.sigma));
        gpu.set_level_sigmas(ctx, &sigmas)?;
        Ok(if frame.frame.flat { &NoLikelihood } else { gpu })
    }

    fn measure_on_cpu(
        &self,
        frame: &BodyFrame<'_>,
        shape: &BatchShape,
        poses: &[f32],
        out: &mut [f32],
    ) -> Result<(), BodyError> {
        self.measure_layer_on_cpu(frame, shape, usize::MAX, poses, out)
    }

    /// Eq. 3 over every point, or over the coarse subset in a coarse layer.
    fn measure_layer_on_cpu(
        &self,
        frame: &BodyFrame<'_>,
        _: &BatchShape,
        layer: usize,
        poses: &[f32],
        out: &mut [f32],
    ) -> Result<(), BodyError> {
        let BodyFrame { skeleton, frame } = frame;
        if frame.flat {
            out.fill(0.0);
            return Ok(());
        }
        match &frame.coarse {
            Some(CoarseFrame {
                rays: Some(rays),
                sigma,
            }) if layer < frame.coarse_layers => {
                let params = CapsuleLikelihoodParams::new(frame.params.tau, *sigma)?;
                host_log_likelihoods(skeleton, rays, params, poses, out)
            }
            _ => host_log_likelihoods(skeleton, frame.rays, frame.params, poses, out),
        }
    }
}

/// One particle filter over θ on one engine (the CPU, or one GPU): the body model stepped by
/// the engine's filter.
pub(crate) struct Filter {
    filter: EngineFilter<BodyModel>,
}

/// What one filter's step gives (an island's, with several GPUs): its estimate, the spread
/// about it and its effective sample size.
#[derive(Debug, Clone, PartialEq)]
pub struct FilterStep {
    pub pose: Vec<f32>,
    pub spread: Vec<f32>,
    pub ess: f64,
    /// The frame's log evidence (`pf_gpu::engine::EngineReport::log_evidence`).
    pub log_evidence: f64,
    /// M of the estimate (eq. 3's sum over the frame's points), when the GPU computed it in the
    /// step's submission; the host computes it otherwise.
    pub estimate_sum: Option<f64>,
    /// The step's own time on its GPU (timestamps where the adapter has them); `None` on the CPU.
    pub gpu_time: Option<pf_gpu::GpuTime>,
    /// The frame a lag behind, smoothed on the GPU, where the filter keeps a lag window.
    pub lagged: Option<pf_core::smooth::lag_window::LaggedSummaries>,
}

/// A frame as every filter weighs it.
pub(crate) struct Frame<'a> {
    pub(crate) rays: &'a Rays,
    /// The rays as the GPU likelihood uploads them (`None` on the CPU engine).
    pub(crate) gpu_rays: Option<&'a crate::likelihood::gpu::PreparedRays>,
    pub(crate) params: CapsuleLikelihoodParams,
    /// σ scaled to the frame's number of points.
    pub(crate) sigma: f32,
    /// The coarse layers' subset of the points, with coarse layers.
    pub(crate) coarse: Option<CoarseFrame<'a>>,
    /// How many of the frame's annealing layers, from the first, weigh the subset.
    pub(crate) coarse_layers: usize,
    pub(crate) flat: bool,
}

/// The coarse layers' subset of a frame ([`crate::likelihood::CoarseLayers`]).
pub(crate) struct CoarseFrame<'a> {
    /// Its rays, for the CPU engine (a GPU weighs the prepared rays' second level).
    pub(crate) rays: Option<&'a Rays>,
    /// σ scaled to the subset's number of points.
    pub(crate) sigma: f32,
}

impl Filter {
    pub(crate) fn step(
        &mut self,
        skeleton: &Skeleton,
        frame: &Frame,
    ) -> Result<FilterStep, BodyError> {
        let report = self.filter.step(&BodyFrame { skeleton, frame })?;
        self.step_of(report, frame.flat)
    }

    /// On a GPU, uploads the frame and submits its step without waiting ([`Self::finish`] reads
    /// it back); `None` on the CPU engine, which steps with [`Self::step`].
    pub(crate) fn submit(
        &mut self,
        skeleton: &Skeleton,
        frame: &Frame,
    ) -> Result<Option<InFlight>, BodyError> {
        if !self.on_gpu() {
            return Ok(None);
        }
        Ok(Some(self.filter.submit(&BodyFrame { skeleton, frame })?))
    }

    /// The step of a frame from [`Self::submit`], after waiting for it.
    pub(crate) fn finish(
        &mut self,
        pending: InFlight,
        flat: bool,
    ) -> Result<FilterStep, BodyError> {
        let report = self.filter.finish(pending)?;
        self.step_of(report, flat)
    }

    /// Whether the filter weighs on a GPU.
    pub(crate) fn on_gpu(&self) -> bool {
        self.filter.context().is_some()
    }

    /// The engine (particles, the GPU context).
    pub(crate) fn engine(&self) -> &FilterEngine {
        self.filter.engine()
    }

    /// The engine, to move samples between islands.
    pub(crate) fn engine_mut(&mut self) -> &mut FilterEngine {
        self.filter.engine_mut()
    }

    /// The filter's step from its engine's report.
    fn step_of(&self, report: EngineReport, flat: bool) -> Result<FilterStep, BodyError> {
        if let Some(Err(e)) = report.status.into_iter().next() {
            return Err(e.into());
        }
        let estimate_sum = match self.on_gpu() {
            true if !flat => {
                let sums: Vec<f32> = report.likelihood.get(BodyLikelihoodGpu::ESTIMATE_SUM)?;
                sums.first().map(|&m| f64::from(m))
            }
            _ => None,
        };
        Ok(FilterStep {
            pose: report.estimates,
            spread: report.spreads,
            ess: report.ess[0],
            log_evidence: report.log_evidence[0],
            estimate_sum,
            gpu_time: report.gpu_time,
            lagged: report.lagged,
        })
    }
}

/// Island `island`'s seed: island 0 keeps the tracker's (so one island is the one-GPU filter).
pub(crate) fn island_seed(seed: u64, island: usize) -> u64 {
    part_seed(seed, island)
}

/// The random walk's σ per pose value (the root's translation, the root's rotations, the
/// joints) and which values are angles (the root's rotations).
pub(crate) fn diffusion(skeleton: &Skeleton, config: &TrackerConfig) -> (Vec<f32>, Vec<bool>) {
    let dims = skeleton.dofs();
    let mut sigma = vec![config.joint_sigma; dims];
    sigma[..3].fill(config.translation_sigma);
    sigma[3..ROOT_DOFS].fill(config.rotation_sigma);
    let mut angular = vec![false; dims];
    angular[3..ROOT_DOFS].fill(true);
    (sigma, angular)
}

/// A frame's annealing layers: the configuration's, partitioned by the skeleton when asked.
pub(crate) fn annealing(
    skeleton: &Skeleton,
    config: &TrackerConfig,
) -> Result<pf_core::anneal::Annealing, BodyError> {
    if config.partitioned {
        super::partitioned_schedule(skeleton, &config.annealing)
    } else {
        Ok(config.annealing.clone())
    }
}

/// One filter of `config.particles` samples around `initial_pose`, on the CPU (`ctx` `None`) or
/// a GPU; island `island` draws its own random numbers (island 0 those of a lone filter).
pub(crate) fn new_filter(
    skeleton: &Skeleton,
    config: &TrackerConfig,
    initial_pose: &[f32],
    ctx: Option<GpuContext>,
    island: usize,
) -> Result<Filter, BodyError> {
    let dims = skeleton.dofs();
    let seed = island_seed(config.seed, island);
    let shape = BatchShape::new(1, config.particles, dims)?;
    let (sigma, angular) = diffusion(skeleton, config);
    let (lower, upper) = skeleton.limits();
    let mut start = initial_pose.to_vec();
    for d in 0..dims {
        start[d] = start[d].clamp(lower[d], upper[d]);
    }
    let batch = BatchConfig {
        shape,
        seed,
        sigma: sigma.clone(),
        bounds: Some((lower.clone(), upper.clone())),
        angular,
        ess_threshold: f64::INFINITY,
        best: 0,
        annealing: annealing(skeleton, config)?,
        motion: config.motion,
    };
    batch.validate()?;
    let mut states = gaussian_clouds(&shape, seed, &start, &sigma);
    // The initial cloud respects the joint limits too.
    for d in 0..dims {
        for m in 0..config.particles {
            let x = &mut states[shape.state_index(0, d, m)];
            *x = x.clamp(lower[d], upper[d]);
        }
    }
    let filter = match ctx {
        None => EngineFilter::on_cpu(
            &batch,
            ResamplerKind::Systematic,
            states,
            BodyModel { gpu: None },
        )?,
        Some(ctx) => {
            let gpu_config = BodyLikelihoodConfig {
                bones: skeleton.gpu_bones(),
                dims,
                points: config.max_points,
                origin: [0.0; 3],
                tau: config.tau,
                sigma: config.sigma_at_1000_points,
                coarse: super::coarse_layers(config),
            };
            let likelihood = BodyLikelihoodGpu::new(&ctx, gpu_config, config.particles)?;
            let model = BodyModel {
                gpu: Some(Box::new(likelihood)),
            };
            EngineFilter::on_gpu(ctx, &batch, GpuResampler::Systematic, &states, model)?
        }
    };
    Ok(Filter { filter })
}

/// Sample `m` of a single-target batch (`[d·M + m]`).
fn pose_of(poses: &[f32], particles: usize, skeleton: &Skeleton, m: usize) -> Vec<f32> {
    (0..skeleton.dofs())
        .map(|d| poses[d * particles + m])
        .collect()
}

/// A host filter step with the measurement `measure(poses, log_likelihood)`, its error kept.
/// The CPU engine's measure: every sample's log-likelihood on all cores (culled capsules).
fn host_log_likelihoods(
    skeleton: &Skeleton,
    rays: &Rays,
    params: CapsuleLikelihoodParams,
    poses: &[f32],
    out: &mut [f32],
) -> Result<(), BodyError> {
    let particles = out.len();
    out.par_iter_mut()
        .enumerate()
        .try_for_each(|(m, out)| -> Result<(), BodyError> {
            let theta = pose_of(poses, particles, skeleton, m);
            let capsules = skeleton.capsules(&theta)?;
            let sum = culled_sum_of_squared_distances(&capsules, rays, params.tau);
            *out = params.log_likelihood(sum) as f32;
            Ok(())
        })
}
