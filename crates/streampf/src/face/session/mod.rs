//! `face track`: the run pipeline. It opens the input and the output directory (locked, resumed
//! or cleared), builds the tracker, reads frames ahead, steps them (two in flight where the GPU
//! allows: `in_flight.rs`), writes every frame's rows as it goes and the summary at the end; an
//! interrupt, a bad frame or a device fault keeps every row already written.

use super::args::{FormatArg, TrackArgs};
use super::extras::{colour_frames, record_face_frame, save_particles};
use super::inputs::{Input, open_input, parse_rect};
use super::openface_csv::OPENFACE_FILE;
use super::record::TrackRecord;
use super::runner::{Runner, announce, build_runner};
use super::scoring::{MOT_TRUTH_FILE, MotLog};
use super::{ERRORS_FILE, LANDMARKS_FILE, STATES_FILE};
use crate::annotated::Annotated;
use crate::face_io::{FrameRead, ReadAhead, Source};
use crate::face_overlay::FaceOverlay;
use crate::recording::Recording;
use crate::run_output::{self, Interrupted, OutputLock, ResumePoint, SkipLog, clear_old_results};
use crate::smoothing::SMOOTHED_FILE;
use anyhow::{Context, bail};
use face_tracker::extraction::FaceRect;
use face_tracker::projection::DIMS;
use face_tracker::{FaceEstimate, GrayImage, TrackStatus};
use std::time::Instant;

mod in_flight;
mod smoothed;
use in_flight::InFlight;
use smoothed::FaceSmoothing;

/// The files a run writes in --out, cleared when it starts over.
const RESULT_FILES: [&str; 6] = [
    STATES_FILE,
    ERRORS_FILE,
    LANDMARKS_FILE,
    SMOOTHED_FILE,
    OPENFACE_FILE,
    MOT_TRUTH_FILE,
];

/// The run's scoring against a synthetic scenario's true faces (`--synthetic --scenario`).
fn scoring(args: &TrackArgs, resume: Option<&ResumePoint>) -> anyhow::Result<Option<MotLog>> {
    if !(args.synthetic && args.video.scenario.is_some()) {
        return Ok(None);
    }
    Ok(Some(MotLog::create(
        &args.out,
        args.video.config()?,
        resume,
    )?))
}

pub(super) fn track(args: &TrackArgs) -> anyhow::Result<()> {
    let (mut source, rects, truth) = checked_input(args)?;
    let recording = args
        .rerun
        .as_deref()
        .map(|path| Recording::create(path, "streampf face track"))
        .transpose()?;
    // Held to the end of the run: nothing below touches --out before it is ours.
    let _lock = OutputLock::acquire(&args.out)?;
    let resume = resume_point(args)?;
    let detect = rects.is_empty() || args.detect;
    // Errors against the ground truth need track k to be face k: tracks from rectangles only.
    let truth = truth.filter(|_| !detect);
    let (first, mut runner, backend_name) = start_tracks(args, &mut source, &rects, detect)?;
    let size = (first.width, first.height);
    if resume.is_none() {
        clear_old_results(&args.out, &RESULT_FILES)?;
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
    let lens = runner.tracker().lens();
    let smoothing =
        FaceSmoothing::for_run(&args.out, &args.smoothing, &mut runner, truth.is_some())?;
    let mut run = FaceRun {
        args,
        record: TrackRecord::create(
            &args.out,
            (truth.is_some(), args.landmarks_out),
            (args.format == FormatArg::Openface).then_some((&lens, size)),
            resume.as_ref(),
            source.fps(),
        )?,
        resume_from: resume.as_ref().map_or(0, |p| p.frame),
        smoothing,
        truth,
        overlay,
        recording,
        last_estimates: Vec::new(),
        scoring: scoring(args, resume.as_ref())?,
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

/// The input, its faces' rectangles (`--face` before the input's own) and its ground truth,
/// with every check that needs no output directory done first.
/// What the detecting tracker says at the end of a run: the scene cuts it saw, and whether the
/// detector's GPU failed.
fn detector_summary(auto: &face_tracker::AutoTracker) {
    if let (cuts @ [_, ..], ended) = auto.scene_cuts() {
        let frames: Vec<String> = cuts.iter().map(usize::to_string).collect();
        outln!(
            "scene cuts at frames {}: {ended} tracks ended there (the detector did not find their faces again)",
            frames.join(", ")
        );
    }
    if let Some(why) = auto.detector_fallback() {
        errln!("warning: the detector's GPU failed ({why}); it ran on the CPU from then on");
    }
}

fn checked_input(args: &TrackArgs) -> anyhow::Result<Input> {
    args.smoothing.check()?;
    let (source, mut rects, truth) = open_input(args)?;
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
    if let Some(max) = args.max_faces
        && rects.len() > max as usize
    {
        bail!(
            "{} face rectangles were given but --max-faces is {max}: give fewer rectangles or a larger --max-faces",
            rects.len()
        );
    }
    Ok((source, rects, truth))
}

/// With `--resume`, where the run continues (checked against `--max-frames`).
fn resume_point(args: &TrackArgs) -> anyhow::Result<Option<ResumePoint>> {
    if !args.resume {
        return Ok(None);
    }
    let states = args.out.join(STATES_FILE);
    let point = ResumePoint::of(&states, &TrackRecord::states_header())?;
    point.check_limit(args.max_frames, &states)?;
    Ok(Some(point))
}

/// Reads frame 0, builds the tracker and starts a track on each given rectangle; the frame,
/// the tracker and the name of what it runs on.
fn start_tracks(
    args: &TrackArgs,
    source: &mut Source,
    rects: &[FaceRect],
    detect: bool,
) -> anyhow::Result<(GrayImage, Runner, String)> {
    let first = source
        .next_frame()
        .context("frame 0 (the first frame must be readable: it starts the tracks)")?
        .context("the input has no frames")?;
    let size = (first.width, first.height);
    let (mut runner, backend_name) = build_runner(args, size, rects, detect)?;
    for (i, r) in rects.iter().enumerate() {
        runner
            .add_face(&first, r)
            .with_context(|| format!("face {i}"))?;
    }
    Ok((first, runner, backend_name))
}

/// Why the frame loop ended.
pub(super) enum LoopEnd {
    /// The source ran out, or --max-frames was reached.
    Done,
    Interrupted,
    /// A frame could not be tracked or written (or, with --strict, read).
    Failed(anyhow::Error),
}

/// A face run in progress: what it writes as it goes, and what it has seen.
pub(super) struct FaceRun<'a> {
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
    /// `--smooth` / `--smooth-lag`: smoothed.csv (rewritten whole by a resumed run, which tracks
    /// every frame again).
    smoothing: Option<FaceSmoothing>,
    /// `--synthetic --scenario`: the run scored against the scenario's true faces.
    scoring: Option<MotLog>,
    /// Frames finished and written (tracked or skipped).
    frames: usize,
}

impl FaceRun<'_> {
    /// Tracks frame after frame, writing each as it is finished, until the source ends, the
    /// limit, an interrupt or a failure.
    pub(super) fn track_frames(
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
    pub(super) fn written(&mut self, bar: &indicatif::ProgressBar) {
        self.frames += 1;
        bar.inc(1);
    }

    pub(super) fn track_one(
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
    pub(super) fn write_frame(
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
        if let Some(scoring) = self.scoring.as_mut() {
            scoring.add(frame, &estimates)?;
        }
        if let Some(smoothing) = self.smoothing.as_mut() {
            (smoothing.add(frame, runner.tracker(), &estimates, self.truth.as_deref()))
                .context("--smooth")?;
        }
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
    pub(super) fn skip_one(&mut self, frame: usize, error: anyhow::Error) -> anyhow::Result<()> {
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
    pub(super) fn finish(
        mut self,
        runner: &Runner,
        source: Option<&Source>,
        elapsed: f64,
        end: LoopEnd,
    ) -> anyhow::Result<()> {
        let closed = self.overlay.take().map_or(Ok(()), FaceOverlay::finish);
        // Flushed whatever ended the run: the recording keeps every frame it had.
        let closed = closed.and(self.recording.take().map_or(Ok(()), Recording::finish));
        // Smoothed whatever ended the run: smoothed.csv gets every frame tracked.
        let truth = self.truth.as_deref();
        let closed = closed.and(match self.smoothing.as_mut() {
            Some(smoothing) => (smoothing.finish(runner.tracker(), truth)).context("--smooth"),
            None => Ok(()),
        });
        let written = matches!(end, LoopEnd::Done);
        self.record.summary(
            self.args,
            runner,
            self.frames,
            elapsed,
            &self.skipped,
            written,
        );
        if let Some(smoothing) = &self.smoothing {
            smoothing.print();
        }
        if let Some(scoring) = &self.scoring {
            scoring.summary();
        }
        if let Runner::Auto(auto) = runner {
            detector_summary(auto);
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
