//! Opening the GPU for the trackers' `--backend` options.

use anyhow::Context;
use pf_gpu::{ContextOptions, GpuContext, GpuError};

/// The options for opening the GPU; says so when every kernel is to keep wgpu's runtime checks
/// (`STREAMPF_CHECK_KERNELS=1`, for a kernel suspected of reading past an array).
fn options(allow_software: bool) -> ContextOptions {
    let options = ContextOptions {
        allow_software,
        ..ContextOptions::default()
    };
    if options.check_every_kernel {
        errln!(
            "note: every GPU kernel keeps wgpu's index and loop checks ({}=1)",
            pf_gpu::CHECK_KERNELS_VAR
        );
    }
    options
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

/// `--backend` of `face track` and `body track`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum BackendArg {
    /// The GPUs when there are (as many as the work pays for), else the CPU.
    Auto,
    Cpu,
    /// The whole step on one GPU.
    Gpu,
    /// Several GPUs, as many as a frame's work pays for, each the whole step for its share (a
    /// share of the faces, or an island of the body's samples).
    AllGpus,
}

/// The GPUs `backend` runs on (none: the CPU): several only as many as `pays_for` (of their
/// count) says a frame's work pays for, or `gpus` (`--gpus N`, with `all-gpus` or `auto` only).
pub fn open(
    backend: BackendArg,
    allow_software: bool,
    gpus: Option<u32>,
    quiet: bool,
    pays_for: &dyn Fn(usize) -> usize,
) -> anyhow::Result<Vec<GpuContext>> {
    if gpus.is_some() && matches!(backend, BackendArg::Cpu | BackendArg::Gpu) {
        anyhow::bail!(
            "--gpus chooses how many GPUs --backend all-gpus or auto uses; --backend cpu and gpu use none or one"
        );
    }
    Ok(match backend {
        BackendArg::Cpu => Vec::new(),
        BackendArg::Gpu => vec![required(allow_software)?],
        BackendArg::AllGpus => by_load(all(allow_software)?, gpus, pays_for, quiet)?,
        BackendArg::Auto => match several_preferred(gpus, pays_for, quiet)? {
            Some(contexts) => contexts,
            None => preferred(allow_software, quiet).into_iter().collect(),
        },
    })
}

/// The GPUs a run of several uses: `forced` (`--gpus N`) when given, else as many as `pays_for`
/// says of those there are (it gets their count); the choice is said unless `quiet`.
fn by_load(
    mut contexts: Vec<GpuContext>,
    forced: Option<u32>,
    pays_for: &dyn Fn(usize) -> usize,
    quiet: bool,
) -> anyhow::Result<Vec<GpuContext>> {
    let available = contexts.len();
    let used = match forced {
        Some(n) if n == 0 || n as usize > available => anyhow::bail!(
            "--gpus {n}: this machine has {available} usable GPU(s) (see `streampf devices`)"
        ),
        Some(n) => n as usize,
        None => pays_for(available).clamp(1, available.max(1)),
    };
    if !quiet && available > 1 {
        let why = match forced {
            Some(_) => "as --gpus asks",
            None => "as many as a frame's work pays for; --gpus N chooses",
        };
        errln!("using {used} of {available} GPUs ({why})");
    }
    contexts.truncate(used);
    Ok(contexts)
}

/// `--backend auto` on a machine of several hardware GPUs whose frame's work pays for more than
/// one (`pays_for` of their count), or `--gpus N` given: those GPUs. `None` otherwise: then
/// [`preferred`] picks one or the CPU.
fn several_preferred(
    forced: Option<u32>,
    pays_for: &dyn Fn(usize) -> usize,
    quiet: bool,
) -> anyhow::Result<Option<Vec<GpuContext>>> {
    let hardware = pf_gpu::list_adapters()
        .map(|adapters| adapters.iter().filter(|a| !a.is_software()).count())
        .unwrap_or(0);
    let wanted = forced.map_or_else(|| pays_for(hardware), |n| n as usize);
    if hardware < 2 || wanted < 2 {
        if forced.is_some_and(|n| n as usize > hardware.max(1)) {
            anyhow::bail!(
                "--gpus {}: this machine has {hardware} hardware GPU(s) (see `streampf devices`)",
                forced.unwrap_or(0)
            );
        }
        return Ok(None);
    }
    by_load(all(false)?, forced, pays_for, quiet).map(Some)
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
