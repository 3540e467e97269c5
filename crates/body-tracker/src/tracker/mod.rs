//! The body tracker: a particle filter over the pose θ weighed by the ray-cast capsule
//! likelihood, with the weighted-mean pose (eq. 1) as the estimate.
//!
//! Three engines, one filter (the batch filter of pf-core and its GPU twin draw the same random
//! numbers, so they follow the same law):
//! - [`Backend::Cpu`]: `pf_core::batch::BatchFilter`, the likelihood on all cores;
//! - [`Backend::Gpu`]: the whole step on one GPU (`pf_gpu::GpuFilter` with forward kinematics and
//!   the likelihood on the GPU): a frame uploads only its rays;
//! - [`Backend::SplitGpus`]: an island of the samples on each GPU, each island the whole step of
//!   its own filter on its GPU, all islands stepping at once; only their estimates meet on the
//!   host, where they are combined and, every few frames, the islands exchange particles
//!   ([`islands`]).
//!
//! Diffusion is a Gaussian random walk, clamped to the joint limits; the root's rotations are
//! angles (wrapped, averaged on the circle). Each frame runs eight annealing layers by default
//! (`TrackerConfig::annealing`, `pf_core::anneal`): 1 000 random-walk samples in 38 dimensions are
//! too thin to follow a waving forearm in one weighing.

use nalgebra::Vector3;
use pf_core::anneal::Annealing;
use pf_core::batch::{BatchShape, Motion};
use pf_gpu::GpuContext;

use crate::error::BodyError;

mod filter;
pub mod islands;
mod lag_window;

use crate::frame::{FramePreparer, PreparedFrame};
use crate::likelihood::{
    CapsuleLikelihoodParams, CoarseLayers, culled_sum_of_squared_distances_parallel,
};
use crate::skeleton::Skeleton;
pub use filter::FilterStep;
use filter::{CoarseFrame, Filter, Frame, new_filter};

/// The default coarse layers' subset: at most this many points (every k-th of a frame).
pub const DEFAULT_COARSE_POINTS: usize = 5_000;
/// The default number of coarse annealing layers, from the first.
pub const DEFAULT_COARSE_LAYERS: usize = 7;

/// Where the filter and the likelihood run.
pub enum Backend {
    Cpu,
    Gpu(Box<GpuContext>),
    /// One island filter per GPU ([`islands`]); the samples are split among them.
    SplitGpus(Vec<GpuContext>),
}

impl Backend {
    pub fn describe(&self) -> String {
        match self {
            Backend::Cpu => format!("CPU ({} threads)", rayon::current_num_threads()),
            Backend::Gpu(ctx) => format!("GPU: {}", ctx.adapter().name),
            Backend::SplitGpus(contexts) => format!(
                "{} GPUs, an island of the samples on each: {}",
                contexts.len(),
                contexts
                    .iter()
                    .map(|c| c.adapter().name.clone())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        }
    }
}

/// What weighs the particles.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Weighing {
    /// The ray-cast capsule likelihood (eq. 3).
    Capsules,
    /// Every particle weighs the same: the filter only diffuses. The baseline a real likelihood
    /// must beat.
    Flat,
}

/// The tracker's settings.
#[derive(Debug, Clone, PartialEq)]
pub struct TrackerConfig {
    /// Pose samples J.
    pub particles: usize,
    /// τ of eq. 6 (m).
    pub tau: f32,
    /// σ of eq. 3 (m) for a frame of 1 000 points. For I points the tracker uses
    /// σ·√(I/1000): M sums I terms, so this keeps the spread of the log-weights, and the
    /// effective sample size, independent of the point density.
    pub sigma_at_1000_points: f32,
    /// Diffusion σ per frame: root translation (m), root rotation (rad), joint angles (rad).
    pub translation_sigma: f32,
    pub rotation_sigma: f32,
    pub joint_sigma: f32,
    /// Frames with more points are thinned to at most this many (every k-th point).
    pub max_points: usize,
    pub seed: u64,
    pub weighing: Weighing,
    /// Annealing layers per frame (`pf_core::anneal`): each resamples, diffuses with the σ above
    /// shrunk by the decay per layer and weighs with the likelihood raised to β.
    pub annealing: Annealing,
    /// The dynamics' drift before the random walk (`pf_core::batch::Motion`).
    pub motion: Motion,
    /// Partitioned sampling ([`partitioned_schedule`]): the first half of the annealing layers
    /// diffuse only the trunk, the second half only the limbs ([`Skeleton::trunk_and_limbs`]).
    pub partitioned: bool,
    /// Coarse-to-fine annealing ([`CoarseLayers`]): the first layers of a frame weigh a subset
    /// of its points, the last ones every point; `None`: every layer weighs every point.
    pub coarse: Option<CoarseLayers>,
    /// With islands ([`Backend::SplitGpus`]): every this many frames the islands exchange
    /// particles ([`islands::exchange`]); 0 never.
    pub island_exchange_every: u64,
}

impl Default for TrackerConfig {
    fn default() -> Self {
        Self {
            // With eight layers, 1 500 samples kept the default walk-wave under 4 cm on every
            // seed tried (3.2–3.7 cm; 1 000: 3.5–4.2 cm) at 155 frames/s on an H100.
            particles: 1500,
            tau: 0.1,
            sigma_at_1000_points: 0.3,
            translation_sigma: 0.02,
            rotation_sigma: 0.03,
            joint_sigma: 0.08,
            max_points: 20_000,
            seed: 1,
            weighing: Weighing::Capsules,
            // Chosen by a sweep on the synthetic walk-wave at 160×120 (docs/ACCURACY.md): eight
            // layers keeping half the samples effective, the noise shrinking ×0.7 a layer, took
            // the mean joint error of 1 000 samples from 10.1 cm (one layer) to 3.5–4.2 cm.
            annealing: Annealing::survival(8, 0.5, 0.7),
            motion: Motion::RandomWalk,
            // Partitioned: the trunk's four layers, then the limbs' four. On the walk-wave
            // (docs/ACCURACY.md, H100, three seeds) it kept the error of eight plain layers
            // (3.4-3.7 cm at 160x120, 3.2-3.4 cm at 1024x768) at the same rate and took the
            // truth's coverage at ±2 reported sd from 52-61 % to 74-78 %.
            partitioned: true,
            coarse: Some(CoarseLayers {
                points: DEFAULT_COARSE_POINTS,
                layers: DEFAULT_COARSE_LAYERS,
            }),
            island_exchange_every: islands::DEFAULT_EXCHANGE_EVERY,
        }
    }
}

/// One frame's result.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameResult {
    /// The weighted-mean pose (eq. 1).
    pub pose: Vec<f32>,
    /// The posterior's spread per pose value: the weighted standard deviation of the samples
    /// about the mean (m, rad), circular for the root's rotations.
    pub spread: Vec<f32>,
    /// The effective sample size after weighing (of the last annealing layer).
    pub ess: f64,
    /// The frame's log evidence, log p̂(frame | earlier frames) up to the likelihood's constant:
    /// the filter's first weighing at β = 1 (with coarse layers, of the first layer's subset of
    /// the points); with islands, the log of the islands' mean evidence
    /// (`pf_core::islands::pooled_log_evidence`).
    pub log_evidence: f64,
    /// How much of the frame the estimated body explains, in [0, 1]: 1 − M / (I·τ²), M the sum
    /// of eq. 3's truncated squared distances of the I points from the estimate's capsules. 1:
    /// every point on a capsule's surface; 0: every point τ or more from the body.
    pub confidence: f32,
    /// Points used (after thinning).
    pub points: usize,
    /// With islands ([`Backend::SplitGpus`]): each island's weight in the estimate (they sum to
    /// 1; [`islands::combine`]). Empty with one filter.
    pub island_weights: Vec<f64>,
}

/// The tracker: a filter over θ on one engine, or one island filter per GPU.
pub struct BodyTracker {
    skeleton: Skeleton,
    config: TrackerConfig,
    /// One filter, or the islands (one per GPU).
    filters: Vec<Filter>,
    /// Frames stepped.
    frames: u64,
    /// The islands' weights at the last frame (empty with one filter).
    island_weights: Vec<f64>,
    /// The last frame a lag behind, smoothed on the GPU ([`Self::keep_lag_window`]).
    last_lagged: Option<pf_core::smooth::lag_window::LaggedSummaries>,
    /// The last frame's GPU time (the slowest island's); `None` on the CPU.
    last_gpu_time: Option<pf_gpu::GpuTime>,
    /// Frames submitted and not yet finished, oldest first.
    in_flight: std::collections::VecDeque<InFlight>,
}

impl BodyTracker {
    /// A tracker whose particles start around `initial_pose` (spread by one frame's diffusion).
    pub fn new(
        skeleton: Skeleton,
        initial_pose: &[f32],
        config: TrackerConfig,
        backend: Backend,
    ) -> Result<Self, BodyError> {
        CapsuleLikelihoodParams::new(config.tau, config.sigma_at_1000_points)?;
        if config.max_points == 0 {
            return Err(BodyError::InvalidInput(
                "max points per frame must be > 0".into(),
            ));
        }
        if let Some(coarse) = &config.coarse {
            coarse.validate()?;
        }
        // Checks the pose's length and values.
        skeleton.capsules(initial_pose)?;
        let filters = match backend {
            Backend::Cpu => vec![new_filter(&skeleton, &config, initial_pose, None, 0)?],
            Backend::Gpu(ctx) => {
                vec![new_filter(&skeleton, &config, initial_pose, Some(*ctx), 0)?]
            }
            Backend::SplitGpus(contexts) => {
                let sizes = islands::island_sizes(config.particles, contexts.len())?;
                contexts
                    .into_iter()
                    .zip(sizes)
                    .enumerate()
                    .map(|(island, (ctx, particles))| {
                        let config = TrackerConfig {
                            particles,
                            ..config.clone()
                        };
                        new_filter(&skeleton, &config, initial_pose, Some(ctx), island)
                    })
                    .collect::<Result<_, _>>()?
            }
        };
        Ok(Self {
            skeleton,
            config,
            filters,
            frames: 0,
            island_weights: Vec::new(),
            last_gpu_time: None,
            last_lagged: None,
            in_flight: std::collections::VecDeque::new(),
        })
    }

    pub fn skeleton(&self) -> &Skeleton {
        &self.skeleton
    }

    /// The dynamics' density for smoothing (`pf_core::smooth`): the random walk of a whole
    /// frame's annealing layers per pose value, the root's rotations the angles.
    pub fn transition(&self) -> Result<pf_core::smooth::GaussianTransition, BodyError> {
        let (sigma, angular) = filter::diffusion(&self.skeleton, &self.config);
        let sigma = filter::annealing(&self.skeleton, &self.config)?.frame_sigma(&sigma);
        Ok(pf_core::smooth::GaussianTransition { sigma, angular })
    }

    /// The constant-velocity gain of the dynamics (0 for the random walk).
    pub fn motion_gain(&self) -> f32 {
        self.config.motion.gain()
    }

    /// The particles after the last step: the batch shape (1 × J × θ's length), the poses in the
    /// batch layout `[d·J + j]` and the normalised log-weights (islands' particles one after
    /// another, each island's weights times its island weight). On the GPU this reads them back
    /// (a wait), so call it only when needed, and not while frames are in flight (whose
    /// particles are not the last finished frame's).
    pub fn particles(&self) -> Result<(BatchShape, Vec<f32>, Vec<f32>), BodyError> {
        if !self.in_flight.is_empty() {
            return Err(BodyError::InvalidInput(
                "the particles of a finished frame: frames are still in flight".into(),
            ));
        }
        if let [filter] = self.filters.as_slice() {
            return Ok(filter.engine().particles()?);
        }
        let islands = self
            .filters
            .iter()
            .map(|f| f.engine().particles())
            .collect::<Result<Vec<_>, _>>()?;
        Ok(islands::joined_particles(&islands, &self.island_weights)?)
    }

    /// The annealing layers of a frame (each resamples).
    pub fn annealing_layers(&self) -> Result<usize, BodyError> {
        Ok(filter::annealing(&self.skeleton, &self.config)?.layers)
    }

    /// The last frame's own time on the GPU (the slowest island's with several; GPU timestamps
    /// where the adapter has them, the step's wall clock otherwise); `None` on the CPU engine.
    pub fn last_gpu_time(&self) -> Option<pf_gpu::GpuTime> {
        self.last_gpu_time
    }

    /// The GPU the filter runs on (the first island's with several; `None` on the CPU engine).
    pub fn gpu_context(&self) -> Option<&pf_gpu::GpuContext> {
        self.filters.first().and_then(|f| f.engine().context())
    }

    /// What prepares this tracker's frames ([`FramePreparer::prepare`]): on any thread, for
    /// example a reader's, while the tracker steps the previous frame.
    pub fn preparer(&self) -> FramePreparer {
        FramePreparer {
            max_points: self.config.max_points,
            on_gpu: self.filters.iter().any(|f| f.on_gpu()),
            coarse: coarse_layers(&self.config),
        }
    }

    /// One frame: predict, weigh against `points` (camera frame, camera at the origin), estimate.
    /// The same as [`Self::preparer`]'s `prepare` then [`Self::step_prepared`].
    pub fn step(&mut self, points: &[Vector3<f32>]) -> Result<FrameResult, BodyError> {
        let frame = self.preparer().prepare(points)?;
        self.step_prepared(&frame)
    }

    /// One frame prepared by this tracker's [`Self::preparer`] (a frame from another tracker's
    /// preparer is an error): predict, weigh, estimate. Not while frames are in flight
    /// ([`Self::submit_prepared`]).
    pub fn step_prepared(&mut self, prepared: &PreparedFrame) -> Result<FrameResult, BodyError> {
        if !self.in_flight.is_empty() {
            return Err(BodyError::InvalidInput(
                "frames are in flight: finish them before stepping another".into(),
            ));
        }
        self.step_now(prepared)
    }

    /// Starts a frame without waiting for it: on one GPU the frame's step is submitted and the
    /// host is free to prepare the next frame or read the one before ([`Self::finish`]), so that
    /// the GPU goes from one frame's step to the next without a round trip between. At most two
    /// frames are in flight. The results are those of [`Self::step_prepared`], bit for bit, in
    /// the order submitted. The CPU engine and the islands of several GPUs step the frame here
    /// and hand its result over at [`Self::finish`].
    pub fn submit_prepared(&mut self, prepared: PreparedFrame) -> Result<(), BodyError> {
        self.check_prepared(&prepared)?;
        if self.in_flight.len() >= 2 {
            return Err(BodyError::InvalidInput(
                "two frames are in flight already: finish one first".into(),
            ));
        }
        let work = match self.filters.as_mut_slice() {
            [filter] if filter.on_gpu() => {
                let frame = frame_of(&self.config, &prepared)?;
                match filter.submit(&self.skeleton, &frame)? {
                    Some(pending) => Submitted::Gpu(pending),
                    None => Submitted::Done(self.step_now(&prepared)),
                }
            }
            _ => Submitted::Done(self.step_now(&prepared)),
        };
        self.in_flight.push_back(InFlight {
            frame: prepared,
            work,
        });
        Ok(())
    }

    /// The result of the oldest frame in flight, after waiting for it; `None` when no frame is.
    pub fn finish(&mut self) -> Result<Option<FrameResult>, BodyError> {
        let Some(InFlight { frame, work }) = self.in_flight.pop_front() else {
            return Ok(None);
        };
        match work {
            Submitted::Done(result) => result.map(Some),
            Submitted::Gpu(pending) => {
                let flat = self.config.weighing == Weighing::Flat;
                let step = self.filters[0].finish(pending, flat)?;
                let weighed = frame_of(&self.config, &frame)?;
                self.result_of(vec![step], &weighed).map(Some)
            }
        }
    }

    /// Frames submitted and not yet finished.
    pub fn frames_in_flight(&self) -> usize {
        self.in_flight.len()
    }

    fn check_prepared(&self, prepared: &PreparedFrame) -> Result<(), BodyError> {
        if prepared.preparer != self.preparer() {
            return Err(BodyError::InvalidInput(format!(
                "a frame prepared for another tracker ({:?}; this one prepares {:?})",
                prepared.preparer,
                self.preparer()
            )));
        }
        Ok(())
    }

    /// One frame, waited for.
    fn step_now(&mut self, prepared: &PreparedFrame) -> Result<FrameResult, BodyError> {
        self.check_prepared(prepared)?;
        let frame = frame_of(&self.config, prepared)?;
        let skeleton = &self.skeleton;
        let steps: Vec<FilterStep> = match self.filters.as_mut_slice() {
            [filter] => vec![filter.step(skeleton, &frame)?],
            // Every island steps at once, each on its own GPU.
            islands => std::thread::scope(|scope| {
                let running: Vec<_> = islands
                    .iter_mut()
                    .map(|island| scope.spawn(|| island.step(skeleton, &frame)))
                    .collect();
                running
                    .into_iter()
                    .map(|r| {
                        r.join().map_err(|_| {
                            BodyError::InvalidInput("an island's thread panicked".into())
                        })?
                    })
                    .collect::<Result<Vec<_>, BodyError>>()
            })?,
        };
        self.result_of(steps, &frame)
    }

    /// The frame's result from its filters' steps: one filter's, or the islands' combined (and,
    /// when due, their exchange of particles).
    fn result_of(
        &mut self,
        steps: Vec<FilterStep>,
        frame: &Frame<'_>,
    ) -> Result<FrameResult, BodyError> {
        let rays = frame.rays;
        let points = rays.depths.len();
        self.frames += 1;
        self.last_gpu_time = steps
            .iter()
            .filter_map(|s| s.gpu_time)
            .max_by_key(|t| t.duration());
        let tau = self.config.tau;
        let log_evidence = pf_core::islands::pooled_log_evidence(
            &steps.iter().map(|s| s.log_evidence).collect::<Vec<_>>(),
        );
        self.last_lagged = match steps.as_slice() {
            [one] => one.lagged.clone(),
            _ => None,
        };
        let (pose, spread, ess, fit) = if let [one] = steps.as_slice() {
            (
                one.pose.clone(),
                one.spread.clone(),
                one.ess,
                one.estimate_sum,
            )
        } else {
            let combined = islands::combine(&self.skeleton, rays, frame.params, &steps)?;
            self.island_weights = combined.weights.clone();
            if islands::exchange_due(self.config.island_exchange_every, self.frames) {
                islands::exchange(
                    &mut self
                        .filters
                        .iter_mut()
                        .map(|f| f.engine_mut())
                        .collect::<Vec<_>>(),
                    &combined.weights,
                    self.config.seed ^ self.frames,
                )?;
            }
            // The combined pose is none of the islands' estimates: weighed on the host.
            (combined.pose, combined.spread, combined.ess, None)
        };
        let fit = match fit {
            Some(sum) => sum,
            None => {
                culled_sum_of_squared_distances_parallel(&self.skeleton.capsules(&pose)?, rays, tau)
            }
        };
        let confidence = 1.0 - fit / (points.max(1) as f64 * f64::from(tau * tau));
        Ok(FrameResult {
            pose,
            spread,
            ess,
            log_evidence,
            confidence: confidence.clamp(0.0, 1.0) as f32,
            points,
            island_weights: self.island_weights.clone(),
        })
    }
}

/// The configuration's coarse layers within its annealing layers (the last weighs every point).
pub(crate) fn coarse_layers(config: &TrackerConfig) -> Option<CoarseLayers> {
    config
        .coarse
        .and_then(|c| c.within(config.annealing.layers))
}

/// A frame as the filters weigh it: its rays, and σ of eq. 3 scaled to its number of points.
fn frame_of<'a>(
    config: &TrackerConfig,
    prepared: &'a PreparedFrame,
) -> Result<Frame<'a>, BodyError> {
    let sigma_for =
        |points: usize| config.sigma_at_1000_points * (points.max(1) as f32 / 1000.0).sqrt();
    let sigma = sigma_for(prepared.rays.depths.len());
    // The coarse layers' σ, scaled to their subset's points as a frame's is to its own.
    let coarse = match (
        coarse_layers(config),
        &prepared.gpu_rays,
        &prepared.coarse_rays,
    ) {
        (None, ..) => None,
        (Some(_), Some(gpu), _) => {
            let points = gpu.levels().get(1).map_or(0, |l| l.points);
            Some(CoarseFrame {
                rays: None,
                sigma: sigma_for(points),
            })
        }
        (Some(_), None, rays) => rays.as_ref().map(|rays| CoarseFrame {
            rays: Some(rays),
            sigma: sigma_for(rays.depths.len()),
        }),
    };
    Ok(Frame {
        rays: &prepared.rays,
        gpu_rays: prepared.gpu_rays.as_ref(),
        params: CapsuleLikelihoodParams::new(config.tau, sigma)?,
        sigma,
        coarse,
        coarse_layers: coarse_layers(config).map_or(0, |c| c.layers),
        flat: config.weighing == Weighing::Flat,
    })
}

/// A frame submitted by [`BodyTracker::submit_prepared`].
struct InFlight {
    frame: PreparedFrame,
    work: Submitted,
}

/// How far a frame in flight has got.
enum Submitted {
    /// On the GPU; its results are read at `finish`.
    Gpu(pf_gpu::engine::InFlight),
    /// Stepped already (the CPU engine, or islands).
    Done(Result<FrameResult, BodyError>),
}

/// Partitioned sampling over the skeleton's tree (MacCormick & Isard, ECCV 2000; the
/// hierarchical search of Deutscher & Reid, IJCV 2005): `annealing`'s first ⌈L/2⌉ layers diffuse
/// only the trunk (the root first), the other layers only the limbs, each partition's noise
/// shrinking from the full σ (`pf_core::anneal::Annealing::sigma_scale`). One layer has nothing
/// to partition: the schedule stays the plain step. A skeleton without limbs is an error.
pub fn partitioned_schedule(
    skeleton: &Skeleton,
    annealing: &Annealing,
) -> Result<Annealing, BodyError> {
    let layers = annealing.layers;
    if layers < 2 {
        return Ok(annealing.clone());
    }
    let (trunk, limbs) = skeleton.trunk_and_limbs();
    if limbs.is_empty() {
        return Err(BodyError::InvalidInput(
            "partitioned sampling needs a skeleton with limbs (bones below its last branch)".into(),
        ));
    }
    let trunk_layers = layers.div_ceil(2);
    let diffused = (0..layers)
        .map(|l| {
            if l < trunk_layers {
                trunk.clone()
            } else {
                limbs.clone()
            }
        })
        .collect();
    Ok(annealing.clone().partitioned(diffused))
}

/// The mean distance (m) between the tracked joints of two poses.
pub fn mean_joint_error(
    skeleton: &Skeleton,
    estimate: &[f32],
    truth: &[f32],
) -> Result<f32, BodyError> {
    let a = skeleton.tracked_joint_positions(estimate)?;
    let b = skeleton.tracked_joint_positions(truth)?;
    Ok(a.iter().zip(&b).map(|(p, q)| (p - q).norm()).sum::<f32>() / a.len() as f32)
}
