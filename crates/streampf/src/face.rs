//! `streampf face`: the multi-face tracker.
//!
//! - `face synth --out DIR`: renders a synthetic video (PNG frames, `faces.csv` with each face's
//!   rectangle at frame 0, `ground_truth.csv`);
//! - `face track VIDEO|DIR`: finds faces with the Viola–Jones detector in its own thread and
//!   tracks them (or starts from given rectangles: `--face`, or faces.csv beside the frames);
//! - `face track --synthetic`: the same on a video generated in memory, with its ground truth;
//!
//! both write `states.csv` (frame, track, status, 7 values, ε), optionally an annotated video or
//! PNG frames, and, when the ground truth is known, the translation and rotation errors.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, bail};
use body_tracker::sequence::read_numeric_csv;
use clap::{Args, Subcommand, ValueEnum};
use face_tracker::detect::{
    Cascade, DEFAULT_CASCADE, DetectConfig, DetectorPlacement, FaceDetector, GpuCascade,
};
use face_tracker::extraction::{ExtractionConfig, FaceRect};
use face_tracker::landmarks::{DEFAULT_PREDICTOR, ShapePredictor};
use face_tracker::model::FaceModel;
use face_tracker::personal::Personaliser;
use face_tracker::projection::{
    DIMS, RZ, STATE_NAMES, pitch_yaw_roll_degrees, rotation_quaternion,
};
use face_tracker::synth::{FaceSynthConfig, FaceVideoRenderer, face_state, initial_rect};
use face_tracker::tracker::pose_errors;
use face_tracker::{
    AutoConfig, AutoTracker, FaceBackend, FaceEstimate, FaceTracker, FaceTrackerConfig, GrayImage,
    TrackStatus,
};
use std::sync::Arc;

use crate::annotated::Annotated;
use crate::face_io::{FrameRead, ReadAhead, Source};
use crate::face_overlay::{ColourFrames, FaceOverlay};

mod in_flight;
use crate::recording::{FaceClouds, FaceFrame, Recording};
use crate::run_output::{
    self, CsvStream, Interrupted, OutputLock, ResumePoint, SkipLog, clear_old_results,
};
use in_flight::InFlight;

#[derive(Debug, Subcommand)]
pub enum FaceCommand {
    /// Render a synthetic video (PNG frames, face rectangles, ground truth) into a directory.
    Synth(SynthArgs),
    /// Track faces through a directory of frames, or through a generated video.
    Track(Box<TrackArgs>),
}

#[derive(Debug, Clone, Args)]
pub struct VideoArgs {
    /// Frames to generate.
    #[arg(long, default_value_t = 100, value_parser = clap::value_parser!(u32).range(1..=100_000))]
    pub frames: u32,
    /// Faces in the video (1 to 16; the paper's Fig. 1 has four).
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=16))]
    pub faces: u32,
    /// Frame width in pixels (at least 160: the heads scale with the frame and need 8 px of half-width).
    #[arg(long, default_value_t = 1024, value_parser = clap::value_parser!(u32).range(160..=8192))]
    pub width: u32,
    /// Frame height in pixels (at least 120).
    #[arg(long, default_value_t = 768, value_parser = clap::value_parser!(u32).range(120..=8192))]
    pub height: u32,
    /// Largest yaw of the heads, in degrees (at most 90).
    #[arg(long, default_value_t = 60.0)]
    pub max_yaw: f32,
    /// Seed of the video's textures.
    #[arg(long, default_value_t = 11)]
    pub video_seed: u64,
    /// The camera's horizontal field of view in degrees (1 to 170): faces are seen through a
    /// pinhole of that angle, whose perspective magnifies what is nearer the camera. Give your
    /// camera's for real input (the real clips in docs/ACCURACY.md measured best at 30-70°);
    /// the synthetic video is rendered through it. Unset: weak perspective, the paper's, right
    /// for a camera far from the faces (docs/ACCURACY.md, "The camera's lens").
    #[arg(long, value_parser = field_of_view)]
    pub fov: Option<f32>,
}

/// `--failure-error`: within (0, 1], as ε is (a fit's robust residual, in [0, 1)).
fn failure_error(text: &str) -> Result<f32, String> {
    let value: f32 = text.parse().map_err(|e| format!("{e}"))?;
    if value > 0.0 && value <= 1.0 {
        Ok(value)
    } else {
        Err(format!(
            "{value}: give a fit error ε above 0 and at most 1 (ε lies in [0, 1); 1 never ends a track)"
        ))
    }
}

/// `--fov`: degrees, within `Lens::FIELD_OF_VIEW`.
fn field_of_view(text: &str) -> Result<f32, String> {
    let value: f32 = text.parse().map_err(|e| format!("{e}"))?;
    let range = face_tracker::likelihood::Lens::FIELD_OF_VIEW;
    if range.contains(&value) {
        Ok(value)
    } else {
        Err(format!(
            "{value}: give the field of view in degrees, {} to {}",
            range.start(),
            range.end()
        ))
    }
}

/// The focal length in pixels of a camera whose frames are `width` pixels wide and span `fov`
/// degrees across (`--fov` is checked as it is parsed).
fn focal_length(fov: f32, width: u32) -> anyhow::Result<f32> {
    Ok(face_tracker::likelihood::Lens::focal_length_for(
        fov, width,
    )?)
}

impl VideoArgs {
    fn config(&self) -> anyhow::Result<FaceSynthConfig> {
        // Checked here in the option's own unit (the config holds radians).
        if !(self.max_yaw.is_finite() && self.max_yaw.abs() <= 90.0) {
            bail!("--max-yaw must be within ±90 degrees, got {}", self.max_yaw);
        }
        let config = FaceSynthConfig {
            width: self.width,
            height: self.height,
            frames: self.frames as usize,
            faces: self.faces as usize,
            half_width: 60.0 * (self.width as f32 / 1024.0).min(self.height as f32 / 768.0),
            max_yaw: self.max_yaw.to_radians(),
            occlusion: true,
            exit_after: None,
            enter_every: 0,
            seed: self.video_seed,
            focal_length: self
                .fov
                .map(|fov| focal_length(fov, self.width))
                .transpose()?,
        };
        config.validate()?;
        Ok(config)
    }
}

#[derive(Debug, Clone, Args)]
pub struct SynthArgs {
    /// The directory to write: new, empty, or an earlier `face synth`'s.
    #[arg(long)]
    pub out: PathBuf,
    /// Write into a directory that holds other files (frame_*.png among them are replaced).
    #[arg(long)]
    pub force: bool,
    #[command(flatten)]
    pub video: VideoArgs,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum BackendArg {
    /// A hardware GPU when there is one, else the CPU.
    Auto,
    Cpu,
    /// The whole step on one GPU.
    Gpu,
    /// The faces' slots split over every GPU, each running the whole step for its share.
    AllGpus,
}

/// The built-in face models a template's points take their depths from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum FaceModelArg {
    /// The photographed head for a video, images or a webcam; the generic head for --synthetic,
    /// whose heads are the generic model. Chosen by measurement on real clips against MediaPipe's
    /// face mesh (docs/ACCURACY.md, "Which face model by default").
    Auto,
    /// The parametric head (an ellipsoid with nose, brow and cheek relief): the synthetic
    /// video's heads.
    Generic,
    /// A real face's depth (the mean of five photographed faces) on the generic skull: nearer
    /// real heads' turns (docs/ACCURACY.md).
    Photographed,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum DetectorArg {
    /// On a GPU when the tracker runs on one, else on the CPU.
    Auto,
    /// On all the CPU's cores.
    Cpu,
    /// On a GPU (a device of its own on the best adapter).
    Gpu,
}

#[derive(Debug, Clone, Args)]
pub struct TrackArgs {
    /// A video file (mp4, avi, webm, …; decoded by FFmpeg) or a directory of image frames (name
    /// order; optionally with faces.csv — x,y,width,height per face at the first frame — and
    /// ground_truth.csv).
    #[arg(required_unless_present_any = ["synthetic", "webcam"], conflicts_with = "synthetic")]
    pub input: Option<PathBuf>,
    /// Track a synthetic video generated in memory (see the video options).
    #[arg(long)]
    pub synthetic: bool,
    /// A V4L2 camera, for example /dev/video0 (built with `--features webcam`).
    #[arg(long, conflicts_with_all = ["synthetic", "input"])]
    pub webcam: Option<PathBuf>,
    /// The camera's frame size, WIDTHxHEIGHT.
    #[arg(long, default_value = "640x480", requires = "webcam")]
    pub webcam_size: String,
    /// A face rectangle at the first frame, `x,y,width,height` (repeat for several faces);
    /// overrides faces.csv. With rectangles the detector is off unless --detect.
    #[arg(long = "face", value_name = "X,Y,W,H")]
    pub faces_at: Vec<String>,
    /// Run the detector even when faces start from rectangles (or on --synthetic).
    #[arg(long)]
    pub detect: bool,
    /// The Haar cascade of the face detector (OpenCV's XML).
    #[arg(long, default_value = DEFAULT_CASCADE)]
    pub cascade: PathBuf,
    /// Hand the detector every n-th frame (with --webcam it skips frames while busy).
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(1..=100_000))]
    pub detect_every: u32,
    /// For a file: use each detection this many frames after the frame the detector saw (0: at
    /// that frame), waiting for it when it is late, so that runs repeat exactly. Frames handed
    /// over in the meantime are detected at the same time, so a delay of a few --detect-every
    /// periods keeps the detector from holding up the tracker, while new faces start tracks
    /// that much later, from where they were then. Not with --webcam (a camera never waits).
    #[arg(
        long,
        default_value_t = 1,
        conflicts_with = "webcam",
        value_parser = clap::value_parser!(u32).range(0..=10_000)
    )]
    pub detection_delay: u32,
    /// Where the detector runs: `auto` on a GPU when the tracker runs on one, else on the CPU's
    /// cores. On the GPU a detection sums its features in f32 (the CPU in f64, as OpenCV): the
    /// same faces, with a raw hit now and then different where a sum lies within rounding of a
    /// threshold.
    #[arg(long, value_enum, default_value_t = DetectorArg::Auto)]
    pub detector: DetectorArg,
    /// The smallest face the detector looks for, in pixels.
    #[arg(long, default_value_t = 40, value_parser = clap::value_parser!(u32).range(8..=8192))]
    pub min_face: u32,
    /// Faces tracked at once (default 8 with the detector; rectangles given with --face or
    /// faces.csv may not exceed it when it is given).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=256))]
    pub max_faces: Option<u32>,
    /// Stop after this many frames.
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
    pub max_frames: Option<u64>,
    /// Where to write states.csv (and errors.csv with ground truth).
    #[arg(long, default_value = "streampf-face-out")]
    pub out: PathBuf,
    /// Also draw every frame with each face's posed template points and axes: a directory (PNG
    /// frames) or a video file (.mp4, .mkv, .avi, .webm; encoded by FFmpeg).
    #[arg(long)]
    pub overlay: Option<PathBuf>,
    /// Also record the run for the rerun viewer (a .rrd file; built with `--features rerun`):
    /// the frames, each track's points, axes, box and particles, and its ESS, confidence,
    /// residual (and errors against the truth) as time series. On a GPU this reads the clouds
    /// back every frame.
    #[arg(long, value_name = "FILE.rrd")]
    pub rerun: Option<PathBuf>,
    /// Write every frame's particles and log-weights here as numpy files:
    /// particles_FRAME.npy (slots, particles, 7; float32, the state columns of states.csv),
    /// log_weights_FRAME.npy (slots, particles) and tracks_FRAME.npy (the track in each slot,
    /// -1 when free). On a GPU this reads the clouds back every frame.
    #[arg(long)]
    pub save_particles: Option<PathBuf>,
    /// A track ends when its estimate's ε (the template's robust relative residual) stays above
    /// this for --failure-frames frames in a row.
    #[arg(long, default_value_t = FaceTrackerConfig::default().failure_error, value_parser = failure_error)]
    pub failure_error: f32,
    #[arg(long, default_value_t = FaceTrackerConfig::default().failure_frames as u32, value_parser = clap::value_parser!(u32).range(1..=100_000))]
    pub failure_frames: u32,
    /// Particles per face.
    #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u32).range(1..=1_000_000))]
    pub particles: u32,
    #[arg(long, value_enum, default_value_t = BackendArg::Auto)]
    pub backend: BackendArg,
    /// Accept a software GPU adapter (Mesa's lavapipe) for --backend gpu.
    #[arg(long)]
    pub allow_software: bool,
    /// Seed of the filters' random numbers.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// The built-in face model (when no --heightmap is given).
    #[arg(long, value_enum, default_value_t = FaceModelArg::Auto, conflicts_with = "heightmap")]
    pub face_model: FaceModelArg,
    /// The photographed head's face this many times as deep (0.25 to 4): its height above the
    /// eyes' outer corners scaled. One depth does not fit every face and camera: on the real
    /// clips a face 1.1 times as deep follows one man's turns better and another's worse
    /// (docs/ACCURACY.md, "The widest turns"). Only with the photographed head.
    #[arg(long, default_value_t = 1.0, value_parser = face_depth)]
    pub face_depth: f32,
    /// Your own face model: a square gray heightmap PNG (with --normalmap; black 0, white
    /// --height-scale half-widths of the face rectangle) instead of the generic head.
    #[arg(long, requires = "normalmap")]
    pub heightmap: Option<PathBuf>,
    /// The model's normalmap: an RGB PNG of the heightmap's size, n = 2·rgb/255 − 1 (x right,
    /// y down, z towards the camera).
    #[arg(long, requires = "heightmap")]
    pub normalmap: Option<PathBuf>,
    /// The height of white in the heightmap, in half-widths of the face rectangle.
    #[arg(long, default_value_t = 0.8)]
    pub height_scale: f32,
    /// dlib's 68-landmark model: each new face's template is built on the face model warped to
    /// its landmarks. Defaults to libdlib-data's file when it is installed (not for
    /// --synthetic, whose heads are the generic model).
    #[arg(long, conflicts_with = "generic_model")]
    pub landmarks: Option<PathBuf>,
    /// Build every template on the generic face model (no landmark fit).
    #[arg(long)]
    pub generic_model: bool,
    /// Template points are not taken inside either eye's fitted outline grown by this factor
    /// (at least 1) about its centre: an eye blinks, narrows and turns with the gaze on its own,
    /// and the fit would read that as a move of the head. 0 takes the eyes like the rest.
    /// Applies where the landmarks are fitted (not with --generic-model or --synthetic).
    #[arg(long, default_value_t = FaceTrackerConfig::default().extraction.eye_outline_growth.unwrap_or(0.0), value_parser = eye_outline_growth)]
    pub eye_outline_growth: f32,
    /// Stop at the first frame that cannot be read (after writing every frame before it)
    /// instead of skipping it with a warning.
    #[arg(long)]
    pub strict: bool,
    /// Continue an interrupted run in --out instead of starting over: the frames it wrote are
    /// tracked again (each row checked against the file: different inputs or settings are
    /// refused at the first row that differs) and the run goes on from its last frame.
    #[arg(long)]
    pub resume: bool,
    /// Accept a video that ends before the length its container announces (a warning instead
    /// of a non-zero exit).
    #[arg(long)]
    pub allow_short: bool,
    /// Also write landmarks.csv: each tracked face's 68 iBUG landmarks in every frame it is
    /// tracked, in pixels — the landmarks fitted when its template was built (the generic
    /// head's where the fit failed), on the face model's surface, posed by the frame's estimate.
    /// Needs the landmark model (--landmarks, or libdlib-data's file).
    #[arg(long)]
    pub landmarks_out: bool,
    /// Print only the summary.
    #[arg(long)]
    pub quiet: bool,
    /// Read settings from a TOML file (its [face] table; keys are the long options' names,
    /// `streampf config --print-default` writes every one); options on the command line win.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    #[command(flatten)]
    pub filter: crate::filter_args::FilterArgs,
    #[command(flatten)]
    pub video: VideoArgs,
}

pub fn run(command: &FaceCommand) -> anyhow::Result<()> {
    match command {
        FaceCommand::Synth(args) => synth(args),
        FaceCommand::Track(args) => track(args),
    }
}

const RECTS_FILE: &str = "faces.csv";
/// Faces tracked at once with the detector unless --max-faces says otherwise.
const DEFAULT_MAX_FACES: u32 = 8;
const TRUTH_FILE: &str = "ground_truth.csv";
const STATES_FILE: &str = "states.csv";
const ERRORS_FILE: &str = "errors.csv";
const LANDMARKS_FILE: &str = "landmarks.csv";

/// Nodes per side of the built-in face models' grids.
const MODEL_GRID: u32 = 129;

fn model() -> anyhow::Result<FaceModel> {
    Ok(FaceModel::generic(MODEL_GRID)?)
}

fn write_text(path: &Path, text: &str) -> anyhow::Result<()> {
    std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}

fn synth(args: &SynthArgs) -> anyhow::Result<()> {
    let config = args.video.config()?;
    let model = model()?;
    run_output::claim_synthetic_dir(&args.out, args.force)?;
    remove_old_frames(&args.out)?;
    let bar = crate::console::progress_bar(config.frames, false);
    let mut truth = String::from("frame,face");
    for n in STATE_NAMES {
        truth.push(',');
        truth.push_str(n);
    }
    truth.push('\n');
    let renderer = FaceVideoRenderer::new(&config, &model)?;
    for frame in 0..config.frames {
        renderer
            .render(frame)?
            .save_png(&args.out.join(format!("frame_{frame:05}.png")))?;
        for k in 0..config.faces {
            let s = face_state(&config, k, frame);
            truth.push_str(&format!("{frame},{k}"));
            for v in s {
                truth.push_str(&format!(",{v}"));
            }
            truth.push('\n');
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    let mut rects = String::from("x,y,width,height\n");
    for k in 0..config.faces {
        let r = initial_rect(&config, k);
        rects.push_str(&format!("{},{},{},{}\n", r.x, r.y, r.width, r.height));
    }
    write_text(&args.out.join(RECTS_FILE), &rects)?;
    write_text(&args.out.join(TRUTH_FILE), &truth)?;
    outln!(
        "wrote {} frames of {}x{} with {} faces, faces.csv and ground_truth.csv to {}",
        config.frames,
        config.width,
        config.height,
        config.faces,
        args.out.display()
    );
    Ok(())
}

/// Removes the frames an earlier `face synth` left in `dir` (frame_NNNNN.png), so that the new
/// video is not mixed with the tail of a longer old one; says how many when there were some.
fn remove_old_frames(dir: &Path) -> anyhow::Result<()> {
    let mut removed = 0;
    for entry in std::fs::read_dir(dir).with_context(|| format!("reading {}", dir.display()))? {
        let path = entry
            .with_context(|| format!("reading {}", dir.display()))?
            .path();
        let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
        if name.starts_with("frame_") && name.ends_with(".png") {
            std::fs::remove_file(&path)
                .with_context(|| format!("removing the old frame {}", path.display()))?;
            removed += 1;
        }
    }
    if removed > 0 {
        errln!(
            "note: removed {removed} frames of an earlier video from {}",
            dir.display()
        );
    }
    Ok(())
}

/// Parses `x,y,width,height`.
fn parse_rect(text: &str, origin: &str) -> anyhow::Result<FaceRect> {
    let values: Vec<f32> = text
        .split(',')
        .map(|v| v.trim().parse::<f32>())
        .collect::<Result<_, _>>()
        .with_context(|| format!("{origin}: {text:?} is not x,y,width,height"))?;
    let [x, y, width, height] = values[..] else {
        bail!(
            "{origin}: {text:?} has {} values, not x,y,width,height",
            values.len()
        );
    };
    if let Some((name, value)) = ["x", "y", "width", "height"]
        .into_iter()
        .zip(values)
        .find(|(_, v)| !v.is_finite())
    {
        bail!("{origin}: {text:?} has {name} {value}: give finite numbers x,y,width,height");
    }
    Ok(FaceRect {
        x,
        y,
        width,
        height,
    })
}

/// faces.csv: `x,y,width,height` per face, with or without a header line. A first line is a
/// header when some field of it is not a number; a line of numbers is a rectangle, checked as
/// every other (so `1,2,3,4,0.9` is the same error with or without a header above it).
fn read_rects(path: &Path) -> anyhow::Result<Vec<FaceRect>> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("reading the face rectangles {}", path.display()))?;
    let has_header = text.lines().next().is_some_and(|first| {
        first
            .split(',')
            .any(|field| field.trim().parse::<f32>().is_err())
    });
    text.lines()
        .enumerate()
        .skip(usize::from(has_header))
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(n, l)| parse_rect(l, &format!("{} line {}", path.display(), n + 1)))
        .collect()
}

/// Ground truth rows `frame, face, 7 values` into `[frame][face]` (NaN where a row is missing;
/// rows beyond the tracked frames and faces are left out).
fn read_truth(path: &Path, frames: usize, faces: usize) -> anyhow::Result<Vec<Vec<[f32; DIMS]>>> {
    let mut out = vec![vec![[f32::NAN; DIMS]; faces]; frames];
    for (n, row) in read_numeric_csv(path, DIMS + 2)?.into_iter().enumerate() {
        let (frame, face) = (row[0], row[1]);
        let whole = |v: f32| v >= 0.0 && v.fract() == 0.0;
        if !(whole(frame) && whole(face)) {
            bail!(
                "{} row {}: frame {frame} and face {face} must be whole numbers >= 0",
                path.display(),
                n + 1
            );
        }
        let (frame, face) = (frame as usize, face as usize);
        // Rows for frames or faces this run does not track are not needed.
        if frame >= frames || face >= faces {
            continue;
        }
        out[frame][face].copy_from_slice(&row[2..]);
    }
    Ok(out)
}

fn open_backend(args: &TrackArgs) -> anyhow::Result<FaceBackend> {
    Ok(match args.backend {
        BackendArg::Cpu => FaceBackend::Cpu,
        BackendArg::Gpu => FaceBackend::Gpu(Box::new(crate::gpu::required(args.allow_software)?)),
        BackendArg::AllGpus => FaceBackend::Gpus(crate::gpu::all(args.allow_software)?),
        BackendArg::Auto => match crate::gpu::preferred(args.allow_software, args.quiet) {
            Some(ctx) => FaceBackend::Gpu(Box::new(ctx)),
            None => FaceBackend::Cpu,
        },
    })
}

/// Logs a tracked frame to the rerun recording: the frame, the tracks, their particle clouds
/// (read back from the filter) and, with the ground truth, their errors.
fn record_face_frame(
    recording: &Recording,
    frame: usize,
    seconds: f64,
    image: &GrayImage,
    runner: &Runner,
    estimates: &[FaceEstimate],
    truth: Option<&Vec<[f32; DIMS]>>,
) -> anyhow::Result<()> {
    let tracker = runner.tracker();
    let (shape, states, _) = tracker.particles()?;
    let clouds = FaceClouds {
        states: &states,
        particles: shape.particles,
    };
    let errors: Vec<(usize, f32, f32)> = estimates
        .iter()
        .filter(|e| e.status == TrackStatus::Tracking)
        .filter_map(|e| {
            let t = truth?.get(e.track)?;
            let (translation, rotation) = pose_errors(&e.state, t);
            Some((e.track, translation, rotation))
        })
        .collect();
    recording.face_frame(FaceFrame {
        frame,
        seconds,
        image,
        templates: &tracker.templates(),
        estimates,
        lens: tracker.lens(),
        clouds: Some(clouds),
        errors: &errors,
    })
}

/// A frame's estimates and the detections that started or restarted tracks before it.
type StepOutcome = (Vec<FaceEstimate>, Vec<(usize, FaceRect, bool)>);

/// The overlay's colour frames: the image files again, or the video decoded a second time; none
/// for a generated video or a camera (drawn in gray).
fn colour_frames(
    args: &TrackArgs,
    source: &Source,
    size: (u32, u32),
) -> anyhow::Result<Option<ColourFrames>> {
    Ok(match (source, args.input.as_deref()) {
        (Source::Images { files, .. }, _) => Some(ColourFrames::images(files.clone())),
        (Source::Video(_), Some(path)) if args.webcam.is_none() => {
            Some(ColourFrames::video(path, size)?)
        }
        _ => None,
    })
}

/// How tracks start: from rectangles given at the first frame, or from the detector thread.
enum Runner {
    Fixed(Box<FaceTracker>),
    Auto(Box<AutoTracker>),
}

impl Runner {
    /// The frame's estimates, and the tracks a detection started (`false`) or restarted
    /// (`true`) before it, with the detection's rectangle.
    fn step(&mut self, frame: &GrayImage) -> anyhow::Result<StepOutcome> {
        Ok(match self {
            Runner::Fixed(tracker) => (tracker.step(frame)?, Vec::new()),
            Runner::Auto(tracker) => {
                let stepped = tracker.step(frame)?;
                let started = stepped.started.iter().map(|&(t, r, _)| (t, r, false));
                let restarted = stepped.restarted.iter().map(|&(t, r, _)| (t, r, true));
                let detections = started.chain(restarted).collect();
                (stepped.estimates, detections)
            }
        })
    }

    fn tracker(&self) -> &FaceTracker {
        match self {
            Runner::Fixed(tracker) => tracker,
            Runner::Auto(auto) => auto.tracker(),
        }
    }

    fn set_personaliser(&mut self, personaliser: Option<Arc<Personaliser>>) {
        match self {
            Runner::Fixed(tracker) => tracker.set_personaliser(personaliser),
            Runner::Auto(auto) => auto.set_personaliser(personaliser),
        }
    }

    fn add_face(&mut self, frame: &GrayImage, rect: &FaceRect) -> anyhow::Result<usize> {
        Ok(match self {
            Runner::Fixed(tracker) => tracker.add_face(frame, rect)?,
            Runner::Auto(auto) => auto.add_face(frame, rect)?,
        })
    }
}

/// `--face-depth`: a finite scale within the face model's range, checked here so that a bad
/// value is refused before anything runs.
fn face_depth(text: &str) -> Result<f32, String> {
    let value: f32 = text.parse().map_err(|e| format!("{e}"))?;
    if face_tracker::model::FACE_DEPTH_RANGE.contains(&value) {
        Ok(value)
    } else {
        let range = face_tracker::model::FACE_DEPTH_RANGE;
        Err(format!(
            "{value}: give a scale from {} to {}",
            range.start(),
            range.end()
        ))
    }
}

/// `--eye-outline-growth`: 0 (eyes taken), or what `ExtractionConfig::eye_outline_growth`
/// accepts, a finite factor of at least 1 (an outline grown less would leave part of the eye in
/// the template), checked here so that a bad value is refused before anything runs.
fn eye_outline_growth(text: &str) -> Result<f32, String> {
    let value: f32 = text.parse().map_err(|e| format!("{e}"))?;
    if value == 0.0 || (value.is_finite() && value >= 1.0) {
        Ok(value)
    } else {
        Err(format!(
            "{value}: give 0 (take the eyes) or a factor of at least 1"
        ))
    }
}

/// The landmark fit for personalised face models: --landmarks, else libdlib-data's model when it
/// is installed (a note when it is not), none for --generic-model and --synthetic.
fn load_personaliser(args: &TrackArgs) -> anyhow::Result<Option<Arc<Personaliser>>> {
    let path = match &args.landmarks {
        Some(path) => path.clone(),
        None if args.generic_model || args.synthetic => return Ok(None),
        None => {
            let default = PathBuf::from(DEFAULT_PREDICTOR);
            if !default.is_file() {
                if !args.quiet {
                    outln!(
                        "note: no landmark model at {DEFAULT_PREDICTOR} (Debian's libdlib-data); templates use the generic face model. Install it or give --landmarks PATH to personalise them"
                    );
                }
                return Ok(None);
            }
            default
        }
    };
    let predictor = ShapePredictor::load(&path)?;
    Ok(Some(Arc::new(Personaliser::new(Arc::new(predictor))?)))
}

/// The detector where `--detector` says: `auto` follows the tracker's backend.
fn open_detector(
    args: &TrackArgs,
    cascade: Cascade,
    backend: &FaceBackend,
) -> anyhow::Result<FaceDetector> {
    let placement = match args.detector {
        DetectorArg::Auto => DetectorPlacement::Auto,
        DetectorArg::Cpu => DetectorPlacement::Cpu,
        DetectorArg::Gpu => DetectorPlacement::Gpu,
    };
    let on_gpu = placement.runs_on_gpu(backend);
    if !on_gpu {
        return Ok(FaceDetector::Cpu(cascade));
    }
    let ctx = crate::gpu::required(args.allow_software)?;
    Ok(GpuCascade::new(ctx, cascade)
        .context("building the face detector on the GPU")?
        .into())
}

fn load_cascade(path: &Path) -> anyhow::Result<Cascade> {
    if !path.exists() && path == Path::new(DEFAULT_CASCADE) {
        bail!(
            "the face detector's cascade {DEFAULT_CASCADE} is missing: install Debian's opencv-data (apt-get install opencv-data), give --cascade PATH to an OpenCV Haar cascade XML, or start from rectangles with --face x,y,width,height"
        );
    }
    Ok(Cascade::load(path)?)
}

#[cfg(feature = "webcam")]
fn webcam_source(device: &Path, size: &str) -> anyhow::Result<Source> {
    let (w, h) = size
        .split_once('x')
        .and_then(|(w, h)| Some((w.parse::<u32>().ok()?, h.parse::<u32>().ok()?)))
        .filter(|&(w, h)| (16..=8192).contains(&w) && (16..=8192).contains(&h))
        .with_context(|| format!("--webcam-size {size:?} is not WIDTHxHEIGHT (16 to 8192)"))?;
    Ok(Source::Video(Box::new(crate::video::VideoReader::webcam(
        device, w, h,
    )?)))
}

#[cfg(not(feature = "webcam"))]
fn webcam_source(_device: &Path, _size: &str) -> anyhow::Result<Source> {
    bail!(
        "this streampf was built without webcam support: build it with `cargo build --release -p streampf --features webcam`"
    )
}

/// Frames, the starting rectangles (faces.csv or none) and the ground truth when known.
type Input = (Source, Vec<FaceRect>, Option<Vec<Vec<[f32; DIMS]>>>);

fn open_input(args: &TrackArgs) -> anyhow::Result<Input> {
    if args.synthetic {
        let config = args.video.config()?;
        let rects = (0..config.faces)
            .map(|k| initial_rect(&config, k))
            .collect();
        let truth: Vec<Vec<[f32; DIMS]>> = (0..config.frames)
            .map(|f| {
                (0..config.faces)
                    .map(|k| face_state(&config, k, f))
                    .collect()
            })
            .collect();
        let source = Source::Synthetic {
            renderer: Box::new(FaceVideoRenderer::new(&config, &model()?)?),
            next: 0,
        };
        return Ok((source, rects, Some(truth)));
    }
    if let Some(device) = &args.webcam {
        return Ok((webcam_source(device, &args.webcam_size)?, Vec::new(), None));
    }
    let input = args
        .input
        .as_deref()
        .context("give a video file or a directory of frames (or --synthetic)")?;
    let source = Source::open(input)?;
    if !input.is_dir() {
        return Ok((source, Vec::new(), None));
    }
    let rects = if input.join(RECTS_FILE).exists() {
        read_rects(&input.join(RECTS_FILE))?
    } else {
        Vec::new()
    };
    let truth = if input.join(TRUTH_FILE).exists() {
        Some(read_truth(
            &input.join(TRUTH_FILE),
            source.len().unwrap_or(0),
            rects.len().max(args.faces_at.len()),
        )?)
    } else {
        None
    };
    Ok((source, rects, truth))
}

fn track(args: &TrackArgs) -> anyhow::Result<()> {
    let (mut source, mut rects, truth) = open_input(args)?;
    if !args.faces_at.is_empty() {
        rects = args
            .faces_at
            .iter()
            .map(|r| parse_rect(r, "--face"))
            .collect::<anyhow::Result<_>>()?;
    }
    if let Some(path) = &args.overlay {
        Annotated::check_path(path)?;
        Annotated::check_not_input(path, args.input.as_deref())?;
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
        .map(|path| Recording::create(path, "streampf face track"))
        .transpose()?;
    // Held to the end of the run: nothing below touches --out before it is ours.
    let _lock = OutputLock::acquire(&args.out)?;
    let resume = args
        .resume
        .then(|| ResumePoint::of(&args.out.join(STATES_FILE), &TrackRecord::states_header()))
        .transpose()?;
    if let Some(point) = &resume {
        point.check_limit(args.max_frames, &args.out.join(STATES_FILE))?;
    }
    if let Some(max) = args.max_faces
        && rects.len() > max as usize
    {
        bail!(
            "{} face rectangles were given but --max-faces is {max}: give fewer rectangles or a larger --max-faces",
            rects.len()
        );
    }
    let detect = rects.is_empty() || args.detect;
    // Errors against the ground truth need track k to be face k: tracks from rectangles only.
    let truth = truth.filter(|_| !detect);
    let first = source
        .next_frame()
        .context("frame 0 (the first frame must be readable: it starts the tracks)")?
        .context("the input has no frames")?;
    let size = (first.width, first.height);
    let (mut runner, backend_name) = build_runner(args, size, &rects, detect)?;
    for (i, r) in rects.iter().enumerate() {
        runner
            .add_face(&first, r)
            .with_context(|| format!("face {i}"))?;
    }
    if resume.is_none() {
        clear_old_results(&args.out, &[STATES_FILE, ERRORS_FILE, LANDMARKS_FILE])?;
    }
    if let Some(dir) = &args.save_particles {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("--save-particles: creating {}", dir.display()))?;
    }
    let overlay = match &args.overlay {
        Some(path) => Some(FaceOverlay::new(
            Annotated::create(path, size.0, size.1, source.fps())?,
            colour_frames(args, &source, size)?,
            runner.tracker().lens(),
        )),
        None => None,
    };
    let limit = args.max_frames.map_or(usize::MAX, |n| n as usize);
    let frames_known = source.len().map(|n| n.min(limit));
    if !args.quiet {
        announce(args, detect, rects.len(), frames_known, size, &backend_name);
        if let Some(point) = &resume {
            outln!(
                "resuming at frame {}: the frames before it are tracked again and checked against {}",
                point.frame,
                args.out.join(STATES_FILE).display()
            );
        }
    }
    let mut run = FaceRun {
        args,
        record: TrackRecord::create(
            &args.out,
            (truth.is_some(), args.landmarks_out),
            resume.as_ref(),
            source.fps(),
        )?,
        resume_from: resume.as_ref().map_or(0, |p| p.frame),
        truth,
        overlay,
        recording,
        last_estimates: Vec::new(),
        skipped: SkipLog::new(&args.out)?,
        frames: 0,
    };
    let started = Instant::now();
    // The first frame was read above; the rest are read ahead on their own thread.
    let mut frames = ReadAhead::start(source, limit.saturating_sub(1))?;
    let mut ended = run.track_frames(&mut runner, &mut frames, first, limit, frames_known);
    let elapsed = started.elapsed().as_secs_f64();
    let source = match frames.finish() {
        Ok(source) => Some(source),
        Err(e) => {
            if matches!(ended, LoopEnd::Done) {
                ended = LoopEnd::Failed(e);
            }
            None
        }
    };
    run.finish(&runner, source.as_ref(), elapsed, ended)
}

/// Why the frame loop ended.
enum LoopEnd {
    /// The source ran out, or --max-frames was reached.
    Done,
    Interrupted,
    /// A frame could not be tracked or written (or, with --strict, read).
    Failed(anyhow::Error),
}

/// A face run in progress: what it writes as it goes, and what it has seen.
struct FaceRun<'a> {
    args: &'a TrackArgs,
    record: TrackRecord,
    truth: Option<Vec<Vec<[f32; DIMS]>>>,
    overlay: Option<FaceOverlay>,
    /// `--rerun`: every frame, replayed ones included, so the recording covers the whole run.
    recording: Option<Recording>,
    /// The last tracked frame's estimates: a skipped frame's tracks coast on them.
    last_estimates: Vec<FaceEstimate>,
    skipped: SkipLog,
    /// A resumed run's first frame to write: earlier ones are only checked against the files.
    resume_from: usize,
    /// Frames finished and written (tracked or skipped).
    frames: usize,
}

impl FaceRun<'_> {
    /// Tracks frame after frame, writing each as it is finished, until the source ends, the
    /// limit, an interrupt or a failure.
    fn track_frames(
        &mut self,
        runner: &mut Runner,
        source: &mut ReadAhead,
        first: GrayImage,
        limit: usize,
        frames_known: Option<usize>,
    ) -> LoopEnd {
        let bar = crate::console::progress_bar(frames_known.unwrap_or(0), self.args.quiet);
        let mut stream = InFlight::for_run(runner, self.args);
        self.record.frames_in_flight = stream.is_some();
        let mut next = FrameRead::Frame(first);
        // The frame `next` holds: frames in flight are read but not yet written.
        let mut frame = 0;
        let end = loop {
            // Each error names its frame (with frames in flight, the one that failed).
            let in_this_frame = |e: anyhow::Error| e.context(format!("frame {frame}"));
            let result = match next {
                FrameRead::End => break LoopEnd::Done,
                FrameRead::Frame(image) => match stream.as_mut() {
                    Some(in_flight) => self.submit_one(runner, in_flight, frame, image, &bar),
                    None => (self.track_one(runner, frame, &image))
                        .map(|()| self.written(&bar))
                        .map_err(in_this_frame),
                },
                FrameRead::Unreadable(e) => (self.finish_in_flight(runner, stream.as_mut(), &bar))
                    .and_then(|()| self.skip_one(frame, e).map_err(in_this_frame))
                    .map(|()| self.written(&bar)),
            };
            if let Err(e) = result {
                break LoopEnd::Failed(e);
            }
            frame += 1;
            if run_output::stop_requested() {
                break LoopEnd::Interrupted;
            }
            if frame >= limit {
                break LoopEnd::Done;
            }
            next = match source.read_next() {
                Ok(read) => read,
                Err(e) => break LoopEnd::Failed(e.context(format!("frame {frame}"))),
            };
        };
        // The frames still in flight are finished and written however the loop ended: a
        // failure loses only what cannot be finished.
        let end = match (self.finish_in_flight(runner, stream.as_mut(), &bar), end) {
            (Err(e), LoopEnd::Done | LoopEnd::Interrupted) => LoopEnd::Failed(e),
            (_, end) => end,
        };
        bar.finish_and_clear();
        end
    }

    /// One more frame written (tracked or skipped).
    fn written(&mut self, bar: &indicatif::ProgressBar) {
        self.frames += 1;
        bar.inc(1);
    }

    fn track_one(
        &mut self,
        runner: &mut Runner,
        frame: usize,
        image: &GrayImage,
    ) -> anyhow::Result<()> {
        run_output::maybe_simulate_gpu_fault(frame, runner.tracker().gpu_context());
        let step_started = Instant::now();
        let (estimates, detections) = runner.step(image)?;
        self.record.tracking_time += step_started.elapsed().as_secs_f64();
        self.record.gpu_time += crate::gpu::gpu_seconds(runner.tracker().last_gpu_time());
        self.write_frame(runner, frame, image, estimates, detections)
    }

    /// Writes a tracked frame's results: states (and errors, landmarks), particles, the
    /// recording and the overlay.
    fn write_frame(
        &mut self,
        runner: &Runner,
        frame: usize,
        image: &GrayImage,
        estimates: Vec<FaceEstimate>,
        detections: Vec<(usize, FaceRect, bool)>,
    ) -> anyhow::Result<()> {
        let replayed = frame < self.resume_from;
        if let Some(dir) = self.args.save_particles.as_ref().filter(|_| !replayed) {
            save_particles(dir, frame, runner.tracker(), &estimates).context("--save-particles")?;
        }
        let truth = self.truth.as_ref().and_then(|t| t.get(frame));
        self.record.add(frame, &estimates, "", truth)?;
        self.record.add_landmarks(
            frame,
            &runner.tracker().templates(),
            &estimates,
            &runner.tracker().lens(),
        )?;
        if let Some(recording) = &self.recording {
            record_face_frame(
                recording,
                frame,
                self.record.seconds(frame),
                image,
                runner,
                &estimates,
                truth,
            )
            .context("--rerun")?;
        }
        if let Some(overlay) = self.overlay.as_mut() {
            let templates = runner.tracker().templates();
            overlay.draw(frame, image, &templates, &estimates, detections, !replayed)?;
        }
        self.last_estimates = estimates;
        Ok(())
    }

    /// A frame that cannot be read: an error with --strict; else a warning, and every track
    /// coasts through it (rows with status `skipped` holding its last estimate).
    fn skip_one(&mut self, frame: usize, error: anyhow::Error) -> anyhow::Result<()> {
        if self.args.strict {
            return Err(error.context("unreadable frame (--strict)"));
        }
        self.skipped.record(frame, &error)?;
        let coasting: Vec<FaceEstimate> = (self.last_estimates.iter())
            .filter(|e| e.status == TrackStatus::Tracking)
            .cloned()
            .collect();
        self.record.add(frame, &coasting, "skipped", None)?;
        if let Some(overlay) = self.overlay.as_mut() {
            overlay.repeat_last(frame)?;
        }
        Ok(())
    }

    /// Closes the files (the overlay video is finalised), prints the summary, and says how the
    /// run ended: interrupted, failed, or a video shorter than announced (unless --allow-short).
    fn finish(
        mut self,
        runner: &Runner,
        source: Option<&Source>,
        elapsed: f64,
        end: LoopEnd,
    ) -> anyhow::Result<()> {
        let closed = self.overlay.take().map_or(Ok(()), FaceOverlay::finish);
        // Flushed whatever ended the run: the recording keeps every frame it had.
        let closed = closed.and(self.recording.take().map_or(Ok(()), Recording::finish));
        let written = matches!(end, LoopEnd::Done);
        self.record.summary(
            self.args,
            runner,
            self.frames,
            elapsed,
            &self.skipped,
            written,
        );
        if let Runner::Auto(auto) = runner
            && let Some(why) = auto.detector_fallback()
        {
            errln!("warning: the detector's GPU failed ({why}); it ran on the CPU from then on");
        }
        match end {
            LoopEnd::Failed(e) => {
                return Err(run_output::stopped(e, self.frames, &self.args.out));
            }
            LoopEnd::Interrupted => {
                closed?;
                return Err(Interrupted {
                    frames: self.frames,
                    out: self.args.out.clone(),
                }
                .into());
            }
            LoopEnd::Done => closed?,
        }
        // The reader ended normally when the loop did (a failed reader is a failed loop).
        let Some(source) = source else {
            return Ok(());
        };
        let messages: Vec<&str> = source.decoder_messages().lines().collect();
        if !self.skipped.frames.is_empty() && !messages.is_empty() {
            errln!(
                "FFmpeg said while decoding (last lines): {}",
                messages[messages.len().saturating_sub(4)..].join("\n")
            );
        }
        if let Some(short) = source
            .short_end()
            .filter(|_| self.frames < self.args.max_frames.map_or(usize::MAX, |n| n as usize))
        {
            if self.args.allow_short {
                errln!("warning: {short}");
            } else {
                bail!(
                    "{short}; the {} frames decoded were tracked and written (--allow-short accepts a short video)",
                    self.frames
                );
            }
        }
        Ok(())
    }
}

/// The tracker for `args` on the backend it asks for: the automatic tracker with the detector
/// when `detect`, else a tracker with room for the given rectangles; and the backend's name.
fn build_runner(
    args: &TrackArgs,
    size: (u32, u32),
    rects: &[FaceRect],
    detect: bool,
) -> anyhow::Result<(Runner, String)> {
    // The built-in model: the photographed head for real input (auto) or when asked for, the
    // generic head for the synthetic video (whose heads are the generic model) or when asked for.
    let photographed = args.heightmap.is_none()
        && matches!(
            (args.face_model, args.synthetic),
            (FaceModelArg::Photographed, _) | (FaceModelArg::Auto, false)
        );
    if args.face_depth != 1.0 && !photographed {
        bail!(
            "--face-depth scales the photographed head's face; this run's model is {} (give --face-model photographed)",
            if args.heightmap.is_some() {
                "your --heightmap"
            } else {
                "the generic head"
            }
        );
    }
    // (clap has a --heightmap come with its --normalmap)
    let face_model = match (&args.heightmap, &args.normalmap) {
        (Some(h), Some(n)) => FaceModel::load(h, n, args.height_scale)?,
        _ if photographed => FaceModel::photographed_with_face_depth(MODEL_GRID, args.face_depth)?,
        _ => model()?,
    };
    let defaults = FaceTrackerConfig::default();
    let config = FaceTrackerConfig {
        particles: args.particles as usize,
        best: (args.particles as usize / 10).max(1),
        seed: args.seed,
        failure_error: args.failure_error,
        failure_frames: args.failure_frames as usize,
        annealing: args.filter.apply(&defaults.annealing)?,
        motion: args.filter.motion(defaults.motion)?,
        extraction: ExtractionConfig {
            eye_outline_growth: (args.eye_outline_growth > 0.0).then_some(args.eye_outline_growth),
            ..defaults.extraction
        },
        focal_length: (args.video.fov)
            .map(|fov| focal_length(fov, size.0))
            .transpose()?,
        ..defaults
    };
    let cascade = if detect {
        Some(load_cascade(&args.cascade)?)
    } else {
        None
    };
    let backend = open_backend(args)?;
    let backend_name = match &backend {
        FaceBackend::Cpu => format!("CPU ({} threads)", rayon::current_num_threads()),
        FaceBackend::Gpu(ctx) => format!("GPU: {}", ctx.adapter().name),
        FaceBackend::Gpus(contexts) => format!(
            "{} GPUs, a share of the faces on each: {}",
            contexts.len(),
            (contexts.iter().map(|c| c.adapter().name.clone()))
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    let personaliser = load_personaliser(args)?;
    if args.landmarks_out && personaliser.is_none() {
        bail!(
            "--landmarks-out needs dlib's 68-landmark model: give --landmarks FILE, or install \
             Debian's libdlib-data (not used by default with --generic-model or --synthetic)"
        );
    }
    let detector = match cascade {
        Some(cascade) => Some(open_detector(args, cascade, &backend)?),
        None => None,
    };
    let backend_name = match &detector {
        Some(detector) => format!("{backend_name}, the detector on {}", detector.device_name()),
        None => backend_name,
    };
    let mut runner = match detector {
        Some(detector) => {
            let auto = AutoConfig {
                detect_every: args.detect_every as usize,
                detect: DetectConfig {
                    min_size: args.min_face,
                    ..DetectConfig::default()
                },
                max_faces: (args.max_faces.unwrap_or(DEFAULT_MAX_FACES) as usize).max(rects.len()),
                // A file waits for each detection at its fixed delay (runs repeat); a camera
                // never waits for it.
                detection_delay: args
                    .webcam
                    .is_none()
                    .then_some(args.detection_delay as usize),
                tracker: config,
                ..AutoConfig::default()
            };
            Runner::Auto(Box::new(AutoTracker::new(
                size,
                detector,
                &face_model,
                auto,
                backend,
            )?))
        }
        None => Runner::Fixed(Box::new(FaceTracker::with_capacity(
            size,
            rects.len(),
            &face_model,
            config,
            backend,
        )?)),
    };
    runner.set_personaliser(personaliser);
    Ok((runner, backend_name))
}

/// The line that says what is about to be tracked.
fn announce(
    args: &TrackArgs,
    detect: bool,
    rectangles: usize,
    frames: Option<usize>,
    size: (u32, u32),
    backend_name: &str,
) {
    let starts = if detect {
        format!(
            "faces found by the detector ({} every {} frames)",
            args.cascade.display(),
            args.detect_every
        )
    } else {
        match rectangles {
            1 => "1 face from its rectangle".to_string(),
            n => format!("{n} faces from their rectangles"),
        }
    };
    let length = frames.map_or("frames".to_string(), |n| format!("{n} frames"));
    outln!(
        "tracking {starts} through {length} of {}x{}, {} particles each, on {backend_name}",
        size.0,
        size.1,
        args.particles
    );
}

/// What a run has tracked: states.csv and (with ground truth) errors.csv, written as each frame
/// is finished, the error sums and the time spent in the tracker.
/// The columns of a states.csv row after `status`: the state, the residual, the spreads, the ESS,
/// the confidence, three angles and a quaternion.
const STATE_COLUMNS_AFTER_STATUS: usize = DIMS + 1 + DIMS + 2 + 3 + 4;

struct TrackRecord {
    states: CsvStream,
    errors: Option<CsvStream>,
    landmarks: Option<CsvStream>,
    translation: f64,
    rotation: f64,
    measured: usize,
    /// Per state dimension, the face-frames whose true value lay within ±2 reported standard
    /// deviations of the estimate (with ground truth).
    within_two_sd: [usize; DIMS],
    tracks_seen: std::collections::BTreeSet<usize>,
    /// Seconds in the tracker's calls, and the GPU's own seconds for the frames (timestamps):
    /// with frames in flight the GPU works while the host waits for the next frame, so the
    /// tracker's time is the longer of the two.
    tracking_time: f64,
    gpu_time: f64,
    /// Whether the frames were tracked with two in flight (`face/in_flight.rs`).
    frames_in_flight: bool,
    /// Frames per second of the input: a row's timestamp is its frame / this.
    fps: f64,
}

impl TrackRecord {
    /// The frame, its timestamp, the track, whether it is tracked, its status, the state, ε (the
    /// residual), then how sure the estimate is (the posterior's spread per dimension, the ESS,
    /// the confidence) and the rotation as degrees and as a quaternion (docs/OUTPUT.md).
    fn states_header() -> String {
        let spreads: Vec<String> = STATE_NAMES.iter().map(|n| format!("sd_{n}")).collect();
        format!(
            "frame,timestamp,track,success,status,{},residual,{},ess,confidence,pitch_deg,yaw_deg,roll_deg,qw,qx,qy,qz",
            STATE_NAMES.join(","),
            spreads.join(",")
        )
    }

    /// The frame, its timestamp, the track, then x and y of each of the 68 iBUG landmarks.
    fn landmarks_header() -> String {
        let columns: Vec<String> = (0..68).map(|k| format!("x{k},y{k}")).collect();
        format!("frame,timestamp,track,{}", columns.join(","))
    }

    /// A frame's landmark rows: each tracked face whose template has landmarks, posed by its
    /// estimate.
    fn add_landmarks(
        &mut self,
        frame: usize,
        templates: &[(usize, &face_tracker::Template)],
        estimates: &[FaceEstimate],
        lens: &face_tracker::likelihood::Lens,
    ) -> anyhow::Result<()> {
        let timestamp = self.timestamp(frame);
        let Some(file) = self.landmarks.as_mut() else {
            return Ok(());
        };
        for e in estimates
            .iter()
            .filter(|e| e.status == TrackStatus::Tracking)
        {
            let landmarks = templates
                .iter()
                .find(|(track, _)| *track == e.track)
                .and_then(|(_, t)| t.landmarks.as_ref());
            let Some(landmarks) = landmarks else { continue };
            let pose = face_tracker::Pose::new(&e.state);
            let pixels: Vec<String> = landmarks
                .iter()
                .map(|&p| {
                    // A landmark at or behind the camera (never on a tracked face) is left empty.
                    (pose.project_through(&nalgebra::Vector3::from(p), lens))
                        .map_or_else(|| ",".to_string(), |at| format!("{},{}", at.x, at.y))
                })
                .collect();
            file.row(&format!(
                "{frame},{timestamp},{},{}",
                e.track,
                pixels.join(",")
            ))?;
        }
        file.end_frame()
    }

    /// A frame's timestamp in seconds (frame / frames per second).
    fn timestamp(&self, frame: usize) -> String {
        format!("{:.6}", self.seconds(frame))
    }

    fn seconds(&self, frame: usize) -> f64 {
        frame as f64 / self.fps
    }

    /// The columns after the state and ε (see [`TrackRecord::states_header`]).
    fn certainty_columns(e: &FaceEstimate) -> String {
        let join = |values: &[f32]| {
            values
                .iter()
                .map(|v| v.to_string())
                .collect::<Vec<_>>()
                .join(",")
        };
        format!(
            "{},{},{},{},{}",
            join(&e.spread),
            e.ess,
            e.confidence,
            join(&pitch_yaw_roll_degrees(&e.state)),
            join(&rotation_quaternion(&e.state))
        )
    }

    /// The files, new or (`resume`) an interrupted run's reopened at its resume point.
    /// `(with_truth, with_landmarks)`: whether errors.csv and landmarks.csv are written.
    fn create(
        out: &Path,
        (with_truth, with_landmarks): (bool, bool),
        resume: Option<&ResumePoint>,
        fps: f64,
    ) -> anyhow::Result<Self> {
        let open = |name: &str, header: &str| match resume {
            Some(point) => CsvStream::resume(&out.join(name), header, point),
            None => CsvStream::create(&out.join(name), header),
        };
        let errors = with_truth
            .then(|| open(ERRORS_FILE, "frame,face,translation_px,rotation_deg"))
            .transpose()?;
        let landmarks = with_landmarks
            .then(|| open(LANDMARKS_FILE, &Self::landmarks_header()))
            .transpose()?;
        Ok(Self {
            states: open(STATES_FILE, &Self::states_header())?,
            errors,
            landmarks,
            translation: 0.0,
            rotation: 0.0,
            measured: 0,
            within_two_sd: [0; DIMS],
            tracks_seen: std::collections::BTreeSet::new(),
            fps: if fps.is_finite() && fps > 0.0 {
                fps
            } else {
                25.0
            },
            tracking_time: 0.0,
            gpu_time: 0.0,
            frames_in_flight: false,
        })
    }

    /// One frame's rows (status `status` when given, else each estimate's own), their errors
    /// where the ground truth (`truth[track]`) is known; flushed to the files.
    fn add(
        &mut self,
        frame: usize,
        estimates: &[FaceEstimate],
        status: &str,
        truth: Option<&Vec<[f32; DIMS]>>,
    ) -> anyhow::Result<()> {
        // A frame whose rows fail to write is dropped from the files (CsvStream), and from the
        // summary's error statistics with it.
        let before = (
            self.translation,
            self.rotation,
            self.measured,
            self.within_two_sd,
        );
        let written = self.add_rows(frame, estimates, status, truth);
        if written.is_err() {
            (
                self.translation,
                self.rotation,
                self.measured,
                self.within_two_sd,
            ) = before;
        }
        written
    }

    fn add_rows(
        &mut self,
        frame: usize,
        estimates: &[FaceEstimate],
        status: &str,
        truth: Option<&Vec<[f32; DIMS]>>,
    ) -> anyhow::Result<()> {
        let timestamp = self.timestamp(frame);
        if estimates.is_empty() {
            // No face this frame: a row that says so, its estimate's columns empty.
            let word = if status.is_empty() { "none" } else { status };
            let empty = ",".repeat(STATE_COLUMNS_AFTER_STATUS);
            self.states
                .row(&format!("{frame},{timestamp},,0,{word}{empty}"))?;
        }
        for e in estimates {
            self.tracks_seen.insert(e.track);
            let status = match e.status {
                _ if !status.is_empty() => status.to_string(),
                TrackStatus::Tracking => "tracking".to_string(),
                TrackStatus::Lost { frame } => format!("lost@{frame}"),
            };
            let success = u8::from(status == "tracking");
            let values: Vec<String> = e.state.iter().map(|v| v.to_string()).collect();
            self.states.row(&format!(
                "{frame},{timestamp},{},{success},{status},{},{},{}",
                e.track,
                values.join(","),
                e.error,
                Self::certainty_columns(e)
            ))?;
            let known = truth.and_then(|f| f.get(e.track));
            if let (Some(t), TrackStatus::Tracking, Some(errors)) =
                (known, e.status, self.errors.as_mut())
                && t.iter().all(|v| v.is_finite())
            {
                let (te, re) = pose_errors(&e.state, t);
                errors.row(&format!("{frame},{},{te},{re}", e.track))?;
                self.translation += f64::from(te);
                self.rotation += f64::from(re);
                self.measured += 1;
                for (d, &true_value) in t.iter().enumerate() {
                    let mut miss = e.state[d] - true_value;
                    if d == RZ {
                        miss = pf_core::batch::wrap_angle_floor(miss);
                    }
                    self.within_two_sd[d] += usize::from(miss.abs() <= 2.0 * e.spread[d]);
                }
            }
        }
        match self.errors.as_mut() {
            Some(errors) => CsvStream::end_frame_in_all(&mut [&mut self.states, errors]),
            None => self.states.end_frame(),
        }
    }

    /// Prints the summary of what was tracked and written.
    fn summary(
        &self,
        args: &TrackArgs,
        runner: &Runner,
        frames: usize,
        elapsed: f64,
        skipped: &SkipLog,
        // Whether the run ended well: a stopped one says what it wrote in its error instead.
        written: bool,
    ) {
        let faces = self.tracks_seen.len();
        outln!(
            "tracked {faces} face{} through {frames} frames in {elapsed:.2} s: {:.1} frames/s in the tracker{}, {:.1} frames/s with reading{}{}",
            if faces == 1 { "" } else { "s" },
            frames as f64 / self.tracking_time.max(self.gpu_time).max(1e-9),
            if self.frames_in_flight {
                " (two frames in flight)"
            } else {
                ""
            },
            frames as f64 / elapsed.max(1e-9),
            if args.overlay.as_deref().is_some() {
                " and drawing"
            } else {
                ""
            },
            skipped.note(),
        );
        let (personalised, missed) = runner.tracker().personalisation_counts();
        if personalised + missed > 0 {
            outln!(
                "face model personalised to the landmarks of {personalised} of {} template{}{}",
                personalised + missed,
                if personalised + missed == 1 { "" } else { "s" },
                if missed > 0 {
                    format!(" (the landmark fit missed {missed}: generic model)")
                } else {
                    String::new()
                }
            );
        }
        let measured = self.measured;
        if measured > 0 {
            outln!(
                "mean translation error: {:.2} px, mean rotation error: {:.2} deg ({measured} face-frames)",
                self.translation / measured as f64,
                self.rotation / measured as f64
            );
            let coverage: Vec<String> = STATE_NAMES
                .iter()
                .zip(self.within_two_sd)
                .map(|(n, k)| format!("{n} {:.0}%", 100.0 * k as f64 / measured as f64))
                .collect();
            outln!(
                "truth within ±2 reported sd: {} (about 95% for an honest spread)",
                coverage.join(", ")
            );
        }
        if !written {
            return;
        }
        outln!(
            "wrote states.csv{}{} to {}{}",
            if self.errors.is_some() {
                ", errors.csv"
            } else {
                ""
            },
            if self.landmarks.is_some() {
                ", landmarks.csv"
            } else {
                ""
            },
            args.out.display(),
            args.overlay.as_deref().map_or(String::new(), |p| format!(
                ", the annotated frames to {}",
                p.display()
            ))
        );
    }
}

/// One frame's clouds as numpy files, with the track that runs in each slot (-1: free).
fn save_particles(
    dir: &Path,
    frame: usize,
    tracker: &FaceTracker,
    estimates: &[face_tracker::FaceEstimate],
) -> anyhow::Result<()> {
    let (shape, states, log_weights) = tracker.particles()?;
    pf_numpy::write_particles(dir, frame, &shape, &states, &log_weights)?;
    let mut tracks = vec![-1.0f32; shape.targets];
    for e in estimates
        .iter()
        .filter(|e| e.status == TrackStatus::Tracking)
    {
        if let Some(slot) = tracks.get_mut(e.slot) {
            *slot = e.track as f32;
        }
    }
    pf_numpy::write_f32(
        &dir.join(format!("tracks_{frame:06}.npy")),
        &[shape.targets],
        &tracks,
    )?;
    Ok(())
}
