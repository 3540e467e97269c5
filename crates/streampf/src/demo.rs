//! `streampf demo`: a synthetic 7-D pose target (Tx, Ty, S, Rx, Ry, Rz, α — the face tracker's
//! state) observed with noise and tracked by pf-core with the face tracker's random-walk
//! diffusion. The yaw Ry turns full circles, so the run also shows angle estimates crossing ±π.

use std::time::Instant;

use anyhow::{Context, bail};
use clap::Args;
use nalgebra::{SVector, vector};
use pf_core::{
    FilterConfig, GaussianDiffusion, GaussianObservation, ParticleFilter, RandomStreams,
    ResamplePolicy, ResamplerKind, Stage, StateSpace,
};

type Pose = SVector<f32, 7>;

/// The rotation dimensions Rx, Ry, Rz.
const ANGLES: [usize; 3] = [3, 4, 5];

#[derive(Debug, Clone, Args)]
pub struct DemoArgs {
    /// Number of frames to track.
    #[arg(long, default_value_t = 100, value_parser = clap::value_parser!(u32).range(1..=1_000_000))]
    pub steps: u32,
    /// Particles per target.
    #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u32).range(1..=100_000_000))]
    pub particles: u32,
    /// Seed of every random number of the run (the sequence and the filter).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Resampler: multinomial, stratified, systematic, residual, metropolis or rejection.
    #[arg(long, default_value = "systematic")]
    pub resampler: ResamplerKind,
    /// Resample only when ESS/N falls below this fraction (default: every step).
    #[arg(long)]
    pub ess_threshold: Option<f64>,
    /// Print only the summary.
    #[arg(long)]
    pub quiet: bool,
}

/// The ground-truth pose at frame `t`: a head drifting over a 1024×768 frame and turning.
fn truth(t: u32) -> Pose {
    let t = t as f32;
    vector![
        512.0 + 100.0 * (0.02 * t).sin(),
        384.0 + 60.0 * (0.03 * t).cos(),
        1.0 + 0.2 * (0.03 * t).sin(),
        0.3 * (0.04 * t).sin(),
        pf_core::estimate::wrap_angle(0.02 * t),
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

pub fn run(args: &DemoArgs) -> anyhow::Result<()> {
    let policy = match args.ess_threshold {
        None => ResamplePolicy::EveryStep,
        Some(f) if f > 0.0 && f <= 1.0 => ResamplePolicy::EssBelow(f),
        Some(f) => bail!("--ess-threshold must be a fraction in (0, 1], got {f}"),
    };
    let space = StateSpace::with_angles(&ANGLES)?;
    let config = FilterConfig {
        particles: args.particles as usize,
        policy,
        seed: args.seed,
        target: 0,
        space,
    };
    let mut filter = ParticleFilter::new(
        config,
        GaussianDiffusion::new(diffusion_sigma())?,
        args.resampler.build(),
        &truth(0),
        &(observation_sigma() * 2.0),
    )
    .context("building the filter")?;
    // The sequence's noise has its own stream, apart from the filter's.
    let mut noise = RandomStreams::new(args.seed).stream(0, Stage::Model(0));
    let sigma = observation_sigma();

    println!(
        "streampf demo: 7-D pose target, {} particles, {} resampling, {} steps, seed {}",
        args.particles, args.resampler, args.steps, args.seed
    );
    if !args.quiet {
        println!("step  transl.err(px)  rot.err(deg)  obs.transl.err(px)       ESS  resampled");
    }
    let (mut sum_t, mut sum_r, mut max_t, mut max_r) = (0.0, 0.0, 0.0f32, 0.0f32);
    let (mut sum_obs_t, mut sum_obs_r) = (0.0, 0.0);
    let start = Instant::now();
    for t in 0..args.steps {
        let x = truth(t);
        let mut observed = x + Pose::from_fn(|d, _| sigma[d] * noise.gaussian_f32());
        space.wrap(&mut observed);
        let likelihood = GaussianObservation {
            observed,
            sigma,
            space,
        };
        let report = filter
            .step(&likelihood)
            .with_context(|| format!("step {t}"))?;
        let (et, er) = errors(&space, &report.estimate, &x);
        let (obs_t, obs_r) = errors(&space, &observed, &x);
        sum_t += et;
        sum_r += er;
        sum_obs_t += obs_t;
        sum_obs_r += obs_r;
        max_t = max_t.max(et);
        max_r = max_r.max(er);
        if !args.quiet {
            println!(
                "{t:4}  {et:14.2}  {er:12.2}  {obs_t:18.2}  {:8.1}  {}",
                report.ess,
                if report.resampled { "yes" } else { "no" }
            );
        }
    }
    let elapsed = start.elapsed();
    let n = args.steps as f32;
    println!(
        "summary: mean translation error {:.2} px (max {:.2}), mean rotation error {:.2} deg (max {:.2}); \
         the raw observations were off by {:.2} px and {:.2} deg on average",
        sum_t / n,
        max_t,
        sum_r / n,
        max_r,
        sum_obs_t / n,
        sum_obs_r / n
    );
    println!(
        "         {:.3} ms per step on the CPU ({} steps in {:.2} s)",
        elapsed.as_secs_f64() * 1e3 / f64::from(args.steps),
        args.steps,
        elapsed.as_secs_f64()
    );
    Ok(())
}
