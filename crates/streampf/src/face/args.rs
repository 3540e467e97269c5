//! The command line of `streampf face`: each command's arguments and their value parsers.

use anyhow::bail;
use clap::{Args, ValueEnum};
use face_tracker::FaceTrackerConfig;
use face_tracker::detect::DEFAULT_CASCADE;
use face_tracker::synth::FaceSynthConfig;
use std::path::PathBuf;

#[derive(Debug, Clone, Args)]
pub struct VideoArgs {
    /// Frames to generate [default: 100; 300 with --scenario, the length its timings are
    /// measured at].
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=100_000))]
    pub frames: Option<u32>,
    /// Faces in the video (1 to 16; the paper's Fig. 1 has four).
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=16))]
    pub faces: u32,
    /// Frame width in pixels (at least 160: the heads scale with the frame and need 8 px of half-width).
    #[arg(long, default_value_t = 1024, value_parser = clap::value_parser!(u32).range(160..=8192))]
    pub width: u32,
    /// Frame height in pixels (at least 120).
    #[arg(long, default_value_t = 768, value_parser = clap::value_parser!(u32).range(120..=8192))]
    pub height: u32,
    /// The heads' width in pixels, at scale 1 (16 to the frame's height; default: 120 at
    /// 1024x768, scaled with the frame). Small faces, as in a crowd or a wide shot: 40-60.
    #[arg(long, value_parser = clap::value_parser!(u32).range(16..=8192))]
    pub face_width: Option<u32>,
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
    /// A named ground-truth scenario for identities, replacing --faces: `exits-and-crossings`,
    /// four faces, the first walking out at 15 % of the video and turning back at 40 %, two
    /// crossing each other's path from 65 %. `face track --synthetic --scenario` finds the faces
    /// with the detector and prints IDF1, identity switches and MOTA (docs/ACCURACY.md).
    #[arg(long, value_enum)]
    pub scenario: Option<ScenarioArg>,
}

/// `--identities`: whether a face found again keeps its identity.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum IdentitiesArg {
    On,
    Off,
}

/// `--scenario`: the named ground-truth videos.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ScenarioArg {
    ExitsAndCrossings,
}

/// `--frames` unless given: the paper's 100 frames.
const DEFAULT_FRAMES: usize = 100;
/// `--frames` unless given, with `--scenario`: the length at which the scenario's scores are
/// measured (docs/ACCURACY.md, "Identities"). Its events fall at shares of the video, so 100
/// frames squeeze a walk out and back into 25 frames, faster than the detector confirms a face.
const SCENARIO_FRAMES: usize = 300;

impl VideoArgs {
    /// The frames to generate: `--frames`, else [`SCENARIO_FRAMES`] for a scenario and
    /// [`DEFAULT_FRAMES`] otherwise.
    pub(super) fn frames(&self) -> usize {
        match (self.frames, self.scenario) {
            (Some(frames), _) => frames as usize,
            (None, Some(_)) => SCENARIO_FRAMES,
            (None, None) => DEFAULT_FRAMES,
        }
    }

    pub(super) fn config(&self) -> anyhow::Result<FaceSynthConfig> {
        // Checked here in the option's own unit (the config holds radians).
        if !(self.max_yaw.is_finite() && self.max_yaw.abs() <= 90.0) {
            bail!("--max-yaw must be within ±90 degrees, got {}", self.max_yaw);
        }
        let mut config = FaceSynthConfig {
            width: self.width,
            height: self.height,
            frames: self.frames(),
            faces: self.faces as usize,
            half_width: self.face_width.map_or_else(
                || 60.0 * (self.width as f32 / 1024.0).min(self.height as f32 / 768.0),
                |width| width as f32 / 2.0,
            ),
            max_yaw: self.max_yaw.to_radians(),
            occlusion: true,
            exit_after: None,
            return_at: None,
            walk_speed: face_tracker::synth::WALK_SPEED_AT_PAPER_WIDTH,
            crossing_at: None,
            enter_every: 0,
            distinct_people: false,
            seed: self.video_seed,
            focal_length: self
                .fov
                .map(|fov| focal_length(fov, self.width))
                .transpose()?,
        };
        if self.scenario == Some(ScenarioArg::ExitsAndCrossings) {
            config = config.exits_and_crossings(self.frames());
        }
        if let Some(width) = self.face_width
            && width > self.height
        {
            bail!(
                "--face-width {width} does not fit a frame {} pixels high",
                self.height
            );
        }
        config.validate()?;
        Ok(config)
    }
}

/// `--failure-error`: within (0, 1], as ε is (a fit's robust residual, in [0, 1)).
pub(super) fn failure_error(text: &str) -> Result<f32, String> {
    let value: f32 = text.parse().map_err(|e| format!("{e}"))?;
    if value > 0.0 && value <= 1.0 {
        Ok(value)
    } else {
        Err(format!(
            "{value}: give a fit error ε above 0 and at most 1 (ε lies in [0, 1); 1 never ends a track)"
        ))
    }
}

/// `--scene-cut`: a histogram change within (0, 2), or `off`.
pub(super) fn scene_cut(text: &str) -> Result<SceneCutArg, String> {
    if text == "off" {
        return Ok(SceneCutArg(None));
    }
    let value: f32 = text
        .parse()
        .map_err(|e| format!("{text}: give a number or `off` ({e})"))?;
    if value > 0.0 && value < 2.0 {
        Ok(SceneCutArg(Some(value)))
    } else {
        Err(format!(
            "{value}: give a histogram change above 0 and below 2 (0 the same levels, 2 none in common), or `off`"
        ))
    }
}

/// `--scene-cut`'s value: a threshold, or `None` for `off`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SceneCutArg(pub Option<f32>);

impl std::fmt::Display for SceneCutArg {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.0 {
            Some(threshold) => write!(f, "{threshold}"),
            None => f.write_str("off"),
        }
    }
}

/// `--fov`: degrees, within `Lens::FIELD_OF_VIEW`.
pub(super) fn field_of_view(text: &str) -> Result<f32, String> {
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
pub(super) fn focal_length(fov: f32, width: u32) -> anyhow::Result<f32> {
    Ok(face_tracker::likelihood::Lens::focal_length_for(
        fov, width,
    )?)
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

pub use crate::gpu::BackendArg;

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

impl From<FaceModelArg> for face_tracker::model::BuiltInModel {
    fn from(arg: FaceModelArg) -> Self {
        match arg {
            FaceModelArg::Auto => Self::Auto,
            FaceModelArg::Generic => Self::Generic,
            FaceModelArg::Photographed => Self::Photographed,
        }
    }
}

/// What `face track` writes beside states.csv.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum FormatArg {
    /// streampf's own files (states.csv; the others as asked).
    Streampf,
    /// Also openface.csv: OpenFace 2.0's FeatureExtraction columns in its units and conventions
    /// (docs/OUTPUT.md). Needs the landmark model.
    Openface,
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
    /// The camera's intrinsics in pixels, fx,fy,cx,cy (OpenCV's camera matrix): faces are seen
    /// through that pinhole, as with --fov but with its own principal point. For real input.
    #[arg(long, value_name = "FX,FY,CX,CY", conflicts_with_all = ["fov", "calibration", "synthetic"])]
    pub camera: Option<String>,
    /// A camera calibration as OpenCV's FileStorage writes it (YAML or JSON: camera_matrix or K,
    /// optionally the distortion and image_width/image_height), used as --camera is; scaled when
    /// the frames are the calibrated images resized. Distortion is not applied (said when given).
    #[arg(long, value_name = "FILE", conflicts_with_all = ["fov", "synthetic"])]
    pub calibration: Option<PathBuf>,
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
    /// A scene cut is a frame whose gray-level histogram changed by more than this (L1 distance
    /// of the levels' shares: 0 the same, 2 none in common) since the frame before. The cut's
    /// first frame goes to the detector, and the tracks it does not find again (at their place,
    /// at about their size) end there: a track does not carry over to another shot's background.
    /// `off`: cuts are not looked for.
    #[arg(long, default_value_t = SceneCutArg(Some(face_tracker::scene_cut::DEFAULT_SCENE_CUT)), value_parser = scene_cut, value_name = "CHANGE|off")]
    pub scene_cut: SceneCutArg,
    /// Who each track is: `on`, a face found again after its track ended (it left, turned
    /// away, was covered, or a scene cut came) takes its earlier identity when its first
    /// template fits the new face well enough (states.csv's `identity`); `off`, every track is
    /// an identity of its own (its number).
    #[arg(long, value_enum, default_value_t = IdentitiesArg::On)]
    pub identities: IdentitiesArg,
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
    #[command(flatten)]
    pub smoothing: crate::smoothing::SmoothArgs,
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
    /// With --backend all-gpus or auto: how many GPUs to use (default: as many as a frame's work
    /// pays for, said when the run starts; docs/BENCHMARKS.md, "Several GPUs").
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..=1024))]
    pub gpus: Option<u32>,
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
    /// A face narrower than this many pixels (its template's rectangle, about four fifths of
    /// the detector's box) has its landmarks fitted and its template taken in its region
    /// enlarged 2-4 times, so that a small face gets a template at a larger face's pixel scale
    /// (docs/ACCURACY.md, "Small faces"). 0: every face at its own size.
    #[arg(long, default_value_t = FaceTrackerConfig::default().extraction.enlarge_below.unwrap_or(0.0), value_parser = enlarge_below)]
    pub enlarge_below: f32,
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
    /// `openface`: also write openface.csv, the columns of OpenFace 2.0's FeatureExtraction
    /// (frame, face_id, timestamp, confidence, success, pose_Tx … pose_Rz, x_0 … x_67, y_0 …
    /// y_67) in OpenFace's units and sign conventions, so that scripts written for OpenFace read
    /// it unchanged (docs/OUTPUT.md). Needs the landmark model, as --landmarks-out does.
    #[arg(long, value_enum, default_value_t = FormatArg::Streampf)]
    pub format: FormatArg,
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

/// `--face-depth`: a finite scale within the face model's range, checked here so that a bad
/// value is refused before anything runs.
pub(super) fn face_depth(text: &str) -> Result<f32, String> {
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
pub(super) fn eye_outline_growth(text: &str) -> Result<f32, String> {
    let value: f32 = text.parse().map_err(|e| format!("{e}"))?;
    if value == 0.0 || (value.is_finite() && value >= 1.0) {
        Ok(value)
    } else {
        Err(format!(
            "{value}: give 0 (take the eyes) or a factor of at least 1"
        ))
    }
}

/// `--enlarge-below`: a finite width in pixels, 0 or more (0: no face is enlarged).
pub(super) fn enlarge_below(text: &str) -> Result<f32, String> {
    let value: f32 = text.parse().map_err(|e| format!("{e}"))?;
    if value.is_finite() && value >= 0.0 {
        Ok(value)
    } else {
        Err(format!(
            "{value}: give a width in pixels, 0 or more (0: off)"
        ))
    }
}
