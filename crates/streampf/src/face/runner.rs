//! Building the tracker a run steps (`Runner`: faces from given rectangles, or found by the
//! detector), from the command line's settings, and announcing what it runs on.

use super::DEFAULT_MAX_FACES;
use super::args::{FormatArg, TrackArgs, focal_length};
use super::inputs::{load_cascade, load_personaliser, open_backend, open_detector};
use anyhow::{Context, bail};
use face_tracker::camera::{Calibration, Intrinsics};
use face_tracker::detect::DetectConfig;
use face_tracker::extraction::{ExtractionConfig, FaceRect};
use face_tracker::model::{BuiltInModel, FaceModel};
use face_tracker::personal::Personaliser;
use face_tracker::{
    AutoConfig, AutoTracker, FaceBackend, FaceEstimate, FaceTracker, FaceTrackerConfig, GrayImage,
};
use std::sync::Arc;

/// The detecting tracker's settings from the command line.
fn auto_config(args: &TrackArgs, tracker: FaceTrackerConfig, rects: usize) -> AutoConfig {
    AutoConfig {
        detect_every: args.detect_every as usize,
        detect: DetectConfig {
            min_size: args.min_face,
            ..DetectConfig::default()
        },
        max_faces: (args.max_faces.unwrap_or(DEFAULT_MAX_FACES) as usize).max(rects),
        // A file waits for each detection at its fixed delay (runs repeat); a camera never
        // waits for it.
        detection_delay: args
            .webcam
            .is_none()
            .then_some(args.detection_delay as usize),
        scene_cut: args.scene_cut.0,
        identities: (args.identities == super::args::IdentitiesArg::On)
            .then(face_tracker::identity::IdentityConfig::default),
        tracker,
        ..AutoConfig::default()
    }
}

/// A frame's estimates and the detections that started or restarted tracks before it.
pub(super) type StepOutcome = (Vec<FaceEstimate>, Vec<(usize, FaceRect, bool)>);

/// How tracks start: from rectangles given at the first frame, or from the detector thread.
pub(super) enum Runner {
    Fixed(Box<FaceTracker>),
    Auto(Box<AutoTracker>),
}

impl Runner {
    /// The frame's estimates, and the tracks a detection started (`false`) or restarted
    /// (`true`) before it, with the detection's rectangle.
    pub(super) fn step(&mut self, frame: &GrayImage) -> anyhow::Result<StepOutcome> {
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

    pub(super) fn tracker(&self) -> &FaceTracker {
        match self {
            Runner::Fixed(tracker) => tracker,
            Runner::Auto(auto) => auto.tracker(),
        }
    }

    /// Keeps the filter's lineage (smoothing with a lag traces it).
    pub(super) fn keep_lineage(&mut self) -> anyhow::Result<()> {
        match self {
            Runner::Fixed(tracker) => tracker.keep_lineage()?,
            Runner::Auto(auto) => auto.keep_lineage()?,
        }
        Ok(())
    }

    /// Keeps a lag window on the tracker's GPUs (`FaceTracker::keep_lag_window`).
    pub(super) fn keep_lag_window(
        &mut self,
        lag: usize,
        compare_filtered: bool,
    ) -> anyhow::Result<()> {
        match self {
            Runner::Fixed(tracker) => tracker.keep_lag_window(lag, compare_filtered)?,
            Runner::Auto(auto) => auto.keep_lag_window(lag, compare_filtered)?,
        }
        Ok(())
    }

    pub(super) fn set_personaliser(&mut self, personaliser: Option<Arc<Personaliser>>) {
        match self {
            Runner::Fixed(tracker) => tracker.set_personaliser(personaliser),
            Runner::Auto(auto) => auto.set_personaliser(personaliser),
        }
    }

    pub(super) fn add_face(&mut self, frame: &GrayImage, rect: &FaceRect) -> anyhow::Result<usize> {
        Ok(match self {
            Runner::Fixed(tracker) => tracker.add_face(frame, rect)?,
            Runner::Auto(auto) => auto.add_face(frame, rect)?,
        })
    }
}

/// The tracker for `args` on the backend it asks for: the automatic tracker with the detector
/// when `detect`, else a tracker with room for the given rectangles; and the backend's name.
pub(super) fn build_runner(
    args: &TrackArgs,
    size: (u32, u32),
    rects: &[FaceRect],
    detect: bool,
) -> anyhow::Result<(Runner, String)> {
    let face_model = face_model(args)?;
    let config = tracker_config(args, size)?;
    let cascade = if detect {
        Some(load_cascade(&args.cascade)?)
    } else {
        None
    };
    // The slots a run can fill: the rectangles, or the detector's most faces.
    let capacity = match detect {
        true => (args.max_faces.unwrap_or(DEFAULT_MAX_FACES) as usize).max(rects.len()),
        false => rects.len(),
    };
    let backend = open_backend(args, |available| {
        face_tracker::tracker::shards::gpus_for_load(capacity, &config, available)
    })?;
    let backend_name = backend_description(&backend);
    let personaliser = load_personaliser(args)?;
    let wants_landmarks = match args.format {
        FormatArg::Openface => Some("--format openface"),
        FormatArg::Streampf => args.landmarks_out.then_some("--landmarks-out"),
    };
    if let (Some(option), None) = (wants_landmarks, &personaliser) {
        bail!(
            "{option} needs dlib's 68-landmark model: give --landmarks FILE, or install \
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
            let auto = auto_config(args, config, rects.len());
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

/// The face model a run tracks with: the user's maps, else the photographed head for real input
/// (auto) or when asked for, the generic head for the synthetic video (whose heads are the
/// generic model) or when asked for.
fn face_model(args: &TrackArgs) -> anyhow::Result<FaceModel> {
    let built_in = BuiltInModel::from(args.face_model);
    let photographed = args.heightmap.is_none() && built_in.is_photographed(args.synthetic);
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
    Ok(match (&args.heightmap, &args.normalmap) {
        (Some(h), Some(n)) => FaceModel::load(h, n, args.height_scale)?,
        _ => built_in.build(args.synthetic, args.face_depth)?,
    })
}

/// The camera `--camera` or `--calibration` gives for frames of `size` pixels, said unless quiet
/// (with a note when the calibration has distortion, which the tracker does not apply).
fn camera(args: &TrackArgs, size: (u32, u32)) -> anyhow::Result<Option<Intrinsics>> {
    let camera = match (&args.camera, &args.calibration) {
        (Some(text), _) => Intrinsics::parse(text).context("--camera")?,
        (None, Some(path)) => {
            let calibration = Calibration::load(path).context("--calibration")?;
            if calibration.distorts() && !args.quiet {
                errln!(
                    "note: {} has lens distortion {:?}; the tracker models a pinhole without it                      (undistort the video for the calibration's full accuracy)",
                    path.display(),
                    calibration.distortion
                );
            }
            let intrinsics = calibration.intrinsics;
            match calibration.image_size {
                Some(calibrated) => intrinsics
                    .for_frames(calibrated, size)
                    .with_context(|| format!("--calibration {}", path.display()))?,
                None => intrinsics,
            }
        }
        (None, None) => return Ok(None),
    };
    if !args.quiet {
        errln!(
            "camera: fx {:.1}, fy {:.1}, principal point ({:.1}, {:.1}): a {:.1}° horizontal field of view",
            camera.fx,
            camera.fy,
            camera.cx,
            camera.cy,
            camera.horizontal_fov(size.0)
        );
    }
    Ok(Some(camera))
}

/// The tracker's settings from the command line (frames of `size` pixels).
fn tracker_config(args: &TrackArgs, size: (u32, u32)) -> anyhow::Result<FaceTrackerConfig> {
    let config = settings_of(args, size)?;
    Ok(match camera(args, size)? {
        Some(camera) => config.with_camera(&camera),
        None => config,
    })
}

/// The tracker's settings from the command line but the camera's.
fn settings_of(args: &TrackArgs, size: (u32, u32)) -> anyhow::Result<FaceTrackerConfig> {
    let defaults = FaceTrackerConfig::default();
    Ok(FaceTrackerConfig {
        particles: args.particles as usize,
        best: (args.particles as usize / 10).max(1),
        seed: args.seed,
        failure_error: args.failure_error,
        failure_frames: args.failure_frames as usize,
        annealing: args.filter.apply(&defaults.annealing)?,
        motion: args.filter.motion(defaults.motion)?,
        extraction: ExtractionConfig {
            eye_outline_growth: (args.eye_outline_growth > 0.0).then_some(args.eye_outline_growth),
            enlarge_below: (args.enlarge_below > 0.0).then_some(args.enlarge_below),
            ..defaults.extraction
        },
        focal_length: (args.video.fov)
            .map(|fov| focal_length(fov, size.0))
            .transpose()?,
        ..defaults
    })
}

/// What a run's tracker steps on, in words.
fn backend_description(backend: &FaceBackend) -> String {
    match backend {
        FaceBackend::Cpu => format!("CPU ({} threads)", rayon::current_num_threads()),
        FaceBackend::Gpu(ctx) => format!("GPU: {}", ctx.adapter().name),
        FaceBackend::Gpus(contexts) => format!(
            "{} GPUs, a share of the faces on each: {}",
            contexts.len(),
            (contexts.iter().map(|c| c.adapter().name.clone()))
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

/// The line that says what is about to be tracked.
pub(super) fn announce(
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
