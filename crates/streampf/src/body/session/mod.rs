//! `body track`: the run pipeline. It opens the sequence and the output directory (locked,
//! resumed or cleared), builds the tracker, prepares frames on a reader thread, steps them (two in
//! flight on one GPU) and writes every frame's rows as it goes (`run.rs`); an interrupt, a bad
//! frame or a device fault keeps every row already written.

use super::args::TrackArgs;
use super::inputs::{Source, open_backend, open_sequence, pose_from_points};
use crate::annotated::Annotated;
use crate::recording::Recording;
use crate::run_output::{self, Interrupted, OutputLock, ResumePoint, clear_old_results};
use crate::smoothing::SMOOTHED_FILE;
use anyhow::{Context, bail};
use body_tracker::likelihood::CoarseLayers;
use body_tracker::sequence::read_pose_csv;
use body_tracker::tracker::islands;
use body_tracker::{BodyTracker, Skeleton, TrackerConfig};
use nalgebra::Vector3;
use std::collections::VecDeque;
use std::time::Instant;

use super::overlay::{BodyOverlay, overlay_camera};
use super::record::BodyFiles;
use super::{ERRORS_FILE, JOINTS_FILE, POSES_FILE};

mod frames;
mod run;
mod smoothed;
use frames::FrameLoop;
use run::BodyRun;
use smoothed::BodySmoothing;

pub(super) fn track(args: &TrackArgs) -> anyhow::Result<()> {
    args.smoothing.check()?;
    check_overlay_path(args)?;
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
    let start = start_pose(args, &skeleton, truth.as_deref(), &first_points)?;
    let config = tracker_config(args)?;
    let backend = open_backend(args, |available| {
        islands::gpus_for_load(&skeleton, &config, first_points.len(), available)
    })?;
    let backend_name = backend.describe();
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
    let resume = resume_point(args, &skeleton)?;
    let mut files = BodyFiles::create(&args.out, &skeleton, truth.is_some(), resume.as_ref())?;
    let mut overlay = args
        .overlay
        .as_deref()
        .map(|path| BodyOverlay::create(path, overlay_camera(&source)?))
        .transpose()?;
    let bar = crate::console::progress_bar(frames, args.quiet);
    let smoothing =
        BodySmoothing::for_run(&args.out, &args.smoothing, &mut tracker, truth.is_some())?;
    let mut run = BodyRun::new(&args.out, smoothing)?;
    let started = Instant::now();
    // Two frames in flight on one GPU (the GPU steps frame t + 1 while frame t is read back and
    // written) where nothing reads the particles between frames; the same results.
    let streaming = tracker.gpu_context().is_some()
        && args.save_particles.is_none()
        && recording.is_none()
        && run.smoothing.is_none();
    run.frames_in_flight = streaming;
    let end = FrameLoop {
        args,
        skeleton: &skeleton,
        tracker: &mut tracker,
        run: &mut run,
        files: &mut files,
        overlay: overlay.as_mut(),
        recording: recording.as_ref(),
        truth: truth.as_deref(),
        resume_from: resume.map_or(0, |p| p.frame),
        synthetic: matches!(source, Source::Synthetic(_)),
        streaming,
        in_flight: VecDeque::new(),
    }
    .run(&source, frames, first_points, &bar);
    bar.finish_and_clear();
    finish_run(
        args,
        &mut run,
        (&tracker, truth.as_deref()),
        (overlay, recording),
        started,
        end,
    )
}

/// An overlay must be a path it can write and not the input; a video overlay cannot be resumed.
fn check_overlay_path(args: &TrackArgs) -> anyhow::Result<()> {
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
    Ok(())
}

/// Where the filter starts: `--init-pose`, else the ground truth's first pose, else a pose
/// fitted to the first frame's points.
fn start_pose(
    args: &TrackArgs,
    skeleton: &Skeleton,
    truth: Option<&[Vec<f32>]>,
    first_points: &[Vector3<f32>],
) -> anyhow::Result<Vec<f32>> {
    Ok(match (&args.init_pose, truth) {
        (Some(path), _) => read_pose_csv(path, skeleton.dofs())?
            .into_iter()
            .next()
            .with_context(|| format!("{} has no pose row", path.display()))?,
        (None, Some(truth)) => truth[0].clone(),
        (None, None) => pose_from_points(skeleton, first_points)?,
    })
}

/// The tracker's settings from the command line.
fn tracker_config(args: &TrackArgs) -> anyhow::Result<TrackerConfig> {
    let defaults = TrackerConfig::default();
    Ok(TrackerConfig {
        particles: args.particles as usize,
        max_points: args.max_points as usize,
        tau: args.tau,
        seed: args.seed,
        annealing: args.filter.apply(&defaults.annealing)?,
        motion: args.filter.motion(defaults.motion)?,
        partitioned: args.partitioned,
        coarse: (args.coarse_layers > 0).then_some(CoarseLayers {
            points: args.coarse_points as usize,
            layers: args.coarse_layers as usize,
        }),
        ..defaults
    })
}

/// With `--resume`, where the run continues (checked against `--max-frames`); without it, the
/// old results are cleared.
fn resume_point(args: &TrackArgs, skeleton: &Skeleton) -> anyhow::Result<Option<ResumePoint>> {
    let poses = args.out.join(POSES_FILE);
    if !args.resume {
        clear_old_results(
            &args.out,
            &[POSES_FILE, JOINTS_FILE, ERRORS_FILE, SMOOTHED_FILE],
        )?;
        return Ok(None);
    }
    let point = ResumePoint::of(&poses, &BodyFiles::poses_header(skeleton))?;
    point.check_limit(args.max_frames.map(u64::from), &poses)?;
    if !args.quiet {
        outln!(
            "resuming at frame {}: the frames before it are tracked again and checked against {}",
            point.frame,
            poses.display()
        );
    }
    Ok(Some(point))
}

/// Closes the overlay and the recording whatever ended the run (so that their frames are kept),
/// prints the summary and turns how the loop ended into the run's result.
fn finish_run(
    args: &TrackArgs,
    run: &mut BodyRun,
    (tracker, truth): (&BodyTracker, Option<&[Vec<f32>]>),
    (overlay, recording): (Option<BodyOverlay>, Option<Recording>),
    started: Instant,
    mut end: LoopEnd,
) -> anyhow::Result<()> {
    let closed = overlay.map_or(Ok(()), |overlay| overlay.out.finish());
    let closed = closed.and(recording.map_or(Ok(()), Recording::finish));
    // Smoothed whatever ended the run: smoothed.csv gets every frame tracked.
    let closed = closed.and(match run.smoothing.as_mut() {
        Some(smoothing) => smoothing.finish(tracker, truth).context("--smooth"),
        None => Ok(()),
    });
    if let (Err(e), LoopEnd::Done | LoopEnd::Interrupted) = (closed, &end) {
        end = LoopEnd::Failed(e.context("finishing --overlay, --rerun or --smooth"));
    }
    run.summary(
        args,
        started.elapsed().as_secs_f64(),
        matches!(end, LoopEnd::Done),
    );
    if let Some(smoothing) = &run.smoothing {
        smoothing.print();
    }
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

/// Why the frame loop ended.
pub(super) enum LoopEnd {
    Done,
    Interrupted,
    Failed(anyhow::Error),
}
