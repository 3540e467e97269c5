//! `face track --synthetic --scenario`: the run scored as the MOT benchmarks score trackers
//! (`face_tracker::mot`: IDF1, identity switches, MOTA), against the scenario's true faces. The
//! true faces of each frame are also written to `mot_truth.csv` (frame, identity, centre, the
//! radius a track must lie within), so that another scorer (py-motmetrics, in the Python
//! suite) can score `states.csv` the same way.

use face_tracker::mot::{MotFrame, MotScores, TrackedFace, TrueFace, score};
use face_tracker::projection::{SCALE, TX, TY};
use face_tracker::synth::{FaceSynthConfig, face_state};
use face_tracker::{FaceEstimate, TrackStatus};
use std::path::Path;

use crate::run_output::{CsvStream, ResumePoint};

/// The file of true faces in --out.
pub(super) const MOT_TRUTH_FILE: &str = "mot_truth.csv";

/// The frames scored so far.
pub(super) struct MotLog {
    config: FaceSynthConfig,
    frames: Vec<MotFrame>,
    truth_file: CsvStream,
}

impl MotLog {
    /// For a run of the synthetic `config`, writing `mot_truth.csv` in `out`.
    pub(super) fn create(
        out: &Path,
        config: FaceSynthConfig,
        resume: Option<&ResumePoint>,
    ) -> anyhow::Result<Self> {
        let (path, header) = (out.join(MOT_TRUTH_FILE), "frame,identity,x,y,radius");
        let truth_file = match resume {
            Some(point) => CsvStream::resume(&path, header, point)?,
            None => CsvStream::create(&path, header)?,
        };
        Ok(Self {
            config,
            frames: Vec::new(),
            truth_file,
        })
    }

    /// A frame's true faces (those in the picture, each matched by a track within its
    /// half-width) and its tracking rows.
    pub(super) fn add(&mut self, frame: usize, estimates: &[FaceEstimate]) -> anyhow::Result<()> {
        let truth: Vec<TrueFace> = (0..self.config.faces)
            .filter(|&k| self.config.visible(k, frame))
            .map(|k| {
                let s = face_state(&self.config, k, frame);
                TrueFace {
                    identity: k as u64,
                    centre: [s[TX], s[TY]],
                    radius: self.config.half_width * s[SCALE],
                }
            })
            .collect();
        for t in &truth {
            let [x, y] = t.centre;
            (self.truth_file).row(&format!("{frame},{},{x},{y},{}", t.identity, t.radius))?;
        }
        self.truth_file.end_frame()?;
        let tracks = estimates
            .iter()
            .filter(|e| e.status == TrackStatus::Tracking)
            .map(|e| TrackedFace {
                // Scored by the person each track is: a face found again after its track
                // ended keeps its identity (the track's number without identities).
                track: e.identity as u64,
                centre: [e.state[TX], e.state[TY]],
            })
            .collect();
        self.frames.push(MotFrame { truth, tracks });
        Ok(())
    }

    /// The scores of the frames so far.
    pub(super) fn scores(&self) -> MotScores {
        score(&self.frames)
    }

    /// Prints the scores.
    pub(super) fn summary(&self) {
        let s = self.scores();
        outln!(
            "identities: IDF1 {:.6} (IDP {:.6}, IDR {:.6}), {} identity switches, MOTA {:.6} over {} true face-frames ({} matched, {} missed, {} false positives)",
            s.idf1,
            s.idp,
            s.idr,
            s.id_switches,
            s.mota,
            s.ground_truth,
            s.matches,
            s.misses,
            s.false_positives
        );
    }
}
