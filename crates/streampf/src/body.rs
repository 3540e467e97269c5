//! `streampf body`: the stereo articulated body tracker.
//!
//! - `body synth --out DIR`: renders a synthetic sequence with ground truth;
//! - `body track DIR` or `body track --synthetic`: tracks a sequence, writes per-frame joint
//!   angles (`poses.csv`) and joint positions (`joints.csv`), and, when the ground truth is known,
//!   the per-frame mean joint position error (`errors.csv`) and its mean.

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, bail};
use body_tracker::camera::Intrinsics;
use body_tracker::human::{BASE_CAPSULES, MAX_CAPSULES, human_skeleton, standing_pose};
use body_tracker::sequence::{
    FrameFormat, SequenceDir, joint_columns, joint_row, read_pose_csv, write_synthetic,
};
use body_tracker::skeleton::ROOT_DOFS;
use body_tracker::synth::{Motion, SynthConfig, pose_at, render};
use body_tracker::{
    Backend, BodyTracker, FrameResult, PreparedFrame, Skeleton, TrackerConfig, mean_joint_error,
};
use clap::{Args, Subcommand, ValueEnum};
use nalgebra::Vector3;

use crate::annotated::Annotated;
use crate::recording::{BodyFrame, Recording};
use crate::run_output::{
    self, CsvStream, Interrupted, OutputLock, ResumePoint, SkipLog, clear_old_results,
};

/// `--tau`: metres, above 0 and at most `CapsuleLikelihoodParams::TAU_MAX`.
fn tau_metres(text: &str) -> Result<f32, String> {
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

#[derive(Debug, Subcommand)]
pub enum BodyCommand {
    /// Render a synthetic sequence (frames, camera, skeleton, ground truth) into a directory.
    Synth(SynthArgs),
    /// Track a body through a directory of frames, or through a generated sequence.
    Track(Box<TrackArgs>),
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
    fn config(&self) -> anyhow::Result<SynthConfig> {
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

    fn skeleton(&self) -> anyhow::Result<Skeleton> {
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

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum BackendArg {
    /// A hardware GPU when there is one, else the CPU.
    Auto,
    Cpu,
    /// The whole step on one GPU.
    Gpu,
    /// An island of the samples on every GPU, each the whole filter step on its GPU.
    AllGpus,
}

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
    /// The starting pose: a CSV like ground_truth.csv (its first row is used). Default: the
    /// ground truth's first row, else an upright body facing the camera at the points' median.
    #[arg(long)]
    pub init_pose: Option<PathBuf>,
    #[arg(long, value_enum, default_value_t = BackendArg::Auto)]
    pub backend: BackendArg,
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

pub fn run(command: &BodyCommand) -> anyhow::Result<()> {
    match command {
        BodyCommand::Synth(args) => synth(args),
        BodyCommand::Track(args) => track(args),
    }
}

fn synth(args: &SynthArgs) -> anyhow::Result<()> {
    let config = args.sequence.config()?;
    let skeleton = args.sequence.skeleton()?;
    let format = match args.format {
        FormatArg::Ply => FrameFormat::Ply,
        FormatArg::DepthPng => FrameFormat::DepthPng,
    };
    run_output::claim_synthetic_dir(&args.out, args.force)?;
    let bar = crate::console::progress_bar(config.frames, false);
    write_synthetic(&args.out, &skeleton, &config, format, |_| bar.inc(1))
        .with_context(|| format!("writing the sequence to {}", args.out.display()))?;
    bar.finish_and_clear();
    let format_name = args
        .format
        .to_possible_value()
        .map_or_else(String::new, |v| v.get_name().to_string());
    outln!(
        "wrote {} frames ({format_name}, {} capsules, {}) with ground truth to {}",
        config.frames,
        skeleton.capsule_count(),
        config.motion,
        args.out.display()
    );
    Ok(())
}

/// `--overlay`: each frame's depth view with the estimate's capsules and the truth's outlines.
struct BodyOverlay {
    camera: Intrinsics,
    out: Annotated,
    /// The last frame drawn, repeated in a video for a frame that could not be read.
    last: Option<image::RgbImage>,
}

impl BodyOverlay {
    /// A video's frame rate: the sequences carry none, and 30 frames/s is the depth cameras'.
    const VIDEO_FPS: f64 = 30.0;

    fn create(path: &Path, camera: Intrinsics) -> anyhow::Result<Self> {
        let out = Annotated::create(path, camera.width, camera.height, Self::VIDEO_FPS)
            .context("--overlay")?;
        Ok(Self {
            camera,
            out,
            last: None,
        })
    }

    fn draw(
        &mut self,
        frame: usize,
        skeleton: &Skeleton,
        points: &[Vector3<f32>],
        pose: &[f32],
        truth: Option<&[f32]>,
    ) -> anyhow::Result<()> {
        let estimate = skeleton.capsules(pose)?;
        let truth = truth.map(|t| skeleton.capsules(t)).transpose()?;
        let image =
            body_tracker::overlay::overlay(&self.camera, points, &estimate, truth.as_deref());
        self.out.write(frame, &image).context("--overlay")?;
        self.last = Some(image);
        Ok(())
    }

    /// A frame that could not be read: a video repeats the last picture to keep its timing.
    fn skip(&mut self, frame: usize) -> anyhow::Result<()> {
        match (&mut self.out, &self.last) {
            (Annotated::Video(_), Some(last)) => self.out.write(frame, last).context("--overlay"),
            _ => Ok(()),
        }
    }
}

/// The camera an overlay draws with: the sequence's, or (a PLY sequence without camera.json) a
/// 640×480 camera with a 60° horizontal field of view.
fn overlay_camera(source: &Source) -> anyhow::Result<Intrinsics> {
    Ok(match source {
        Source::Synthetic(config) => config.camera,
        Source::Directory(dir) => match dir.camera {
            Some(camera) => camera,
            None => Intrinsics::with_fov(640, 480, 60.0)?,
        },
    })
}

/// Where the frames come from.
enum Source {
    Directory(SequenceDir),
    Synthetic(SynthConfig),
}

impl Source {
    fn frames(&self) -> usize {
        match self {
            Source::Directory(dir) => dir.frames.len(),
            Source::Synthetic(config) => config.frames,
        }
    }

    fn points(&self, skeleton: &Skeleton, frame: usize) -> anyhow::Result<Vec<Vector3<f32>>> {
        Ok(match self {
            Source::Directory(dir) => dir.read_frame(frame)?,
            Source::Synthetic(config) => {
                let truth = pose_at(skeleton, config, frame)?;
                render(skeleton, &truth, config, frame)?.points
            }
        })
    }
}

fn open_backend(args: &TrackArgs) -> anyhow::Result<Backend> {
    Ok(match args.backend {
        BackendArg::Cpu => Backend::Cpu,
        BackendArg::Gpu => Backend::Gpu(Box::new(crate::gpu::required(args.allow_software)?)),
        BackendArg::AllGpus => Backend::SplitGpus(crate::gpu::all(args.allow_software)?),
        BackendArg::Auto => match crate::gpu::preferred(args.allow_software, args.quiet) {
            Some(ctx) => Backend::Gpu(Box::new(ctx)),
            None => Backend::Cpu,
        },
    })
}

/// An upright body facing the camera, its pelvis placed from the points' medians.
fn pose_from_points(skeleton: &Skeleton, points: &[Vector3<f32>]) -> anyhow::Result<Vec<f32>> {
    if points.is_empty() {
        bail!("the first frame has no points to start from; give --init-pose");
    }
    let median = |axis: usize| {
        let mut values: Vec<f32> = points.iter().map(|p| p[axis]).collect();
        values.sort_by(f32::total_cmp);
        values[values.len() / 2]
    };
    let mut theta = standing_pose(skeleton, median(2) + 0.12);
    theta[0] = median(0);
    // The visible points centre on the torso, about 0.15 m above the pelvis.
    theta[1] = median(1) - 0.15;
    Ok(theta)
}

/// The frames (generated or a sequence directory), the skeleton and the ground truth (one θ
/// per frame) if known.
type Sequence = (Source, Skeleton, Option<Vec<Vec<f32>>>);

/// Opens what `args` asks to track.
fn open_sequence(args: &TrackArgs) -> anyhow::Result<Sequence> {
    Ok(if args.synthetic {
        let config = args.sequence.config()?;
        let skeleton = args.sequence.skeleton()?;
        let truth = (0..config.frames)
            .map(|f| pose_at(&skeleton, &config, f))
            .collect::<Result<Vec<_>, _>>()?;
        (Source::Synthetic(config), skeleton, Some(truth))
    } else {
        let dir = args.dir.as_deref().unwrap_or(Path::new("."));
        let sequence = SequenceDir::open(dir)?;
        let skeleton = match sequence.skeleton()? {
            Some(s) => s,
            None => args.sequence.skeleton()?,
        };
        let truth = sequence.ground_truth(&skeleton)?;
        if let Some(t) = &truth
            && t.len() < sequence.frames.len()
        {
            bail!(
                "{} has {} rows for {} frames",
                dir.join(body_tracker::sequence::GROUND_TRUTH_FILE)
                    .display(),
                t.len(),
                sequence.frames.len()
            );
        }
        (Source::Directory(sequence), skeleton, truth)
    })
}

fn track(args: &TrackArgs) -> anyhow::Result<()> {
    if let Some(path) = &args.overlay {
        Annotated::check_path(path).context("--overlay")?;
        Annotated::check_not_input(path, args.dir.as_deref())?;
        if args.resume && crate::video::is_video_path(path) {
            bail!(
                "--resume cannot continue an overlay video ({}); write the overlay as PNG frames (a directory) to resume",
                path.display()
            );
        }
    }
    let recording = args
        .rerun
        .as_deref()
        .map(|path| Recording::create(path, "streampf body track"))
        .transpose()?;
    let (source, skeleton, truth) = open_sequence(args)?;
    // Held to the end of the run: nothing below touches --out before it is ours.
    let _lock = OutputLock::acquire(&args.out)?;
    let frames = source
        .frames()
        .min(args.max_frames.map_or(usize::MAX, |n| n as usize));
    let first_points = source.points(&skeleton, 0)?;
    let start = match (&args.init_pose, &truth) {
        (Some(path), _) => read_pose_csv(path, skeleton.dofs())?
            .into_iter()
            .next()
            .with_context(|| format!("{} has no pose row", path.display()))?,
        (None, Some(truth)) => truth[0].clone(),
        (None, None) => pose_from_points(&skeleton, &first_points)?,
    };
    let backend = open_backend(args)?;
    let backend_name = backend.describe();
    let defaults = TrackerConfig::default();
    let config = TrackerConfig {
        particles: args.particles as usize,
        max_points: args.max_points as usize,
        tau: args.tau,
        seed: args.seed,
        annealing: args.filter.apply(&defaults.annealing)?,
        motion: args.filter.motion(defaults.motion)?,
        partitioned: args.partitioned,
        ..defaults
    };
    let mut tracker = BodyTracker::new(skeleton.clone(), &start, config, backend)?;
    if let Some(dir) = &args.save_particles {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("--save-particles: creating {}", dir.display()))?;
    }
    if !args.quiet {
        outln!(
            "tracking {frames} frames, {} capsules, {} particles on {backend_name}",
            skeleton.capsule_count(),
            args.particles
        );
    }

    let resume = args
        .resume
        .then(|| {
            ResumePoint::of(
                &args.out.join(POSES_FILE),
                &BodyFiles::poses_header(&skeleton),
            )
        })
        .transpose()?;
    if let Some(point) = &resume {
        point.check_limit(args.max_frames.map(u64::from), &args.out.join(POSES_FILE))?;
    }
    if resume.is_none() {
        clear_old_results(&args.out, &[POSES_FILE, JOINTS_FILE, ERRORS_FILE])?;
    } else if let Some(point) = resume.as_ref().filter(|_| !args.quiet) {
        outln!(
            "resuming at frame {}: the frames before it are tracked again and checked against {}",
            point.frame,
            args.out.join(POSES_FILE).display()
        );
    }
    let mut files = BodyFiles::create(&args.out, &skeleton, truth.is_some(), resume.as_ref())?;
    let resume_from = resume.map_or(0, |p| p.frame);
    let mut overlay = args
        .overlay
        .as_deref()
        .map(|path| BodyOverlay::create(path, overlay_camera(&source)?))
        .transpose()?;
    let bar = crate::console::progress_bar(frames, args.quiet);
    let mut run = BodyRun::new(&args.out)?;
    let started = Instant::now();
    let mut end = LoopEnd::Done;
    // Frames in flight: the next frames are read (or rendered) and prepared for the tracker
    // (their rays, and on a GPU their order and cones) on a thread of their own, up to two ahead
    // of the tracker, in order, so that the host's share of a frame overlaps the GPU's step.
    let preparer = tracker.preparer();
    let prepare = |points: anyhow::Result<Vec<Vector3<f32>>>| {
        points.and_then(|points| {
            let prepared = preparer.prepare(&points)?;
            Ok((points, prepared))
        })
    };
    let first = prepare(Ok(first_points));
    std::thread::scope(|scope| {
        let (send, frames_ahead) = std::sync::mpsc::sync_channel(2);
        let (source, skeleton, prepare) = (&source, &skeleton, &prepare);
        scope.spawn(move || {
            for frame in 1..frames {
                // A closed channel: the loop below stopped early.
                if send.send(prepare(source.points(skeleton, frame))).is_err() {
                    break;
                }
            }
        });
        let mut first = Some(first);
        // Two frames in flight on one GPU (the GPU steps frame t + 1 while frame t is read back
        // and written) where nothing reads the particles between frames; the same results.
        let streaming =
            tracker.gpu_context().is_some() && args.save_particles.is_none() && recording.is_none();
        let mut in_flight: VecDeque<(usize, Vec<Vector3<f32>>)> = VecDeque::new();
        run.frames_in_flight = streaming;
        for frame in 0..frames {
            let points = if let Some(first) = first.take() {
                first
            } else {
                frames_ahead.recv().unwrap_or_else(|_| {
                    Err(anyhow::anyhow!(
                        "the frame reader thread stopped unexpectedly"
                    ))
                })
            };
            let result = match points {
                // Each error names its frame (with frames in flight, the one that failed).
                Ok((points, prepared)) if streaming => tracker
                    .submit_prepared(prepared)
                    .with_context(|| format!("frame {frame}"))
                    .and_then(|()| {
                        in_flight.push_back((frame, points));
                        if in_flight.len() < MAX_BODY_FRAMES_IN_FLIGHT {
                            return Ok(());
                        }
                        run.finish_oldest(
                            &mut in_flight,
                            overlay.as_mut(),
                            &mut tracker,
                            skeleton,
                            &mut files,
                            resume_from,
                            truth.as_deref(),
                        )
                    }),
                Ok((points, prepared)) => {
                    let save = args
                        .save_particles
                        .as_deref()
                        .filter(|_| frame >= resume_from);
                    let overlay = overlay.as_mut().filter(|_| frame >= resume_from);
                    run.track_one(
                        save,
                        (overlay, recording.as_ref()),
                        &mut tracker,
                        skeleton,
                        &mut files,
                        frame,
                        (&points, &prepared),
                        truth.as_deref(),
                    )
                    .map_err(|e| e.context(format!("frame {frame}")))
                }
                Err(e) if args.strict => Err(e
                    .context("unreadable frame (--strict)")
                    .context(format!("frame {frame}"))),
                // A generated frame that fails is a bug or a bad setting, not a frame to skip.
                Err(e) if matches!(source, Source::Synthetic(_)) => {
                    Err(e.context(format!("frame {frame}")))
                }
                Err(e) => run
                    .finish_in_flight(
                        &mut in_flight,
                        overlay.as_mut(),
                        &mut tracker,
                        skeleton,
                        &mut files,
                        resume_from,
                        truth.as_deref(),
                    )
                    .and_then(|()| {
                        run.skip_one(frame, e)
                            .and_then(|()| match overlay.as_mut() {
                                Some(overlay) => overlay.skip(frame),
                                None => Ok(()),
                            })
                            .map_err(|e| e.context(format!("frame {frame}")))
                    }),
            };
            if let Err(e) = result {
                end = LoopEnd::Failed(e);
                break;
            }
            if let Some(error) = run.errors.last() {
                bar.set_message(format!("joint error {:.1} cm", 100.0 * error));
            }
            bar.set_position(run.frames as u64);
            if run_output::stop_requested() {
                end = LoopEnd::Interrupted;
                break;
            }
        }
        // The frames still in flight are finished and written however the loop ended (after a
        // frame that failed to finish, none are left): a failure loses only what cannot be
        // finished.
        let finished = run.finish_in_flight(
            &mut in_flight,
            overlay.as_mut(),
            &mut tracker,
            skeleton,
            &mut files,
            resume_from,
            truth.as_deref(),
        );
        if let (Err(e), LoopEnd::Done | LoopEnd::Interrupted) = (finished, &end) {
            end = LoopEnd::Failed(e);
        }
        // Dropping the receiver ends the reader at its next frame.
        drop(frames_ahead);
    });
    bar.finish_and_clear();
    // The overlay video is finalised whatever ended the run, so that its frames are kept.
    let closed = overlay.map_or(Ok(()), |overlay| overlay.out.finish());
    let closed = closed.and(recording.map_or(Ok(()), Recording::finish));
    if let (Err(e), LoopEnd::Done | LoopEnd::Interrupted) = (closed, &end) {
        end = LoopEnd::Failed(e.context("finishing --overlay or --rerun"));
    }
    run.summary(
        args,
        started.elapsed().as_secs_f64(),
        matches!(end, LoopEnd::Done),
    );
    match end {
        LoopEnd::Done => Ok(()),
        LoopEnd::Interrupted => Err(Interrupted {
            frames: run.frames,
            out: args.out.clone(),
        }
        .into()),
        LoopEnd::Failed(e) => Err(run_output::stopped(e, run.frames, &args.out)),
    }
}

/// The most frames a body run keeps in flight on its GPU (`BodyTracker::submit_prepared`).
const MAX_BODY_FRAMES_IN_FLIGHT: usize = 2;

const POSES_FILE: &str = "poses.csv";
const JOINTS_FILE: &str = "joints.csv";
const ERRORS_FILE: &str = "errors.csv";

/// Why the frame loop ended.
enum LoopEnd {
    Done,
    Interrupted,
    Failed(anyhow::Error),
}

/// poses.csv, joints.csv and (with ground truth) errors.csv, written a frame at a time.
struct BodyFiles {
    poses: CsvStream,
    joints: CsvStream,
    errors: Option<CsvStream>,
}

impl BodyFiles {
    /// The pose, its spread per value (`sd_` + the value's name), the ESS and the confidence
    /// (docs/OUTPUT.md).
    fn poses_header(skeleton: &Skeleton) -> String {
        let names = skeleton.pose_names();
        let spreads: Vec<String> = names.iter().map(|n| format!("sd_{n}")).collect();
        format!(
            "frame,{},{},ess,confidence",
            names.join(","),
            spreads.join(",")
        )
    }

    /// The files, new or (`resume`) an interrupted run's reopened at its resume point.
    fn create(
        out: &Path,
        skeleton: &Skeleton,
        with_truth: bool,
        resume: Option<&ResumePoint>,
    ) -> anyhow::Result<Self> {
        let open = |name: &str, header: &str| match resume {
            Some(point) => CsvStream::resume(&out.join(name), header, point),
            None => CsvStream::create(&out.join(name), header),
        };
        let joints_header = format!("frame,{}", joint_columns(skeleton).join(","));
        Ok(Self {
            poses: open(POSES_FILE, &Self::poses_header(skeleton))?,
            joints: open(JOINTS_FILE, &joints_header)?,
            errors: with_truth
                .then(|| open(ERRORS_FILE, "frame,mean_joint_error_m"))
                .transpose()?,
        })
    }
}

fn csv_row(frame: usize, values: &[f32]) -> String {
    let mut row = frame.to_string();
    for v in values {
        row.push(',');
        row.push_str(&v.to_string());
    }
    row
}

/// What a body run has tracked so far.
struct BodyRun {
    /// Frames finished and written (tracked or skipped).
    frames: usize,
    errors: Vec<f32>,
    /// Pose values (frames × values, with ground truth) whose true value lay within ±2 reported
    /// standard deviations of the estimate, and how many were checked.
    within_two_sd: usize,
    values_checked: usize,
    skipped: SkipLog,
    points_seen: usize,
    /// Seconds in the tracker's calls, and the GPU's own seconds for the frames: with frames in
    /// flight the GPU works while the host waits for the next frame, so the tracker's time is
    /// the longer of the two.
    tracking_time: f64,
    gpu_time: f64,
    /// Whether the frames were tracked with two in flight.
    frames_in_flight: bool,
}

impl BodyRun {
    fn new(out: &Path) -> anyhow::Result<Self> {
        Ok(Self {
            frames: 0,
            errors: Vec::new(),
            within_two_sd: 0,
            values_checked: 0,
            skipped: SkipLog::new(out)?,
            points_seen: 0,
            tracking_time: 0.0,
            gpu_time: 0.0,
            frames_in_flight: false,
        })
    }

    #[allow(clippy::too_many_arguments)]
    fn track_one(
        &mut self,
        save_particles: Option<&Path>,
        (overlay, recording): (Option<&mut BodyOverlay>, Option<&Recording>),
        tracker: &mut BodyTracker,
        skeleton: &Skeleton,
        files: &mut BodyFiles,
        frame: usize,
        (points, prepared): (&[Vector3<f32>], &PreparedFrame),
        truth: Option<&[Vec<f32>]>,
    ) -> anyhow::Result<()> {
        run_output::maybe_simulate_gpu_fault(frame, tracker.gpu_context());
        let step_started = Instant::now();
        let result = tracker.step_prepared(prepared)?;
        self.tracking_time += step_started.elapsed().as_secs_f64();
        self.gpu_time += crate::gpu::gpu_seconds(tracker.last_gpu_time());
        let outputs = (save_particles, (overlay, recording));
        self.write_frame(
            outputs, tracker, skeleton, files, frame, points, result, truth,
        )
    }

    /// Finishes the oldest of the frames in flight and writes it (see [`track`]).
    #[allow(clippy::too_many_arguments)]
    fn finish_oldest(
        &mut self,
        in_flight: &mut VecDeque<(usize, Vec<Vector3<f32>>)>,
        overlay: Option<&mut BodyOverlay>,
        tracker: &mut BodyTracker,
        skeleton: &Skeleton,
        files: &mut BodyFiles,
        resume_from: usize,
        truth: Option<&[Vec<f32>]>,
    ) -> anyhow::Result<()> {
        let Some((frame, points)) = in_flight.pop_front() else {
            return Ok(());
        };
        let finish_and_write = || -> anyhow::Result<()> {
            // A device fault (simulated for the tests) shows when a frame is read back.
            run_output::maybe_simulate_gpu_fault(frame, tracker.gpu_context());
            let started = Instant::now();
            let finished = tracker.finish();
            self.tracking_time += started.elapsed().as_secs_f64();
            self.gpu_time += crate::gpu::gpu_seconds(tracker.last_gpu_time());
            let result = finished?.context("the frame was not in flight")?;
            let overlay = overlay.filter(|_| frame >= resume_from);
            let outputs = (None, (overlay, None));
            self.write_frame(
                outputs, tracker, skeleton, files, frame, &points, result, truth,
            )
        };
        let written = finish_and_write().with_context(|| format!("frame {frame}"));
        if written.is_err() {
            // The frames after a failed one are not written: the files would have a gap.
            in_flight.clear();
        }
        written
    }

    /// Finishes and writes every frame in flight, oldest first (none after one that fails).
    #[allow(clippy::too_many_arguments)]
    fn finish_in_flight(
        &mut self,
        in_flight: &mut VecDeque<(usize, Vec<Vector3<f32>>)>,
        mut overlay: Option<&mut BodyOverlay>,
        tracker: &mut BodyTracker,
        skeleton: &Skeleton,
        files: &mut BodyFiles,
        resume_from: usize,
        truth: Option<&[Vec<f32>]>,
    ) -> anyhow::Result<()> {
        while !in_flight.is_empty() {
            self.finish_oldest(
                in_flight,
                overlay.as_deref_mut(),
                tracker,
                skeleton,
                files,
                resume_from,
                truth,
            )?;
        }
        Ok(())
    }

    /// Writes a tracked frame's results: the CSV rows, and the particles, the recording and the
    /// overlay when asked for.
    #[allow(clippy::too_many_arguments)]
    fn write_frame(
        &mut self,
        (save_particles, (overlay, recording)): (
            Option<&Path>,
            (Option<&mut BodyOverlay>, Option<&Recording>),
        ),
        tracker: &mut BodyTracker,
        skeleton: &Skeleton,
        files: &mut BodyFiles,
        frame: usize,
        points: &[Vector3<f32>],
        result: FrameResult,
        truth: Option<&[Vec<f32>]>,
    ) -> anyhow::Result<()> {
        if let Some(dir) = save_particles {
            let (shape, states, log_weights) = tracker.particles()?;
            pf_numpy::write_particles(dir, frame, &shape, &states, &log_weights)
                .context("--save-particles")?;
        }
        self.points_seen += result.points;
        let mut pose_row = result.pose.clone();
        pose_row.extend(&result.spread);
        pose_row.extend([result.ess as f32, result.confidence]);
        files.poses.row(&csv_row(frame, &pose_row))?;
        let joints = joint_row(&skeleton.tracked_joint_positions(&result.pose)?);
        files.joints.row(&csv_row(frame, &joints))?;
        let mut joint_error = None;
        if let (Some(truth), Some(out)) = (truth, files.errors.as_mut()) {
            let error = mean_joint_error(skeleton, &result.pose, &truth[frame])?;
            joint_error = Some(error);
            out.row(&csv_row(frame, &[error]))?;
        }
        if let Some(recording) = recording {
            let (shape, states, _) = tracker.particles()?;
            let shown = BodyFrame {
                frame,
                points,
                pose: &result.pose,
                truth: truth.map(|t| t[frame].as_slice()),
                ess: result.ess,
                confidence: result.confidence,
                joint_error,
                samples: Some((&states, shape.particles)),
            };
            recording.body_frame(skeleton, shown).context("--rerun")?;
        }
        if let Some(overlay) = overlay {
            let truth = truth.map(|t| t[frame].as_slice());
            overlay.draw(frame, skeleton, points, &result.pose, truth)?;
        }
        match files.errors.as_mut() {
            Some(errors) => {
                CsvStream::end_frame_in_all(&mut [&mut files.poses, &mut files.joints, errors])?
            }
            None => CsvStream::end_frame_in_all(&mut [&mut files.poses, &mut files.joints])?,
        }
        // Counted once the frame is in the files (a frame that failed to write is dropped).
        if let (Some(truth), Some(error)) = (truth, joint_error) {
            self.errors.push(error);
            self.count_coverage(&result.pose, &result.spread, &truth[frame]);
        }
        self.frames += 1;
        Ok(())
    }

    /// Counts the pose values whose truth lies within ±2 reported sd (the root's rotations, the
    /// filter's angles, wrapped).
    fn count_coverage(&mut self, pose: &[f32], spread: &[f32], truth: &[f32]) {
        for (d, ((&estimate, &sd), &true_value)) in pose.iter().zip(spread).zip(truth).enumerate() {
            let mut miss = estimate - true_value;
            if (3..ROOT_DOFS).contains(&d) {
                miss = pf_core::batch::wrap_angle_floor(miss);
            }
            self.within_two_sd += usize::from(miss.abs() <= 2.0 * sd);
            self.values_checked += 1;
        }
    }

    /// A frame that cannot be read: a warning and a row in skipped.csv; the filter is not
    /// stepped (the pose holds), and poses.csv has no row for the frame.
    fn skip_one(&mut self, frame: usize, error: anyhow::Error) -> anyhow::Result<()> {
        self.skipped.record(frame, &error)?;
        self.frames += 1;
        Ok(())
    }

    /// `written`: whether the run ended well (a stopped one says what it wrote in its error).
    fn summary(&self, args: &TrackArgs, elapsed: f64, written: bool) {
        let tracked = self.frames - self.skipped.frames.len();
        outln!(
            "tracked {tracked} frames ({:.0} points a frame) in {elapsed:.2} s: {:.1} frames/s in the tracker{}{}",
            self.points_seen as f64 / tracked.max(1) as f64,
            tracked as f64 / self.tracking_time.max(self.gpu_time).max(1e-9),
            if self.frames_in_flight {
                " (two frames in flight)"
            } else {
                ""
            },
            self.skipped.note(),
        );
        if !self.errors.is_empty() {
            let mean =
                self.errors.iter().map(|&e| f64::from(e)).sum::<f64>() / self.errors.len() as f64;
            outln!(
                "mean joint position error: {mean:.4} m over {} frames",
                self.errors.len()
            );
            outln!(
                "truth within ±2 reported sd: {:.0}% of the pose values (about 95% for an honest spread)",
                100.0 * self.within_two_sd as f64 / self.values_checked.max(1) as f64
            );
        }
        if !written {
            return;
        }
        outln!(
            "wrote poses.csv, joints.csv{}{} to {}",
            if self.errors.is_empty() {
                ""
            } else {
                ", errors.csv"
            },
            if self.skipped.frames.is_empty() {
                ""
            } else {
                ", skipped.csv"
            },
            args.out.display()
        );
        if let Some(path) = &args.overlay {
            outln!("drew the frames to {}", path.display());
        }
    }
}
