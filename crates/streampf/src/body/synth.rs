//! `body synth`: a synthetic sequence written with its camera, skeleton and ground truth.

use super::args::{FormatArg, SynthArgs};
use crate::run_output::{self};
use anyhow::Context;
use body_tracker::sequence::{FrameFormat, write_synthetic};
use clap::ValueEnum;

pub(super) fn synth(args: &SynthArgs) -> anyhow::Result<()> {
    let config = args.sequence.config()?;
    let skeleton = args.sequence.skeleton()?;
    let format = match args.format {
        FormatArg::Ply => FrameFormat::Ply,
        FormatArg::DepthPng => FrameFormat::DepthPng,
    };
    run_output::claim_synthetic_dir(&args.out, args.force)?;
    let bar = crate::console::progress_bar(config.frames, false);
    write_synthetic(&args.out, &skeleton, &config, format, |_| bar.inc(1))
        .with_context(|| format!("writing the sequence to {}", args.out.display()))?;
    bar.finish_and_clear();
    let format_name = args
        .format
        .to_possible_value()
        .map_or_else(String::new, |v| v.get_name().to_string());
    outln!(
        "wrote {} frames ({format_name}, {} capsules, {}) with ground truth to {}",
        config.frames,
        skeleton.capsule_count(),
        config.motion,
        args.out.display()
    );
    Ok(())
}
