//! What `face track` reads before it tracks: the video, webcam or frames, the faces' rectangles,
//! the ground truth, the detector and its cascade, the personalising model and the GPUs.

use super::args::{DetectorArg, TrackArgs};
use super::{RECTS_FILE, TRUTH_FILE, model};
use crate::face_io::Source;
use anyhow::{Context, bail};
use body_tracker::sequence::read_numeric_csv;
use face_tracker::FaceBackend;
use face_tracker::detect::{Cascade, DEFAULT_CASCADE, DetectorPlacement, FaceDetector, GpuCascade};
use face_tracker::extraction::FaceRect;
use face_tracker::landmarks::{DEFAULT_PREDICTOR, ShapePredictor};
use face_tracker::personal::Personaliser;
use face_tracker::projection::DIMS;
use face_tracker::synth::{FaceSynthConfig, FaceVideoRenderer, face_state, initial_rect};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Parses `x,y,width,height`.
pub(super) fn parse_rect(text: &str, origin: &str) -> anyhow::Result<FaceRect> {
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
pub(super) fn read_rects(path: &Path) -> anyhow::Result<Vec<FaceRect>> {
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
pub(super) fn read_truth(
    path: &Path,
    frames: usize,
    faces: usize,
) -> anyhow::Result<Vec<Vec<[f32; DIMS]>>> {
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

/// The backend `--backend` asks for ([`crate::gpu::open`]).
pub(super) fn open_backend(
    args: &TrackArgs,
    pays_for: impl Fn(usize) -> usize,
) -> anyhow::Result<FaceBackend> {
    let (backend, gpus) = (args.backend, args.gpus);
    let mut contexts = crate::gpu::open(backend, args.allow_software, gpus, args.quiet, &pays_for)?;
    Ok(match contexts.len() {
        0 => FaceBackend::Cpu,
        1 => FaceBackend::Gpu(Box::new(contexts.remove(0))),
        _ => FaceBackend::Gpus(contexts),
    })
}

/// The landmark fit for personalised face models: --landmarks, else libdlib-data's model when it
/// is installed (a note when it is not), none for --generic-model and --synthetic.
pub(super) fn load_personaliser(args: &TrackArgs) -> anyhow::Result<Option<Arc<Personaliser>>> {
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
pub(super) fn open_detector(
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

pub(super) fn load_cascade(path: &Path) -> anyhow::Result<Cascade> {
    if !path.exists() && path == Path::new(DEFAULT_CASCADE) {
        bail!(
            "the face detector's cascade {DEFAULT_CASCADE} is missing: install Debian's opencv-data (apt-get install opencv-data), give --cascade PATH to an OpenCV Haar cascade XML, or start from rectangles with --face x,y,width,height"
        );
    }
    Ok(Cascade::load(path)?)
}

#[cfg(feature = "webcam")]
pub(super) fn webcam_source(device: &Path, size: &str) -> anyhow::Result<Source> {
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
pub(super) fn webcam_source(_device: &Path, _size: &str) -> anyhow::Result<Source> {
    bail!(
        "this streampf was built without webcam support: build it with `cargo build --release -p streampf --features webcam`"
    )
}

/// Face `k`'s true state at `frame`, NaN while it is out of the picture (no error is measured
/// against it, and it is no true face to score a tracker on).
fn visible_state(config: &FaceSynthConfig, k: usize, frame: usize) -> [f32; DIMS] {
    match config.visible(k, frame) {
        true => face_state(config, k, frame),
        false => [f32::NAN; DIMS],
    }
}

/// Frames, the starting rectangles (faces.csv or none) and the ground truth when known.
pub(super) type Input = (Source, Vec<FaceRect>, Option<Vec<Vec<[f32; DIMS]>>>);

pub(super) fn open_input(args: &TrackArgs) -> anyhow::Result<Input> {
    if args.synthetic {
        let config = args.video.config()?;
        // A scenario's faces come and go: the detector finds them.
        let rects = match args.video.scenario {
            Some(_) => Vec::new(),
            None => (0..config.faces)
                .map(|k| initial_rect(&config, k))
                .collect(),
        };
        let truth: Vec<Vec<[f32; DIMS]>> = (0..config.frames)
            .map(|f| {
                (0..config.faces)
                    .map(|k| visible_state(&config, k, f))
                    .collect()
            })
            .collect();
        // A scenario's tracks are numbered as the detector finds them: track k is not face k,
        // so no track is measured against a face (the run's identity scores match them).
        let truth = args.video.scenario.is_none().then_some(truth);
        let source = Source::Synthetic {
            renderer: Box::new(FaceVideoRenderer::new(&config, &model()?)?),
            next: 0,
        };
        return Ok((source, rects, truth));
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
