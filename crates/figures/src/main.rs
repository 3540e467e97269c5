//! `reproduce-figures`: the binary behind `cargo xtask reproduce-figures`.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use streampf_figures::{FIGURES_DIR, Options, experiments::EXPERIMENTS, run};

/// Regenerates the papers' figures: CSV, SVG and PNG per figure and one markdown report.
#[derive(Parser, Debug)]
#[command(name = "reproduce-figures", after_help = figure_list())]
struct Args {
    /// Small sizes for CI and laptops: minutes on 2 cores with any adapter (or none with
    /// --no-gpu); every plot and table is stamped "quick mode".
    #[arg(long)]
    quick: bool,
    /// Output directory: the report (REPRODUCTION.md) and figures/ with each figure's files.
    #[arg(long, default_value = "target/figures")]
    out: PathBuf,
    /// Run only these figures (repeat the option or separate with commas).
    #[arg(long, value_delimiter = ',', num_args = 1..)]
    only: Vec<String>,
    /// Let the full run use a software adapter (Mesa's lavapipe) when there is no hardware GPU.
    #[arg(long)]
    allow_software: bool,
    /// Quick mode without any GPU: the CPU series only.
    #[arg(long)]
    no_gpu: bool,
}

fn figure_list() -> String {
    let mut s = String::from("Figures:\n");
    for e in &EXPERIMENTS {
        s.push_str(&format!("  {:<14} {}\n", e.name, e.about));
    }
    s
}

fn main() -> ExitCode {
    let args = Args::parse();
    let options = Options {
        quick: args.quick,
        out: args.out,
        only: args.only,
        allow_software: args.allow_software,
        no_gpu: args.no_gpu,
    };
    match run(&options) {
        Ok(outcome) => {
            println!(
                "wrote {} figure{} to {} and the report {}",
                outcome.figures.len(),
                if outcome.figures.len() == 1 { "" } else { "s" },
                options.out.join(FIGURES_DIR).display(),
                outcome.report.display()
            );
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("reproduce-figures: {e:#}");
            ExitCode::FAILURE
        }
    }
}
