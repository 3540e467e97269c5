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
//!
//! The files: `args.rs` (the command line), `synth.rs`, `inputs.rs` (what a run reads),
//! `runner.rs` (the tracker it steps), `session/` (the run pipeline: frames in, rows out,
//! interrupts, `--resume`; `session/in_flight.rs`, two frames in flight) and `record.rs` (the
//! files it writes and the summary) with `extras.rs` (the rerun frame, the overlay's colours,
//! the particles).

mod args;
pub(crate) use args::SceneCutArg;
mod extras;
mod inputs;
mod openface_csv;
mod record;
mod runner;
mod scoring;
mod session;
mod synth;

use args::{SynthArgs, TrackArgs};
use clap::Subcommand;
use face_tracker::model::FaceModel;
use session::track;
use synth::synth;

#[derive(Debug, Subcommand)]
pub enum FaceCommand {
    /// Render a synthetic video (PNG frames, face rectangles, ground truth) into a directory.
    Synth(SynthArgs),
    /// Track faces through a directory of frames, or through a generated video.
    Track(Box<TrackArgs>),
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

/// The generic head: the synthetic video's heads.
fn model() -> anyhow::Result<FaceModel> {
    Ok(FaceModel::generic(face_tracker::model::BUILT_IN_GRID)?)
}
