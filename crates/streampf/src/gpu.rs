//! Opening the GPU for the trackers' `--backend` options.

use anyhow::Context;
use pf_gpu::{ContextOptions, GpuContext, GpuError};

fn options(allow_software: bool) -> ContextOptions {
    ContextOptions {
        allow_software,
        ..ContextOptions::default()
    }
}

/// The library's error in the command line's words: a software adapter is taken with
/// `--allow-software`.
fn in_cli_words(err: GpuError) -> anyhow::Error {
    match err {
        GpuError::OnlySoftwareAdapters { names } => anyhow::anyhow!(
            "only software adapters were found ({names}): they are far too slow to track with; \
             add --allow-software to use one anyway"
        ),
        other => other.into(),
    }
}

/// `--backend gpu`: the GPU, or an error that says how to find one.
pub fn required(allow_software: bool) -> anyhow::Result<GpuContext> {
    GpuContext::new(&options(allow_software))
        .map_err(in_cli_words)
        .context("opening the GPU (see `streampf devices`)")
}

/// `--backend all-gpus`: every adapter.
pub fn all(allow_software: bool) -> anyhow::Result<Vec<GpuContext>> {
    GpuContext::all(&options(allow_software))
        .map_err(in_cli_words)
        .context("opening the GPUs (see `streampf devices`)")
}

/// `--backend auto`: the GPU when there is one, else `None` (the CPU), said unless `quiet`.
pub fn preferred(allow_software: bool, quiet: bool) -> Option<GpuContext> {
    match GpuContext::new(&options(allow_software)) {
        Ok(ctx) => Some(ctx),
        // One short line: it is said on every run of a machine without a GPU.
        Err(GpuError::OnlySoftwareAdapters { .. }) => {
            if !quiet {
                errln!(
                    "no hardware GPU; tracking on the CPU (--backend gpu --allow-software uses a software one)"
                );
            }
            None
        }
        Err(_) => {
            if !quiet {
                errln!("no usable GPU; tracking on the CPU (`streampf devices` says why)");
            }
            None
        }
    }
}

/// The GPU's own seconds for a step (0 on the CPU).
pub(crate) fn gpu_seconds(time: Option<pf_gpu::GpuTime>) -> f64 {
    time.map_or(0.0, |t| t.duration().as_secs_f64())
}
