//! `streampf body`: the stereo articulated body tracker.
//!
//! - `body synth --out DIR`: renders a synthetic sequence with ground truth;
//! - `body track DIR` or `body track --synthetic`: tracks a sequence, writes per-frame joint
//!   angles (`poses.csv`) and joint positions (`joints.csv`), and, when the ground truth is known,
//!   the per-frame mean joint position error (`errors.csv`) and its mean.
//!
//! The files: `args.rs` (the command line), `synth.rs`, `inputs.rs` (the sequence, its first pose
//! and the engines), `session/` (the run pipeline; `session/frames.rs`, the frame loop;
//! `session/run.rs`, a frame's tracking and writing),
//! `record.rs` (poses, joints and errors, a frame at a time) and `overlay.rs`.

mod args;
mod inputs;
mod overlay;
mod record;
mod session;
mod synth;

use args::{SynthArgs, TrackArgs};
use session::track;
use synth::synth;

use clap::Subcommand;

#[derive(Debug, Subcommand)]
pub enum BodyCommand {
    /// Render a synthetic sequence (frames, camera, skeleton, ground truth) into a directory.
    Synth(SynthArgs),
    /// Track a body through a directory of frames, or through a generated sequence.
    Track(Box<TrackArgs>),
}

pub fn run(command: &BodyCommand) -> anyhow::Result<()> {
    match command {
        BodyCommand::Synth(args) => synth(args),
        BodyCommand::Track(args) => track(args),
    }
}

/// The most frames a body run keeps in flight on its GPU (`BodyTracker::submit_prepared`).
const MAX_BODY_FRAMES_IN_FLIGHT: usize = 2;

const POSES_FILE: &str = "poses.csv";
const JOINTS_FILE: &str = "joints.csv";
const ERRORS_FILE: &str = "errors.csv";
