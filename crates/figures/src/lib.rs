//! # streampf-figures
//!
//! `cargo xtask reproduce-figures` runs this crate's binary: every experiment behind the two
//! papers' figures (and the accuracy and resampler figures), each written as a CSV with the run's
//! provenance, a plot (SVG and PNG, drawn with plotters) and a section of one markdown report
//! that sets the papers' values beside ours.
//!
//! - [`experiments`]: the experiments, one figure each ([`experiments::EXPERIMENTS`]);
//! - [`timing`]: warm-up, repeats, median and interquartile range;
//! - [`record`]: figures, panels, series and the CSV;
//! - [`plot`]: the plots; [`report`]: the markdown report; [`paper`]: the papers' values;
//! - [`machine`]: the host, adapter, commit and mode stamped on everything.

pub mod experiments;
pub mod machine;
pub mod paper;
pub mod plot;
pub mod record;
pub mod report;
pub mod timing;

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use indicatif::{ProgressBar, ProgressStyle};
use pf_gpu::{ContextOptions, GpuContext};

use experiments::{EXPERIMENTS, Experiment, Run};
use machine::Machine;
use timing::TimingPlan;

/// The report's file name inside the output directory; the figures go to `figures/`.
pub const REPORT: &str = "REPRODUCTION.md";
pub const FIGURES_DIR: &str = "figures";

/// What to run.
#[derive(Debug, Clone)]
pub struct Options {
    pub quick: bool,
    pub out: PathBuf,
    /// Experiment names; empty means all.
    pub only: Vec<String>,
    /// Full mode on a software adapter (slow; the timings say nothing about GPUs).
    pub allow_software: bool,
    /// Run the CPU series only (quick mode on a machine with no adapter at all).
    pub no_gpu: bool,
}

/// What a run wrote.
#[derive(Debug, Clone)]
pub struct Outcome {
    pub report: PathBuf,
    pub figures: Vec<&'static str>,
    pub machine: Machine,
}

/// The experiments `only` names (all when empty), or an error naming the unknown ones and the
/// known ones.
pub fn select(only: &[String]) -> anyhow::Result<Vec<&'static Experiment>> {
    if only.is_empty() {
        return Ok(EXPERIMENTS.iter().collect());
    }
    let unknown: Vec<&str> = only
        .iter()
        .map(String::as_str)
        .filter(|n| !EXPERIMENTS.iter().any(|e| e.name == *n))
        .collect();
    if !unknown.is_empty() {
        bail!(
            "unknown figure name{} {}; the figures are: {}",
            if unknown.len() > 1 { "s" } else { "" },
            unknown.join(", "),
            EXPERIMENTS.map(|e| e.name).join(", ")
        );
    }
    Ok(EXPERIMENTS
        .iter()
        .filter(|e| only.iter().any(|n| n == e.name))
        .collect())
}

/// Creates `out/figures` and proves it writable, before any work.
fn prepare_output(out: &Path) -> anyhow::Result<PathBuf> {
    let figures = out.join(FIGURES_DIR);
    std::fs::create_dir_all(&figures).with_context(|| {
        format!(
            "--out {}: cannot create {}",
            out.display(),
            figures.display()
        )
    })?;
    let probe = figures.join(".write-test");
    std::fs::write(&probe, b"").with_context(|| {
        format!(
            "--out {}: {} is not writable",
            out.display(),
            figures.display()
        )
    })?;
    std::fs::remove_file(&probe).ok();
    Ok(figures)
}

/// The GPU for the run: a hardware adapter; in quick mode (or with `allow_software`) a software
/// one when there is no hardware; none with `no_gpu` (quick mode only).
fn open_gpu(options: &Options) -> anyhow::Result<Option<GpuContext>> {
    if options.no_gpu {
        if !options.quick {
            bail!("--no-gpu is for --quick runs; the full run measures the GPU series");
        }
        return Ok(None);
    }
    if let Ok(ctx) = GpuContext::new(&ContextOptions::default()) {
        return Ok(Some(ctx));
    }
    if !(options.quick || options.allow_software) {
        bail!(
            "the full run needs a hardware GPU and none was found (see `streampf devices`).\n\
             Run it on a machine with one (an NVIDIA, AMD or Intel GPU with a Vulkan driver), or:\n  \
             --quick            small sizes on any adapter, Mesa's lavapipe included (minutes)\n  \
             --allow-software   the full sizes on a software adapter (hours; its GPU timings say nothing about GPUs)"
        );
    }
    let software = ContextOptions {
        allow_software: true,
        poll_timeout: std::time::Duration::from_secs(600),
        ..ContextOptions::default()
    };
    match GpuContext::new(&software) {
        Ok(ctx) => Ok(Some(ctx)),
        // Quick mode runs anywhere: without any adapter it measures the CPU series only, and the
        // stamp on every plot and table says "no GPU".
        Err(e) if options.quick => {
            eprintln!(
                "reproduce-figures: no GPU adapter ({e}); quick mode runs the CPU series only"
            );
            Ok(None)
        }
        Err(e) => Err(e.into()),
    }
}

/// Runs the selected experiments and writes every CSV, SVG, PNG and the report.
pub fn run(options: &Options) -> anyhow::Result<Outcome> {
    let selected = select(&options.only)?;
    let figures_dir = prepare_output(&options.out)?;
    let gpu = open_gpu(options)?;
    let machine = Machine::detect(gpu.as_ref().map(|c| c.adapter().clone()), options.quick);
    eprintln!("reproduce-figures ({} mode)", machine.mode());
    eprintln!("  GPU:  {}", machine.adapter_name());
    eprintln!("  host: {}", machine.host);
    let total: u64 = selected.iter().map(|e| (e.steps)(options.quick)).sum();
    let progress = ProgressBar::new(total);
    progress.set_style(
        ProgressStyle::with_template(
            "{elapsed_precise} [{bar:32}] {pos}/{len} measurements, ETA {eta}  {msg}",
        )
        .map_err(|e| anyhow::anyhow!("{e}"))?
        .progress_chars("=> "),
    );
    let plan = if options.quick {
        TimingPlan::quick()
    } else {
        TimingPlan::full()
    };
    let mut context = Run::new(options.quick, plan, gpu.as_ref(), &progress);
    let mut figures = Vec::new();
    for experiment in &selected {
        let figure = (experiment.run)(&mut context)
            .with_context(|| format!("figure {}", experiment.name))?;
        let stem = figures_dir.join(figure.name);
        record::write_csv(&figure, &machine, &stem.with_extension("csv"))?;
        plot::write_plots(
            &figure,
            &machine,
            &stem.with_extension("svg"),
            &stem.with_extension("png"),
        )?;
        // The report is rewritten after every figure, so an interrupted run keeps what it made.
        figures.push(figure);
        let report_path = options.out.join(REPORT);
        std::fs::write(&report_path, report::write(&figures, &machine))
            .with_context(|| format!("writing {}", report_path.display()))?;
    }
    progress.finish_with_message("done");
    Ok(Outcome {
        report: options.out.join(REPORT),
        figures: figures.iter().map(|f| f.name).collect(),
        machine,
    })
}
