//! One particle filter over the pose θ on one engine (the CPU, or one GPU) and how it weighs:
//! the piece the tracker runs once, or once per island with several GPUs. A frame reaches it
//! prepared ([`crate::frame`]); on a GPU only the rays are uploaded.

use crate::skeleton::gpu::{BodyLikelihoodConfig, BodyLikelihoodGpu};
use pf_core::batch::{BatchConfig, BatchShape, gaussian_clouds};
use pf_core::random::part_seed;
use pf_gpu::engine::{EngineReport, FilterEngine};
use pf_gpu::{GpuContext, NoLikelihood, PendingStep};
use rayon::prelude::*;

use super::TrackerConfig;
use crate::error::BodyError;
use crate::likelihood::{CapsuleLikelihoodParams, Rays, culled_sum_of_squared_distances};
use crate::skeleton::{ROOT_DOFS, Skeleton};

/// How the particles are weighed, beside the filter's engine.
pub(crate) enum Measure {
    /// On the host, all cores (the CPU engine).
    Host,
    /// On the GPU, in the engine's submission (the GPU engine).
    Gpu(Box<BodyLikelihoodGpu>),
}

/// One particle filter over θ on one engine (the CPU, or one GPU), and how it weighs.
pub(crate) struct Filter {
    pub(crate) engine: FilterEngine,
    pub(crate) measure: Measure,
}

/// What one filter's step gives (an island's, with several GPUs): its estimate, the spread
/// about it and its effective sample size.
#[derive(Debug, Clone, PartialEq)]
pub struct FilterStep {
    pub pose: Vec<f32>,
    pub spread: Vec<f32>,
    pub ess: f64,
    /// M of the estimate (eq. 3's sum over the frame's points), when the GPU computed it in the
    /// step's submission; the host computes it otherwise.
    pub estimate_sum: Option<f64>,
    /// The step's own time on its GPU (timestamps where the adapter has them); `None` on the CPU.
    pub gpu_time: Option<pf_gpu::GpuTime>,
}

/// A frame as every filter weighs it.
pub(crate) struct Frame<'a> {
    pub(crate) rays: &'a Rays,
    /// The rays as the GPU likelihood uploads them (`None` on the CPU engine).
    pub(crate) gpu_rays: Option<&'a crate::likelihood::gpu::PreparedRays>,
    pub(crate) params: CapsuleLikelihoodParams,
    /// σ scaled to the frame's number of points.
    pub(crate) sigma: f32,
    pub(crate) flat: bool,
}

impl Filter {
    pub(crate) fn step(
        &mut self,
        skeleton: &Skeleton,
        frame: &Frame,
    ) -> Result<FilterStep, BodyError> {
        self.upload(frame)?;
        let Self { engine, measure } = self;
        let on_gpu: &dyn pf_gpu::GpuLikelihood = match &*measure {
            Measure::Gpu(likelihood) if !frame.flat => &**likelihood,
            _ => &NoLikelihood,
        };
        let report = engine.step(
            |_, poses, out| -> Result<(), BodyError> {
                match measure {
                    Measure::Host if !frame.flat => {
                        host_log_likelihoods(skeleton, frame.rays, frame.params, poses, out)
                    }
                    // A flat likelihood; the GPU engine never measures on the host.
                    _ => {
                        out.fill(0.0);
                        Ok(())
                    }
                }
            },
            on_gpu,
        )?;
        self.step_of(report, frame.flat)
    }

    /// On a GPU, uploads the frame and submits its step without waiting ([`Self::finish`] reads
    /// it back); `None` on the CPU engine, which steps with [`Self::step`].
    pub(crate) fn submit(&mut self, frame: &Frame) -> Result<Option<PendingStep>, BodyError> {
        if !matches!(self.measure, Measure::Gpu(_)) {
            return Ok(None);
        }
        self.upload(frame)?;
        let on_gpu: &dyn pf_gpu::GpuLikelihood = match &self.measure {
            Measure::Gpu(likelihood) if !frame.flat => &**likelihood,
            _ => &NoLikelihood,
        };
        Ok(self.engine.submit(on_gpu)?)
    }

    /// The step of a frame from [`Self::submit`], after waiting for it.
    pub(crate) fn finish(
        &mut self,
        pending: PendingStep,
        flat: bool,
    ) -> Result<FilterStep, BodyError> {
        let report = self.engine.finish(pending)?;
        self.step_of(report, flat)
    }

    /// A GPU filter's upload of a frame: its prepared rays and σ.
    fn upload(&mut self, frame: &Frame) -> Result<(), BodyError> {
        let Self { engine, measure } = self;
        if let (Measure::Gpu(likelihood), Some(ctx)) = (&mut *measure, engine.context()) {
            let rays = frame.gpu_rays.ok_or_else(|| {
                BodyError::InvalidInput("a GPU filter got a frame prepared for the CPU".into())
            })?;
            likelihood.upload_prepared_rays(ctx, rays)?;
            likelihood.set_sigma(ctx, frame.sigma)?;
        }
        Ok(())
    }

    /// The filter's step from its engine's report.
    fn step_of(&self, report: EngineReport, flat: bool) -> Result<FilterStep, BodyError> {
        if let Some(Err(e)) = report.status.into_iter().next() {
            return Err(e.into());
        }
        let estimate_sum = match &self.measure {
            Measure::Gpu(_) if !flat => {
                let sums: Vec<f32> = report.likelihood.get(BodyLikelihoodGpu::ESTIMATE_SUM)?;
                sums.first().map(|&m| f64::from(m))
            }
            _ => None,
        };
        Ok(FilterStep {
            pose: report.estimates,
            spread: report.spreads,
            ess: report.ess[0],
            estimate_sum,
            gpu_time: report.gpu_time,
        })
    }
}

/// Island `island`'s seed: island 0 keeps the tracker's (so one island is the one-GPU filter).
pub(crate) fn island_seed(seed: u64, island: usize) -> u64 {
    part_seed(seed, island)
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
    let mut sigma = vec![config.joint_sigma; dims];
    sigma[..3].fill(config.translation_sigma);
    sigma[3..ROOT_DOFS].fill(config.rotation_sigma);
    let mut angular = vec![false; dims];
    angular[3..ROOT_DOFS].fill(true);
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
        annealing: if config.partitioned {
            super::partitioned_schedule(skeleton, &config.annealing)?
        } else {
            config.annealing.clone()
        },
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
    Ok(match ctx {
        None => Filter {
            engine: FilterEngine::cpu(&batch, states)?,
            measure: Measure::Host,
        },
        Some(ctx) => {
            let gpu_config = BodyLikelihoodConfig {
                bones: skeleton.gpu_bones(),
                dims,
                points: config.max_points,
                origin: [0.0; 3],
                tau: config.tau,
                sigma: config.sigma_at_1000_points,
            };
            let mut likelihood = BodyLikelihoodGpu::new(&ctx, gpu_config, config.particles)?;
            let engine = FilterEngine::gpu(ctx, &batch, &states)?;
            if let Some((ctx, inputs)) = engine.likelihood_inputs() {
                pf_gpu::GpuLikelihood::prepare(&mut likelihood, ctx, &inputs)?;
            }
            Filter {
                engine,
                measure: Measure::Gpu(Box::new(likelihood)),
            }
        }
    })
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
