//! A run's written results: `TrackRecord` (states.csv, errors.csv, landmarks.csv, the summary).

use super::args::TrackArgs;
use super::openface_csv::{OPENFACE_FILE, OpenFaceCsv};
use super::runner::Runner;
use super::{ERRORS_FILE, LANDMARKS_FILE, STATES_FILE};
use crate::run_output::{CsvStream, ResumePoint, SkipLog};
use face_tracker::projection::{
    DIMS, RZ, STATE_NAMES, pitch_yaw_roll_degrees, rotation_quaternion,
};
use face_tracker::tracker::pose_errors;
use face_tracker::{FaceEstimate, TrackStatus};
use std::path::Path;

/// The columns of a states.csv row after `status`: the state, the residual, the spreads, the ESS,
/// the log evidence, the confidence, three angles and a quaternion.
pub(super) const STATE_COLUMNS_AFTER_STATUS: usize = DIMS + 1 + DIMS + 3 + 3 + 4 + 1;

/// What a run has tracked: states.csv and (with ground truth) errors.csv, written as each frame
/// is finished, the error sums and the time spent in the tracker.
pub(super) struct TrackRecord {
    pub(super) states: CsvStream,
    pub(super) errors: Option<CsvStream>,
    pub(super) landmarks: Option<CsvStream>,
    /// openface.csv (`--format openface`).
    pub(super) openface: Option<OpenFaceCsv>,
    pub(super) translation: f64,
    pub(super) rotation: f64,
    pub(super) measured: usize,
    /// Per state dimension, the face-frames whose true value lay within ±2 reported standard
    /// deviations of the estimate (with ground truth).
    pub(super) within_two_sd: [usize; DIMS],
    pub(super) tracks_seen: std::collections::BTreeSet<usize>,
    /// Seconds in the tracker's calls, and the GPU's own seconds for the frames (timestamps):
    /// with frames in flight the GPU works while the host waits for the next frame, so the
    /// tracker's time is the longer of the two.
    pub(super) tracking_time: f64,
    pub(super) gpu_time: f64,
    /// Whether the frames were tracked with two in flight (`face/in_flight.rs`).
    pub(super) frames_in_flight: bool,
    /// Frames per second of the input: a row's timestamp is its frame / this.
    pub(super) fps: f64,
}

impl TrackRecord {
    /// The frame, its timestamp, the track, whether it is tracked, its status, the state, ε (the
    /// residual), then how sure the estimate is (the posterior's spread per dimension, the ESS,
    /// the frame's log evidence, the confidence), the rotation as degrees and as a quaternion,
    /// and the person the track follows (docs/OUTPUT.md).
    pub(super) fn states_header() -> String {
        let spreads: Vec<String> = STATE_NAMES.iter().map(|n| format!("sd_{n}")).collect();
        format!(
            "frame,timestamp,track,success,status,{},residual,{},ess,log_evidence,confidence,pitch_deg,yaw_deg,roll_deg,qw,qx,qy,qz,identity",
            STATE_NAMES.join(","),
            spreads.join(",")
        )
    }

    /// The frame, its timestamp, the track, then x and y of each of the 68 iBUG landmarks.
    pub(super) fn landmarks_header() -> String {
        let columns: Vec<String> = (0..68).map(|k| format!("x{k},y{k}")).collect();
        format!("frame,timestamp,track,{}", columns.join(","))
    }

    /// A frame's landmark rows (landmarks.csv, and openface.csv when written): each tracked
    /// face whose template has landmarks, posed by its estimate.
    pub(super) fn add_landmarks(
        &mut self,
        frame: usize,
        templates: &[(usize, &face_tracker::Template)],
        estimates: &[FaceEstimate],
        lens: &face_tracker::likelihood::Lens,
    ) -> anyhow::Result<()> {
        let seconds = self.seconds(frame);
        if let Some(openface) = self.openface.as_mut() {
            openface.add(frame, seconds, templates, estimates, lens)?;
        }
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
    pub(super) fn timestamp(&self, frame: usize) -> String {
        format!("{:.6}", self.seconds(frame))
    }

    pub(super) fn seconds(&self, frame: usize) -> f64 {
        frame as f64 / self.fps
    }

    /// The columns after the state and ε (see [`TrackRecord::states_header`]).
    pub(super) fn certainty_columns(e: &FaceEstimate) -> String {
        let join = |values: &[f32]| {
            values
                .iter()
                .map(|v| v.to_string())
                .collect::<Vec<_>>()
                .join(",")
        };
        format!(
            "{},{},{},{},{},{},{}",
            join(&e.spread),
            e.ess,
            e.log_evidence,
            e.confidence,
            join(&pitch_yaw_roll_degrees(&e.state)),
            join(&rotation_quaternion(&e.state)),
            e.identity
        )
    }

    /// The files, new or (`resume`) an interrupted run's reopened at its resume point.
    /// `(with_truth, with_landmarks)`: whether errors.csv and landmarks.csv are written;
    /// `openface`: openface.csv's lens and frame size, when it is written.
    pub(super) fn create(
        out: &Path,
        (with_truth, with_landmarks): (bool, bool),
        openface: Option<(&face_tracker::likelihood::Lens, (u32, u32))>,
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
        let openface = openface
            .map(|(lens, size)| {
                // OpenFace counts frames from 1.
                let (path, header) = (out.join(OPENFACE_FILE), OpenFaceCsv::header());
                let file = match resume {
                    Some(point) => CsvStream::resume_numbered_from(&path, &header, point, 1)?,
                    None => CsvStream::create(&path, &header)?,
                };
                anyhow::Ok(OpenFaceCsv::new(file, lens, size))
            })
            .transpose()?;
        Ok(Self {
            states: open(STATES_FILE, &Self::states_header())?,
            errors,
            landmarks,
            openface,
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
    pub(super) fn add(
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

    pub(super) fn add_rows(
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
    pub(super) fn summary(
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
        self.print_errors();
        if !written {
            return;
        }
        self.print_written(args);
    }

    /// The errors against the ground truth and how often it lay within the reported spread.
    fn print_errors(&self) {
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
    }

    /// Which files the run wrote, and where.
    fn print_written(&self, args: &TrackArgs) {
        outln!(
            "wrote states.csv{}{}{} to {}{}",
            if self.errors.is_some() {
                ", errors.csv"
            } else {
                ""
            },
            if self.openface.is_some() {
                ", openface.csv"
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
