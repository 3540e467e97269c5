//! Opening the GPU for the trackers' `--backend` options.

use anyhow::Context;
use pf_gpu::{ContextOptions, GpuContext};

fn options(allow_software: bool) -> ContextOptions {
    ContextOptions {
        allow_software,
        ..ContextOptions::default()
    }
}

/// `--backend gpu`: the GPU, or an error that says how to find one.
pub fn required(allow_software: bool) -> anyhow::Result<GpuContext> {
    GpuContext::new(&options(allow_software)).context("opening the GPU (see `streampf devices`)")
}

/// `--backend all-gpus`: every adapter.
pub fn all(allow_software: bool) -> anyhow::Result<Vec<GpuContext>> {
    GpuContext::all(&options(allow_software)).context("opening the GPUs (see `streampf devices`)")
}

/// `--backend auto`: the GPU when there is one, else `None` (the CPU), said unless `quiet`.
pub fn preferred(allow_software: bool, quiet: bool) -> Option<GpuContext> {
    match GpuContext::new(&options(allow_software)) {
        Ok(ctx) => Some(ctx),
        Err(err) => {
            if !quiet {
                eprintln!("no hardware GPU ({err}); tracking on the CPU");
            }
            None
        }
    }
}
