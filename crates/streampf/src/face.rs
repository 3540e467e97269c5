//! `streampf face`: the multi-face tracker.
//!
//! - `face synth --out DIR`: renders a synthetic video (PNG frames, `faces.csv` with each face's
//!   rectangle at frame 0, `ground_truth.csv`);
//! - `face track DIR` or `face track --synthetic`: tracks every face from its rectangle, writes
//!   `states.csv` (frame, face, status, 7 values, ε), optional overlay frames, and, when the
//!   ground truth is known, the translation and rotation errors.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, bail};
use body_tracker::sequence::read_numeric_csv;
use clap::{Args, Subcommand, ValueEnum};
use face_tracker::extraction::FaceRect;
use face_tracker::model::FaceModel;
use face_tracker::projection::{DIMS, Pose, STATE_NAMES};
use face_tracker::synth::{FaceSynthConfig, face_state, initial_rect, render_frame};
use face_tracker::tracker::pose_errors;
use face_tracker::{
    FaceBackend, FaceEstimate, FaceTracker, FaceTrackerConfig, GrayImage, Template, TrackStatus,
};
use nalgebra::Vector3;

#[derive(Debug, Subcommand)]
pub enum FaceCommand {
    /// Render a synthetic video (PNG frames, face rectangles, ground truth) into a directory.
    Synth(SynthArgs),
    /// Track faces through a directory of frames, or through a generated video.
    Track(TrackArgs),
}

#[derive(Debug, Clone, Args)]
pub struct VideoArgs {
    /// Frames to generate.
    #[arg(long, default_value_t = 100, value_parser = clap::value_parser!(u32).range(1..=100_000))]
    pub frames: u32,
    /// Faces in the video (1 to 16; the paper's Fig. 1 has four).
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=16))]
    pub faces: u32,
    #[arg(long, default_value_t = 1024, value_parser = clap::value_parser!(u32).range(64..=8192))]
    pub width: u32,
    #[arg(long, default_value_t = 768, value_parser = clap::value_parser!(u32).range(64..=8192))]
    pub height: u32,
    /// Largest yaw of the heads, in degrees (at most 90).
    #[arg(long, default_value_t = 60.0)]
    pub max_yaw: f32,
    /// Seed of the video's textures.
    #[arg(long, default_value_t = 11)]
    pub video_seed: u64,
}

impl VideoArgs {
    fn config(&self) -> anyhow::Result<FaceSynthConfig> {
        let config = FaceSynthConfig {
            width: self.width,
            height: self.height,
            frames: self.frames as usize,
            faces: self.faces as usize,
            half_width: 60.0 * (self.width as f32 / 1024.0).min(self.height as f32 / 768.0),
            max_yaw: self.max_yaw.to_radians(),
            occlusion: true,
            exit_after: None,
            seed: self.video_seed,
        };
        config.validate()?;
        Ok(config)
    }
}

#[derive(Debug, Clone, Args)]
pub struct SynthArgs {
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub video: VideoArgs,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum BackendArg {
    /// A hardware GPU when there is one, else the CPU.
    Auto,
    Cpu,
    Gpu,
}

#[derive(Debug, Clone, Args)]
pub struct TrackArgs {
    /// A directory of frames (*.png, name order) with faces.csv (x,y,width,height per face at
    /// the first frame) and optionally ground_truth.csv.
    #[arg(required_unless_present = "synthetic", conflicts_with = "synthetic")]
    pub dir: Option<PathBuf>,
    /// Track a synthetic video generated in memory (see the video options).
    #[arg(long)]
    pub synthetic: bool,
    /// A face rectangle at the first frame, `x,y,width,height` (repeat for several faces);
    /// overrides faces.csv.
    #[arg(long = "face", value_name = "X,Y,W,H")]
    pub faces_at: Vec<String>,
    /// Where to write states.csv (and errors.csv with ground truth).
    #[arg(long, default_value = "streampf-face-out")]
    pub out: PathBuf,
    /// Also write every frame with the posed template points and axes drawn, into this directory.
    #[arg(long)]
    pub overlay: Option<PathBuf>,
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
    /// Print only the summary.
    #[arg(long)]
    pub quiet: bool,
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
const TRUTH_FILE: &str = "ground_truth.csv";

fn model() -> anyhow::Result<FaceModel> {
    Ok(FaceModel::generic(129)?)
}

fn write_text(path: &Path, text: &str) -> anyhow::Result<()> {
    std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}

fn synth(args: &SynthArgs) -> anyhow::Result<()> {
    let config = args.video.config()?;
    let model = model()?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let bar = crate::body::progress_bar(config.frames, false);
    let mut truth = String::from("frame,face");
    for n in STATE_NAMES {
        truth.push(',');
        truth.push_str(n);
    }
    truth.push('\n');
    for frame in 0..config.frames {
        render_frame(&config, &model, frame)?
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
    println!(
        "wrote {} frames of {}x{} with {} faces, faces.csv and ground_truth.csv to {}",
        config.frames,
        config.width,
        config.height,
        config.faces,
        args.out.display()
    );
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
    Ok(FaceRect {
        x,
        y,
        width,
        height,
    })
}

fn read_rects(path: &Path) -> anyhow::Result<Vec<FaceRect>> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("reading the face rectangles {}", path.display()))?;
    text.lines()
        .enumerate()
        .skip(1)
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

enum Source {
    Directory(Vec<PathBuf>),
    Synthetic(FaceSynthConfig, FaceModel),
}

impl Source {
    fn frames(&self) -> usize {
        match self {
            Source::Directory(files) => files.len(),
            Source::Synthetic(config, _) => config.frames,
        }
    }

    fn frame(&self, i: usize) -> anyhow::Result<GrayImage> {
        Ok(match self {
            Source::Directory(files) => GrayImage::load(&files[i])?,
            Source::Synthetic(config, model) => render_frame(config, model, i)?,
        })
    }
}

fn open_backend(args: &TrackArgs) -> anyhow::Result<FaceBackend> {
    Ok(match args.backend {
        BackendArg::Cpu => FaceBackend::Cpu,
        BackendArg::Gpu => FaceBackend::Gpu(Box::new(crate::gpu::required(args.allow_software)?)),
        BackendArg::Auto => match crate::gpu::preferred(args.allow_software, args.quiet) {
            Some(ctx) => FaceBackend::Gpu(Box::new(ctx)),
            None => FaceBackend::Cpu,
        },
    })
}

/// Colours of the faces in overlays.
const COLOURS: [[u8; 3]; 4] = [[255, 60, 60], [60, 220, 60], [70, 130, 255], [255, 200, 0]];

fn put(img: &mut image::RgbImage, x: f32, y: f32, colour: [u8; 3]) {
    if x >= 0.0 && y >= 0.0 && (x as u32) < img.width() && (y as u32) < img.height() {
        img.put_pixel(x as u32, y as u32, image::Rgb(colour));
    }
}

fn line(img: &mut image::RgbImage, a: (f32, f32), b: (f32, f32), colour: [u8; 3]) {
    let steps = ((b.0 - a.0).abs().max((b.1 - a.1).abs()).ceil() as usize).max(1);
    for i in 0..=steps {
        let t = i as f32 / steps as f32;
        put(img, a.0 + (b.0 - a.0) * t, a.1 + (b.1 - a.1) * t, colour);
    }
}

/// The frame with each tracked face's visible template points and its axes drawn.
fn overlay(
    frame: &GrayImage,
    templates: &[Template],
    estimates: &[FaceEstimate],
) -> image::RgbImage {
    let mut img = image::RgbImage::from_fn(frame.width, frame.height, |x, y| {
        let v = frame.at(x, y).round().clamp(0.0, 255.0) as u8;
        image::Rgb([v, v, v])
    });
    for (k, (template, e)) in templates.iter().zip(estimates).enumerate() {
        if e.status != TrackStatus::Tracking {
            continue;
        }
        let colour = COLOURS[k % COLOURS.len()];
        let pose = Pose::new(&e.state);
        for q in &template.points {
            if pose.faces_camera(&Vector3::from(q.normal)) {
                let p = pose.project(&Vector3::from(q.position));
                for (dx, dy) in [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0)] {
                    put(&mut img, p.x + dx, p.y + dy, colour);
                }
            }
        }
        let origin = pose.project(&Vector3::zeros());
        for (axis, c) in [
            (Vector3::x(), [255, 0, 0]),
            (Vector3::y(), [0, 255, 0]),
            (Vector3::z(), [0, 0, 255]),
        ] {
            let end = pose.project(&(axis * 50.0));
            line(&mut img, (origin.x, origin.y), (end.x, end.y), c);
        }
    }
    img
}

fn track(args: &TrackArgs) -> anyhow::Result<()> {
    let (source, mut rects, truth) = if args.synthetic {
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
        (Source::Synthetic(config, model()?), rects, Some(truth))
    } else {
        let dir = args.dir.as_deref().unwrap_or(Path::new("."));
        let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
            .with_context(|| format!("reading {}", dir.display()))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")))
            .collect();
        files.sort();
        if files.is_empty() {
            bail!("{}: no *.png frames", dir.display());
        }
        let rects = if dir.join(RECTS_FILE).exists() {
            read_rects(&dir.join(RECTS_FILE))?
        } else {
            Vec::new()
        };
        let truth = if dir.join(TRUTH_FILE).exists() {
            Some(read_truth(
                &dir.join(TRUTH_FILE),
                files.len(),
                rects.len().max(args.faces_at.len()),
            )?)
        } else {
            None
        };
        (Source::Directory(files), rects, truth)
    };
    if !args.faces_at.is_empty() {
        rects = args
            .faces_at
            .iter()
            .map(|r| parse_rect(r, "--face"))
            .collect::<anyhow::Result<_>>()?;
    }
    if rects.is_empty() {
        bail!("no face rectangles: give --face x,y,width,height or a faces.csv beside the frames");
    }
    let frames = source.frames();
    let first = source.frame(0).context("frame 0")?;
    let backend = open_backend(args)?;
    let backend_name = match &backend {
        FaceBackend::Cpu => format!("CPU ({} threads)", rayon::current_num_threads()),
        FaceBackend::Gpu(ctx) => format!("GPU: {}", ctx.adapter().name),
    };
    let config = FaceTrackerConfig {
        particles: args.particles as usize,
        best: (args.particles as usize / 10).max(1),
        seed: args.seed,
        ..FaceTrackerConfig::default()
    };
    let face_model = match (&args.heightmap, &args.normalmap) {
        (Some(h), Some(n)) => FaceModel::load(h, n, args.height_scale)?,
        _ => model()?,
    };
    let mut tracker = FaceTracker::new(&first, &rects, &face_model, config, backend)?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    if let Some(dir) = &args.overlay {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    if !args.quiet {
        println!(
            "tracking {} faces through {frames} frames of {}x{}, {} particles each, on {backend_name}",
            rects.len(),
            first.width,
            first.height,
            args.particles
        );
    }
    let bar = crate::body::progress_bar(frames, args.quiet);
    let mut states = String::from("frame,face,status");
    for n in STATE_NAMES {
        states.push(',');
        states.push_str(n);
    }
    states.push_str(",error\n");
    let mut errors = String::from("frame,face,translation_px,rotation_deg\n");
    let (mut translation, mut rotation, mut measured) = (0.0f64, 0.0f64, 0usize);
    let mut tracking_time = 0.0f64;
    let started = Instant::now();
    for frame in 0..frames {
        let image = if frame == 0 {
            first.clone()
        } else {
            source
                .frame(frame)
                .with_context(|| format!("frame {frame}"))?
        };
        let step_started = Instant::now();
        let estimates = tracker
            .step(&image)
            .with_context(|| format!("frame {frame}"))?;
        tracking_time += step_started.elapsed().as_secs_f64();
        for (k, e) in estimates.iter().enumerate() {
            let status = match e.status {
                TrackStatus::Tracking => "tracking".to_string(),
                TrackStatus::Lost { frame } => format!("lost@{frame}"),
            };
            states.push_str(&format!("{frame},{k},{status}"));
            for v in e.state {
                states.push_str(&format!(",{v}"));
            }
            states.push_str(&format!(",{}\n", e.error));
            let known = truth
                .as_ref()
                .and_then(|t| t.get(frame))
                .and_then(|f| f.get(k));
            if let (Some(t), TrackStatus::Tracking) = (known, e.status)
                && t.iter().all(|v| v.is_finite())
            {
                let (te, re) = pose_errors(&e.state, t);
                errors.push_str(&format!("{frame},{k},{te},{re}\n"));
                translation += f64::from(te);
                rotation += f64::from(re);
                measured += 1;
            }
        }
        if let Some(dir) = &args.overlay {
            let path = dir.join(format!("overlay_{frame:05}.png"));
            overlay(&image, tracker.templates(), &estimates)
                .save(&path)
                .with_context(|| format!("writing {}", path.display()))?;
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    write_text(&args.out.join("states.csv"), &states)?;
    println!(
        "tracked {} faces through {frames} frames in {:.2} s: {:.1} frames/s in the tracker",
        rects.len(),
        started.elapsed().as_secs_f64(),
        frames as f64 / tracking_time.max(1e-9)
    );
    if measured > 0 {
        write_text(&args.out.join("errors.csv"), &errors)?;
        println!(
            "mean translation error: {:.2} px, mean rotation error: {:.2} deg ({measured} face-frames)",
            translation / measured as f64,
            rotation / measured as f64
        );
    }
    println!(
        "wrote states.csv{} to {}",
        if measured > 0 { ", errors.csv" } else { "" },
        args.out.display()
    );
    Ok(())
}
