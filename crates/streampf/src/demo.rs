//! `streampf demo`: synthetic 7-D pose targets (Tx, Ty, S, Rx, Ry, Rz, α — the face tracker's
//! state) observed with noise and tracked with the face tracker's random-walk diffusion by the
//! engine's one `Filter` over the toy plug-in model (`pf_gpu::toy`), on the CPU (all cores) or on
//! the GPU (one submission per frame for all targets), with the same random numbers. The yaw Ry
//! turns full circles, so the run also shows angle estimates crossing ±π.

use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use clap::Args;
use nalgebra::{SVector, vector};
use pf_core::batch::{BatchConfig, BatchShape, gaussian_clouds};
use pf_core::{RandomStream, RandomStreams, ResamplerKind, Stage, StateSpace};
use pf_gpu::engine::Filter;
use pf_gpu::model::Plugin;
use pf_gpu::toy::{TOY_MODEL, ToyConstants, ToyObservation, ToyTwin};
use pf_gpu::{ContextOptions, GpuContext, GpuResampler};

type Pose = SVector<f32, 7>;

/// The rotation dimensions Rx, Ry, Rz.
const ANGLES: [usize; 3] = [3, 4, 5];

#[derive(Debug, Clone, Args)]
pub struct DemoArgs {
    /// Number of frames to track.
    #[arg(long, default_value_t = 100, value_parser = clap::value_parser!(u32).range(1..=1_000_000))]
    pub steps: u32,
    /// Particles per target.
    #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u32).range(1..=10_000_000))]
    pub particles: u32,
    /// Number of targets tracked at once.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=65_535))]
    pub targets: u32,
    /// Seed of every random number of the run (the sequence and the filter).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Resampler: multinomial, stratified, systematic, residual, metropolis or rejection (the GPU
    /// runs systematic, stratified and metropolis).
    #[arg(long, default_value = "systematic")]
    pub resampler: ResamplerKind,
    /// Resample only when ESS/N falls below this fraction (default: every step).
    #[arg(long)]
    pub ess_threshold: Option<f64>,
    /// Run the whole filter step on the GPU.
    #[arg(long)]
    pub gpu: bool,
    /// With --gpu: accept a software adapter (Mesa's lavapipe) when there is no GPU.
    #[arg(long, requires = "gpu")]
    pub allow_software: bool,
    /// Print only the summary.
    #[arg(long)]
    pub quiet: bool,
}

/// Target `k`'s ground-truth pose at frame `t`: a head drifting over a 1024×768 frame and turning.
fn truth(k: u32, t: u32) -> Pose {
    let (k, t) = (k as f32, t as f32);
    vector![
        512.0 + 100.0 * (0.02 * t + k).sin(),
        384.0 + 60.0 * (0.03 * t + 0.5 * k).cos(),
        1.0 + 0.2 * (0.03 * t).sin(),
        0.3 * (0.04 * t).sin(),
        pf_core::estimate::wrap_angle(0.02 * t + 0.7 * k),
        0.2 * (0.05 * t).sin(),
        1.0 + 0.1 * (0.02 * t).sin()
    ]
}

/// Observation noise per dimension (px, px, scale, rad, rad, rad, gain).
fn observation_sigma() -> Pose {
    vector![10.0, 10.0, 0.05, 0.1, 0.1, 0.1, 0.05]
}

/// Diffusion per step: about the path's largest per-frame motion, so that the cloud keeps up.
fn diffusion_sigma() -> Pose {
    vector![3.0, 3.0, 0.005, 0.01, 0.03, 0.01, 0.003]
}

fn errors(space: &StateSpace<7>, estimate: &Pose, truth: &Pose) -> (f32, f32) {
    let d = space.difference(estimate, truth);
    let translation = (d[0] * d[0] + d[1] * d[1]).sqrt();
    let rotation = d[3].abs().max(d[4].abs()).max(d[5].abs()).to_degrees();
    (translation, rotation)
}

/// One frame's estimates and ESS per target.
struct Frame {
    estimates: Vec<Pose>,
    ess: Vec<f64>,
    resampled: usize,
}

/// The toy model (a Gaussian about each target's observation) on either engine.
type ToyPlugin = Plugin<ToyObservation, ToyConstants, ToyTwin>;

/// Every target's filter: the engine's one `Filter` over the toy model, on the CPU (all cores)
/// or the GPU; the two draw the same random numbers.
struct Trackers {
    filter: Filter<ToyPlugin>,
}

impl Trackers {
    fn new(args: &DemoArgs, ess_threshold: f64, space: StateSpace<7>) -> anyhow::Result<Self> {
        let start_sigma = observation_sigma() * 2.0;
        let shape = BatchShape::new(args.targets as usize, args.particles as usize, 7)?;
        let mut config = BatchConfig::new(shape, args.seed, diffusion_sigma().as_slice().to_vec());
        config.angular = space.angular.to_vec();
        config.ess_threshold = ess_threshold;
        let means: Vec<f32> = (0..args.targets)
            .flat_map(|k| truth(k, 0).as_slice().to_vec())
            .collect();
        let initial = gaussian_clouds(&shape, args.seed, &means, start_sigma.as_slice());
        let sigma: [f32; 7] = observation_sigma().into();
        let constants = ToyConstants::from_sigma(&sigma)?;
        let twin = ToyTwin {
            angular: space.angular,
        };
        if !args.gpu {
            let model = Plugin::cpu(twin, constants);
            let filter = Filter::on_cpu(&config, args.resampler, initial, model)
                .context("building the filter")?;
            return Ok(Self { filter });
        }
        let resampler = GpuResampler::for_kind(args.resampler).context("--resampler")?;
        let options = ContextOptions {
            allow_software: args.allow_software,
            ..ContextOptions::default()
        };
        let ctx = GpuContext::new(&options).context("opening the GPU (see `streampf devices`)")?;
        let model = Plugin::gpu(&ctx, TOY_MODEL, &shape, twin, constants)?;
        let filter = Filter::on_gpu(ctx, &config, resampler, &initial, model)
            .context("building the GPU filter")?;
        Ok(Self { filter })
    }

    fn device(&self) -> String {
        match self.filter.context() {
            None => format!("CPU ({} threads)", rayon::current_num_threads()),
            Some(ctx) => format!("GPU: {} ({})", ctx.adapter().name, ctx.adapter().backend),
        }
    }

    /// One frame for every target; returns the frame and the GPU's own timing when there is one.
    fn step(&mut self, observed: &[Pose]) -> anyhow::Result<(Frame, Option<pf_gpu::GpuTime>)> {
        let observations: Vec<ToyObservation> = (observed.iter())
            .map(|z| ToyObservation { z: (*z).into() })
            .collect();
        let report = self.filter.step(&observations)?;
        for (k, status) in report.status.iter().enumerate() {
            status.clone().with_context(|| format!("target {k}"))?;
        }
        let frame = Frame {
            estimates: report
                .estimates
                .chunks(7)
                .map(Pose::from_column_slice)
                .collect(),
            ess: report.ess,
            resampled: report.resampled.iter().filter(|&&r| r).count(),
        };
        Ok((frame, report.gpu_time))
    }
}

fn observe(k: u32, t: u32, noise: &mut RandomStream, space: &StateSpace<7>) -> Pose {
    let sigma = observation_sigma();
    let mut z = truth(k, t) + Pose::from_fn(|d, _| sigma[d] * noise.gaussian_f32());
    space.wrap(&mut z);
    z
}

/// The most particles a demo holds in all (about 8 GB of host memory at ~80 bytes each): a
/// larger run is refused before it allocates rather than aborted by the allocator.
const MAX_TOTAL_PARTICLES: u64 = 100_000_000;

/// The errors of a run, summed over steps (each step's the mean over its targets).
#[derive(Default)]
struct Tally {
    translation: f32,
    rotation: f32,
    max_translation: f32,
    max_rotation: f32,
    observed_translation: f32,
    observed_rotation: f32,
}

impl Tally {
    /// Adds step `t`'s errors; its mean translation and rotation errors and the observations'
    /// translation error.
    fn add_step(
        &mut self,
        space: &StateSpace<7>,
        t: u32,
        estimates: &[Pose],
        observed: &[Pose],
    ) -> (f32, f32, f32) {
        let n = estimates.len() as f32;
        let (mut step_t, mut step_r, mut step_obs_t) = (0.0, 0.0, 0.0);
        for (k, (estimate, seen)) in estimates.iter().zip(observed).enumerate() {
            let x = truth(k as u32, t);
            let (et, er) = errors(space, estimate, &x);
            let (obs_t, obs_r) = errors(space, seen, &x);
            step_t += et / n;
            step_r += er / n;
            step_obs_t += obs_t / n;
            self.observed_rotation += obs_r / n;
            self.max_translation = self.max_translation.max(et);
            self.max_rotation = self.max_rotation.max(er);
        }
        self.translation += step_t;
        self.rotation += step_r;
        self.observed_translation += step_obs_t;
        (step_t, step_r, step_obs_t)
    }

    fn print_summary(&self, steps: u32) {
        let n = steps as f32;
        outln!(
            "summary: mean translation error {:.2} px (max {:.2}), mean rotation error {:.2} deg (max {:.2}); \
             the raw observations were off by {:.2} px and {:.2} deg on average",
            self.translation / n,
            self.max_translation,
            self.rotation / n,
            self.max_rotation,
            self.observed_translation / n,
            self.observed_rotation / n
        );
    }
}

/// The ESS fraction below which a target resamples (`--ess-threshold`; infinity: every step),
/// after the run's size is checked.
fn checked_ess_threshold(args: &DemoArgs) -> anyhow::Result<f64> {
    let total = u64::from(args.targets) * u64::from(args.particles);
    if total > MAX_TOTAL_PARTICLES {
        bail!(
            "--targets {} x --particles {} is {total} particles in all; the demo holds at most {MAX_TOTAL_PARTICLES} (about 80 bytes each): fewer targets or particles",
            args.targets,
            args.particles
        );
    }
    Ok(match args.ess_threshold {
        None => f64::INFINITY,
        Some(f) if f > 0.0 && f <= 1.0 => f,
        Some(f) => bail!("--ess-threshold must be a fraction in (0, 1], got {f}"),
    })
}

pub fn run(args: &DemoArgs) -> anyhow::Result<()> {
    let ess_threshold = checked_ess_threshold(args)?;
    let space = StateSpace::with_angles(&ANGLES)?;
    let mut trackers = Trackers::new(args, ess_threshold, space)?;
    // The sequence's noise has its own stream per target, apart from the filters'.
    let streams = RandomStreams::new(args.seed);
    let mut noise: Vec<RandomStream> = (0..args.targets)
        .map(|k| streams.stream(k, Stage::Model(0)))
        .collect();

    outln!(
        "streampf demo: {} 7-D pose target(s) x {} particles, {} resampling, {} steps, seed {}, on {}",
        args.targets,
        args.particles,
        args.resampler,
        args.steps,
        args.seed,
        trackers.device()
    );
    if !args.quiet {
        outln!("step  transl.err(px)  rot.err(deg)  obs.transl.err(px)  mean ESS  resampled");
    }
    let mut tally = Tally::default();
    let mut gpu_time = Duration::ZERO;
    let mut gpu_time_source = "";
    let start = Instant::now();
    for t in 0..args.steps {
        let observed: Vec<Pose> = (0..args.targets)
            .map(|k| observe(k, t, &mut noise[k as usize], &space))
            .collect();
        let (frame, time) = trackers
            .step(&observed)
            .with_context(|| format!("step {t}"))?;
        if let Some(time) = time {
            gpu_time += time.duration();
            gpu_time_source = time.source();
        }
        let (step_t, step_r, step_obs_t) = tally.add_step(&space, t, &frame.estimates, &observed);
        if !args.quiet {
            let mean_ess = frame.ess.iter().sum::<f64>() / frame.ess.len() as f64;
            outln!(
                "{t:4}  {step_t:14.2}  {step_r:12.2}  {step_obs_t:18.2}  {mean_ess:8.1}  {}/{}",
                frame.resampled,
                args.targets
            );
        }
    }
    let elapsed = start.elapsed();
    tally.print_summary(args.steps);
    let per_step_ms = elapsed.as_secs_f64() * 1e3 / f64::from(args.steps);
    match trackers.filter.context() {
        None => outln!(
            "         {per_step_ms:.3} ms per step on the CPU, all targets ({} steps in {:.2} s, observation synthesis included)",
            args.steps,
            elapsed.as_secs_f64()
        ),
        Some(_) => outln!(
            "         {per_step_ms:.3} ms per step on the host, {:.3} ms of it the GPU step ({gpu_time_source}), all targets ({} steps in {:.2} s)",
            gpu_time.as_secs_f64() * 1e3 / f64::from(args.steps),
            args.steps,
            elapsed.as_secs_f64()
        ),
    }
    Ok(())
}
