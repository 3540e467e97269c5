//! docs/EXTENDING.md's Rust (and the README's), compiled and run: every `rust` block must appear, line
//! for line (indentation aside), in code that is built and run by the tests — this file, the
//! range-only example it runs (`examples/range_only.rs`) or the engine seam's toy model
//! (`tests/engine_seam.rs`). A block edited in the page but not in the code, or code changed
//! under a block, fails `every_rust_block_of_the_page_is_compiled_code`.
//!
//! The functions below hold the page's fragments in their context: eight range-only targets of
//! 1 000 particles, one frame, on the GPU (lavapipe in CI) and the CPU. Their bound is only that
//! each runs and gives finite estimates; the example's tracking error is `tests/model_plugin.rs`'.

mod common;

#[path = "../examples/range_only.rs"]
mod range_only;

use std::path::Path;

use pf_core::batch::{BatchConfig, BatchFilter, BatchShape, gaussian_clouds};
use pf_core::resample::{ResamplerKind, Systematic};
use pf_gpu::engine::Filter;
use pf_gpu::model::{CheckInputs, ModelFilter, Plugin, check_against_cpu};
use pf_gpu::{GpuContext, GpuResampler};
use range_only::{CONSTANTS, Constants, MODEL, RangeOnly, Ranges};

type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

/// The page's context: a configuration, initial clouds and one frame's observations.
fn context() -> Result<(BatchConfig, Vec<f32>, Vec<Ranges>, Constants)> {
    let config = BatchConfig::new(BatchShape::new(8, 1000, 4)?, 3, vec![0.0; 4]);
    let means: Vec<f32> = (0..8)
        .flat_map(|t| [6.0 + t as f32, 8.0, 1.0, 0.0])
        .collect();
    let initial = gaussian_clouds(&config.shape, 4, &means, &[1.0, 1.0, 0.5, 0.5]);
    let observations = vec![
        Ranges {
            r: [10.0, 14.0, 12.0]
        };
        8
    ];
    Ok((config, initial, observations, CONSTANTS))
}

fn finite(estimates: &[f32]) -> bool {
    !estimates.is_empty() && estimates.iter().all(|x| x.is_finite())
}

/// "The GPU side": a WGSL model's filter, one frame.
fn gpu_side(ctx: &GpuContext) -> Result<Vec<f32>> {
    let (config, initial, observations, constants) = context()?;
    let systematic = GpuResampler::Systematic;
    let mut filter = ModelFilter::new(ctx, &config, systematic, &initial, MODEL, &constants)?;
    let report = filter.step(&observations)?; // one Observation per target
    Ok(report.estimates)
}

/// "The CPU twin": the same frame through `BatchFilter::step_model`.
fn cpu_twin() -> Result<Vec<f32>> {
    let (config, initial, observations, constants) = context()?;
    let mut cpu = BatchFilter::new(&config, Systematic, initial)?;
    let report = cpu.step_model(&RangeOnly, &observations, &constants)?;
    Ok(report.estimates)
}

/// "Both sides as one model": the plug-in on a GPU, then on the CPU engine.
fn plugin_on_either_engine(ctx: &GpuContext) -> Result<[Vec<f32>; 2]> {
    let (config, initial, observations, _) = context()?;
    let systematic = GpuResampler::Systematic;
    let model = Plugin::gpu(ctx, MODEL, &config.shape, RangeOnly, CONSTANTS)?;
    let mut filter = Filter::on_gpu(ctx.clone(), &config, systematic, &initial, model)?;
    let on_gpu = filter.step(&observations)?.estimates;
    let model = Plugin::cpu(RangeOnly, CONSTANTS);
    let mut filter = Filter::on_cpu(&config, ResamplerKind::Systematic, initial, model)?;
    let on_cpu = filter.step(&observations)?.estimates;
    Ok([on_gpu, on_cpu])
}

/// "Checking one against the other".
fn check(ctx: &GpuContext) -> Result<()> {
    let (config, states, observed, _) = context()?;
    let shape = config.shape;
    let check = check_against_cpu(
        ctx,
        MODEL,
        &RangeOnly,
        &CheckInputs {
            shape,
            states: &states,
            observations: &observed,
            constants: &CONSTANTS,
            angular: &[false; 4],
            seed: 5,
        },
    )?;
    assert!(check.passed(), "{check}"); // lists the first values that disagree
    Ok(())
}

#[test]
fn the_pages_fragments_run() {
    assert!(finite(&cpu_twin().unwrap()));
    let Some(ctx) = common::gpu_context("docs/EXTENDING.md's fragments") else {
        return;
    };
    assert!(finite(&gpu_side(&ctx).unwrap()));
    let [on_gpu, on_cpu] = plugin_on_either_engine(&ctx).unwrap();
    assert!(finite(&on_gpu) && finite(&on_cpu));
    check(&ctx).unwrap();
}

/// A block's lines without indentation, blank lines left out.
fn normalised(text: &str) -> Vec<String> {
    (text.lines())
        .map(|l| l.trim().to_string())
        .filter(|l| !l.is_empty())
        .collect()
}

fn rust_blocks(page: &str) -> Vec<(usize, String)> {
    let (mut blocks, mut current, mut start) = (Vec::new(), None::<String>, 0);
    for (n, line) in page.lines().enumerate() {
        match (&mut current, line.trim()) {
            (None, "```rust") => (current, start) = (Some(String::new()), n + 1),
            (Some(_), "```") => blocks.push((start, current.take().unwrap_or_default())),
            (Some(block), _) => {
                block.push_str(line);
                block.push('\n');
            }
            (None, _) => {}
        }
    }
    blocks
}

fn contains_run(haystack: &[String], needle: &[String]) -> bool {
    !needle.is_empty() && haystack.windows(needle.len()).any(|w| w == needle)
}

#[test]
fn every_rust_block_of_the_page_is_compiled_code() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let read = |path: &str| std::fs::read_to_string(root.join(path)).expect(path);
    let sources: Vec<Vec<String>> = [
        "tests/extending_doc.rs",
        "examples/range_only.rs",
        "tests/engine_seam.rs",
    ]
    .iter()
    .map(|path| normalised(&read(path)))
    .collect();
    let blocks = rust_blocks(&read("docs/EXTENDING.md"));
    assert!(
        blocks.len() >= 6,
        "docs/EXTENDING.md has {} rust blocks",
        blocks.len()
    );
    for (line, block) in blocks {
        let lines = normalised(&block);
        assert!(
            sources.iter().any(|source| contains_run(source, &lines)),
            "docs/EXTENDING.md:{line}: this block is not in the compiled code (tests/extending_doc.rs, \
             examples/range_only.rs, tests/engine_seam.rs):\n{block}"
        );
    }
    // The matcher itself: a changed line is not found.
    let source = normalised("fn a() {\n    let x = 1;\n    let y = 2;\n}\n");
    assert!(contains_run(&source, &normalised("let x = 1;\nlet y = 2;")));
    assert!(!contains_run(
        &source,
        &normalised("let x = 1;\nlet y = 3;")
    ));
}
