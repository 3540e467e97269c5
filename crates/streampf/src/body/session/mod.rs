//! `body track`: the run pipeline. It opens the sequence and the output directory (locked,
//! resumed or cleared), builds the tracker, prepares frames on a reader thread, steps them (two in
//! flight on one GPU) and writes every frame's rows as it goes (`run.rs`); an interrupt, a bad
//! frame or a device fault keeps every row already written.

use super::args::TrackArgs;
use super::inputs::{Source, open_backend, open_sequence, pose_from_points};
use crate::annotated::Annotated;
use crate::recording::Recording;
use crate::run_output::{self, Interrupted, OutputLock, ResumePoint, clear_old_results};
use anyhow::{Context, bail};
use body_tracker::sequence::read_pose_csv;
use body_tracker::{BodyTracker, TrackerConfig};
use nalgebra::Vector3;
use std::collections::VecDeque;
use std::time::Instant;

use super::overlay::{BodyOverlay, overlay_camera};
use super::record::BodyFiles;
use super::{ERRORS_FILE, JOINTS_FILE, MAX_BODY_FRAMES_IN_FLIGHT, POSES_FILE};

mod run;
use run::BodyRun;

pub(super) fn track(args: &TrackArgs) -> anyhow::Result<()> {
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

/// Why the frame loop ended.
pub(super) enum LoopEnd {
    Done,
    Interrupted,
    Failed(anyhow::Error),
}
