//! A thousand independent targets in one batch: each a point wandering in 2-D, seen with noise.
//! The likelihood is six lines of WGSL; the engine's Gaussian random walk is the dynamics. One
//! GPU submission per frame steps all 1000 × 256 particles; the CPU twin steps the same batch.
//! `run_on_all_gpus` gives the same model what the engine gives any model: annealing layers,
//! two frames in flight and the targets split over every GPU.
//! `cargo run --release --example many_targets -- --allow-software`

use bytemuck::{Pod, Zeroable};
use std::collections::VecDeque;

use pf_core::anneal::Annealing;
use pf_core::batch::{BatchConfig, BatchFilter, BatchShape, gaussian_clouds};
use pf_core::{plugin::CpuModel, resample::Systematic};
use pf_gpu::model::{ModelFilter, ModelSource, ShardedModelFilter};
use pf_gpu::{ContextOptions, GpuContext, GpuResampler};

pub const MODEL: ModelSource = ModelSource {
    name: "noisy 2-D position",
    wgsl: "
struct Observation { x: f32, y: f32 }
struct Constants { inv_sigma: f32 }
fn log_likelihood(s: State, z: Observation, c: Constants) -> f32 {
    let e = vec2(s[0] - z.x, s[1] - z.y) * c.inv_sigma;
    return -0.5 * dot(e, e);
}",
};

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct Position {
    pub x: f32,
    pub y: f32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub struct Constants {
    pub inv_sigma: f32,
}

pub struct NoisyPosition;

impl CpuModel<Position, Constants> for NoisyPosition {
    fn log_likelihood(&self, s: &[f32], z: &Position, c: &Constants) -> f32 {
        let (ex, ey) = ((s[0] - z.x) * c.inv_sigma, (s[1] - z.y) * c.inv_sigma);
        -0.5 * (ex * ex + ey * ey)
    }
}

const NOISE: f32 = 0.5;
const STEP: f32 = 0.3;

/// The mean distance of the estimates `[t·2 + d]` from the true positions.
fn position_error(truth: &[[f32; 2]], estimates: &[f32]) -> f32 {
    let e = |t: usize, p: &[f32; 2]| (estimates[2 * t] - p[0]).hypot(estimates[2 * t + 1] - p[1]);
    truth.iter().enumerate().map(|(t, p)| e(t, p)).sum::<f32>() / truth.len() as f32
}

/// One frame of the walkers: each takes a Gaussian step, then is seen with noise.
fn walk_and_observe(truth: &mut [[f32; 2]], rng: &mut pf_core::RandomStream) -> Vec<Position> {
    for p in truth.iter_mut() {
        p.iter_mut().for_each(|x| *x += STEP * rng.gaussian_f32());
    }
    (truth.iter())
        .map(|p| Position {
            x: p[0] + NOISE * rng.gaussian_f32(),
            y: p[1] + NOISE * rng.gaussian_f32(),
        })
        .collect()
}

/// Tracks `targets` random walkers for `frames` frames; the mean position error over the second
/// half, on the GPU (when `ctx` is given) and on the CPU, and the raw observations' error.
pub fn run(
    ctx: Option<&GpuContext>,
    targets: usize,
    frames: usize,
) -> anyhow::Result<(Option<f32>, f32, f32)> {
    let config = BatchConfig::new(BatchShape::new(targets, 256, 2)?, 1, vec![STEP; 2]);
    let mut rng = pf_core::RandomStreams::new(2).stream(0, pf_core::Stage::Model(0));
    let mut truth: Vec<[f32; 2]> = (0..targets).map(|t| [t as f32, -(t as f32)]).collect();
    let start = gaussian_clouds(&config.shape, 3, truth.as_flattened(), &[1.0, 1.0]);
    let constants = Constants {
        inv_sigma: 1.0 / NOISE,
    };
    let systematic = GpuResampler::Systematic;
    let mut gpu = (ctx
        .map(|ctx| ModelFilter::new(ctx, &config, systematic, &start, MODEL, &constants)))
    .transpose()?;
    let mut cpu = BatchFilter::new(&config, Systematic, start.clone())?;
    let mut errors = [Vec::new(), Vec::new(), Vec::new()]; // GPU, CPU, raw
    for _ in 0..frames {
        let seen = walk_and_observe(&mut truth, &mut rng);
        if let Some(filter) = gpu.as_mut() {
            errors[0].push(position_error(&truth, &filter.step(&seen)?.estimates));
        }
        let on_cpu = cpu.step_model(&NoisyPosition, &seen, &constants)?;
        errors[1].push(position_error(&truth, &on_cpu.estimates));
        errors[2].push(position_error(
            &truth,
            &seen.iter().flat_map(|p| [p.x, p.y]).collect::<Vec<_>>(),
        ));
    }
    let second_half =
        |e: &[f32]| e[frames / 2..].iter().sum::<f32>() / (frames - frames / 2) as f32;
    Ok((
        gpu.map(|_| second_half(&errors[0])),
        second_half(&errors[1]),
        second_half(&errors[2]),
    ))
}

/// The same walkers on every GPU of `contexts` (the targets split between them), with `layers`
/// annealing layers a frame and two frames in flight: frame t + 1 is submitted before frame t
/// is read back. The mean position error over the second half, and the raw observations'.
pub fn run_on_all_gpus(
    contexts: Vec<GpuContext>,
    targets: usize,
    frames: usize,
    layers: usize,
) -> anyhow::Result<(f32, f32)> {
    let mut config = BatchConfig::new(BatchShape::new(targets, 256, 2)?, 1, vec![STEP; 2]);
    config.annealing = Annealing::survival(layers, 0.5, 0.5);
    let mut rng = pf_core::RandomStreams::new(2).stream(0, pf_core::Stage::Model(0));
    let mut truth: Vec<[f32; 2]> = (0..targets).map(|t| [t as f32, -(t as f32)]).collect();
    let start = gaussian_clouds(&config.shape, 3, truth.as_flattened(), &[1.0, 1.0]);
    let constants = Constants {
        inv_sigma: 1.0 / NOISE,
    };
    let systematic = GpuResampler::Systematic;
    let mut filter =
        ShardedModelFilter::new(contexts, &config, systematic, &start, MODEL, &constants)?;
    // Each frame's truth waits beside its submission until the frame is read back.
    let mut in_flight = VecDeque::new();
    let (mut filtered, mut raw) = (Vec::new(), Vec::new());
    // One pass more than there are frames, to read the last one back.
    for frame in 0..=frames {
        if frame < frames {
            let seen = walk_and_observe(&mut truth, &mut rng);
            let flat: Vec<f32> = seen.iter().flat_map(|p| [p.x, p.y]).collect();
            raw.push(position_error(&truth, &flat));
            in_flight.push_back((filter.submit(&seen)?, truth.clone()));
        }
        if in_flight.len() == 2 || (frame == frames && !in_flight.is_empty()) {
            let (pending, seen_truth) = in_flight.pop_front().expect("a frame in flight");
            filtered.push(position_error(
                &seen_truth,
                &filter.finish(pending)?.estimates,
            ));
        }
    }
    let second_half =
        |e: &[f32]| e[frames / 2..].iter().sum::<f32>() / (frames - frames / 2) as f32;
    Ok((second_half(&filtered), second_half(&raw)))
}

#[allow(dead_code)]
fn main() -> anyhow::Result<()> {
    let allow_software = std::env::args().any(|a| a == "--allow-software");
    let options = ContextOptions {
        allow_software,
        ..Default::default()
    };
    let ctx = GpuContext::new(&options)
        .map_err(|e| eprintln!("no GPU ({e}); CPU only"))
        .ok();
    let (gpu, cpu, raw) = run(ctx.as_ref(), 1000, 30)?;
    println!("1000 targets: raw observations {raw:.3}, CPU filter {cpu:.3}");
    if let (Some(g), Some(ctx)) = (gpu, &ctx) {
        println!("GPU ({}): {g:.3} mean position error", ctx.adapter().name);
    }
    let contexts = GpuContext::all(&options).unwrap_or_default();
    if !contexts.is_empty() {
        let count = contexts.len();
        let (filtered, _) = run_on_all_gpus(contexts, 1000, 30, 3)?;
        println!("{count} GPU(s), 3 annealing layers, two frames in flight: {filtered:.3}");
    }
    Ok(())
}
