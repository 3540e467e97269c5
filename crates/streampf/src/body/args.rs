//! The command line of `streampf body`: each command's arguments and their value parsers.

use anyhow::bail;
use body_tracker::human::{BASE_CAPSULES, MAX_CAPSULES, human_skeleton};
use body_tracker::synth::{Motion, SynthConfig};
use body_tracker::tracker::{DEFAULT_COARSE_LAYERS, DEFAULT_COARSE_POINTS};
use body_tracker::{Skeleton, TrackerConfig};
use clap::{Args, ValueEnum};
use std::path::PathBuf;

/// `--tau`: metres, above 0 and at most `CapsuleLikelihoodParams::TAU_MAX`.
pub(super) fn tau_metres(text: &str) -> Result<f32, String> {
    let value: f32 = text.parse().map_err(|e| format!("{e}"))?;
    let max = body_tracker::likelihood::CapsuleLikelihoodParams::TAU_MAX;
    if value > 0.0 && value <= max {
        Ok(value)
    } else {
        Err(format!(
            "{value}: give τ in metres, above 0 and at most {max}"
        ))
    }
}

/// The synthetic sequence's settings, shared by `synth` and `track --synthetic`.
#[derive(Debug, Clone, Args)]
pub struct SequenceArgs {
    /// Frames to generate.
    #[arg(long, default_value_t = 40, value_parser = clap::value_parser!(u32).range(1..=100_000))]
    pub frames: u32,
    /// Capsules of the default human (19 to 96; the paper used 40 to 48).
    #[arg(long, default_value_t = 48, value_parser = clap::value_parser!(u32).range(BASE_CAPSULES as i64..=MAX_CAPSULES as i64))]
    pub capsules: u32,
    /// The movement: walk, wave or walk-wave.
    #[arg(long, default_value = "walk-wave")]
    pub motion: Motion,
    /// Camera width and height in pixels.
    #[arg(long, default_value_t = 160, value_parser = clap::value_parser!(u32).range(1..=8192))]
    pub width: u32,
    #[arg(long, default_value_t = 120, value_parser = clap::value_parser!(u32).range(1..=8192))]
    pub height: u32,
    /// Horizontal field of view in degrees.
    #[arg(long, default_value_t = 60.0)]
    pub fov: f32,
    /// Depth noise σ at 1 m, in metres (grows with the square of the depth).
    #[arg(long, default_value_t = 0.005)]
    pub noise: f32,
    /// Fraction of body pixels lost.
    #[arg(long, default_value_t = 0.1)]
    pub dropout: f32,
    /// Fraction of points moved to a random depth along their ray.
    #[arg(long, default_value_t = 0.02)]
    pub outliers: f32,
    /// Seed of the sequence's noise.
    #[arg(long, default_value_t = 7)]
    pub sequence_seed: u64,
}

impl SequenceArgs {
    pub(super) fn config(&self) -> anyhow::Result<SynthConfig> {
        if !(self.fov.is_finite() && self.fov > 1.0 && self.fov < 179.0) {
            bail!(
                "--fov must be more than 1 and less than 179 degrees, got {}",
                self.fov
            );
        }
        let config = SynthConfig {
            frames: self.frames as usize,
            motion: self.motion,
            fps: 30.0,
            camera: body_tracker::camera::Intrinsics::with_fov(self.width, self.height, self.fov)?,
            distance: 3.0,
            depth_noise: self.noise,
            dropout: self.dropout,
            outliers: self.outliers,
            seed: self.sequence_seed,
        };
        config.validate()?;
        Ok(config)
    }

    pub(super) fn skeleton(&self) -> anyhow::Result<Skeleton> {
        Ok(human_skeleton(self.capsules as usize)?)
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum FormatArg {
    Ply,
    DepthPng,
}

#[derive(Debug, Clone, Args)]
pub struct SynthArgs {
    /// The directory to write (created if needed): new, empty, or an earlier `body synth`'s.
    #[arg(long)]
    pub out: PathBuf,
    /// Write into a directory that holds other files (its frames are replaced).
    #[arg(long)]
    pub force: bool,
    /// Frame files: PLY point clouds or 16-bit depth PNGs.
    #[arg(long, value_enum, default_value_t = FormatArg::Ply)]
    pub format: FormatArg,
    #[command(flatten)]
    pub sequence: SequenceArgs,
}

pub use crate::gpu::BackendArg;

#[derive(Debug, Clone, Args)]
pub struct TrackArgs {
    /// A sequence directory: *.ply frames, or *.png depth images with camera.json; optional
    /// skeleton.json and ground_truth.csv.
    #[arg(required_unless_present = "synthetic", conflicts_with = "synthetic")]
    pub dir: Option<PathBuf>,
    /// Track a synthetic sequence generated in memory (see the sequence options).
    #[arg(long)]
    pub synthetic: bool,
    /// Where to write poses.csv, joints.csv and errors.csv.
    #[arg(long, default_value = "streampf-body-out")]
    pub out: PathBuf,
    /// Also draw every frame: the points as the depth camera sees them (near bright), the
    /// estimated skeleton's capsules filled in orange and the ground truth's outlined in green; a
    /// directory (PNG frames) or a video file (.mp4, .mkv, .avi, .webm; encoded by FFmpeg).
    #[arg(long)]
    pub overlay: Option<PathBuf>,
    /// Pose samples (particles).
    #[arg(long, default_value_t = 1500, value_parser = clap::value_parser!(u32).range(1..=1_000_000))]
    pub particles: u32,
    /// τ of the likelihood (eq. 6), in metres: a point's distance to the body counts up to this
    /// much, and a point no capsule explains costs τ².
    #[arg(long, default_value_t = TrackerConfig::default().tau, value_parser = tau_metres)]
    pub tau: f32,
    /// Partitioned sampling: the first half of the annealing layers move only the trunk (the
    /// root, pelvis, spine and chest), the second half only the limbs, each from the full σ;
    /// false: every layer moves every pose value.
    #[arg(long, default_value_t = TrackerConfig::default().partitioned, action = clap::ArgAction::Set)]
    pub partitioned: bool,
    /// Frames are thinned to at most this many points.
    #[arg(long, default_value_t = 20_000, value_parser = clap::value_parser!(u32).range(1..=10_000_000))]
    pub max_points: u32,
    /// Coarse-to-fine annealing: the first --coarse-layers layers of a frame weigh at most this
    /// many of its points (every k-th), the later layers every point (docs/USAGE.md).
    #[arg(long, default_value_t = DEFAULT_COARSE_POINTS as u32, value_parser = clap::value_parser!(u32).range(1..=10_000_000))]
    pub coarse_points: u32,
    /// How many of a frame's annealing layers, from the first, weigh the coarse subset of
    /// --coarse-points points (0: every layer weighs every point; the last layer always does).
    #[arg(long, default_value_t = DEFAULT_COARSE_LAYERS as u32, value_parser = clap::value_parser!(u32).range(0..=1000))]
    pub coarse_layers: u32,
    /// The starting pose: a CSV like ground_truth.csv (its first row is used). Default: the
    /// ground truth's first row, else an upright body facing the camera at the points' median.
    #[arg(long)]
    pub init_pose: Option<PathBuf>,
    #[arg(long, value_enum, default_value_t = BackendArg::Auto)]
    pub backend: BackendArg,
    /// With --backend all-gpus or auto: how many GPUs to use (default: as many as a frame's work
    /// pays for, said when the run starts; docs/BENCHMARKS.md, "Several GPUs").
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..=1024))]
    pub gpus: Option<u32>,
    /// Accept a software GPU adapter (Mesa's lavapipe) for --backend gpu or all-gpus.
    #[arg(long)]
    pub allow_software: bool,
    /// Seed of the filter's random numbers.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Also record the run for the rerun viewer (a .rrd file; built with `--features rerun`):
    /// the points, the estimated and true capsules, the samples' root positions, and the ESS,
    /// confidence and joint error as time series. On a GPU this reads the samples back every
    /// frame.
    #[arg(long, value_name = "FILE.rrd")]
    pub rerun: Option<PathBuf>,
    /// Write every frame's pose samples and log-weights here as numpy files:
    /// particles_FRAME.npy (1, J, pose values; float32, named as in poses.csv) and
    /// log_weights_FRAME.npy (1, J). On a GPU this reads the cloud back every frame.
    #[arg(long)]
    pub save_particles: Option<PathBuf>,
    #[command(flatten)]
    pub smoothing: crate::smoothing::SmoothArgs,
    /// Continue an interrupted run in --out instead of starting over: the frames it wrote are
    /// tracked again (each row checked against the file: different inputs or settings are
    /// refused at the first row that differs) and the run goes on from its last frame.
    #[arg(long)]
    pub resume: bool,
    /// Stop at the first frame that cannot be read (after writing every frame before it)
    /// instead of skipping it with a warning.
    #[arg(long)]
    pub strict: bool,
    /// Stop after this many frames.
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..))]
    pub max_frames: Option<u32>,
    /// Print only the summary.
    #[arg(long)]
    pub quiet: bool,
    /// Read settings from a TOML file (its [body] table; keys are the long options' names,
    /// `streampf config --print-default` writes every one); options on the command line win.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    #[command(flatten)]
    pub filter: crate::filter_args::FilterArgs,
    #[command(flatten)]
    pub sequence: SequenceArgs,
}
