//! A thousand independent targets in one batch: each a point wandering in 2-D, seen with noise.
//! The likelihood is six lines of WGSL; the engine's Gaussian random walk is the dynamics. One
//! GPU submission per frame steps all 1000 × 256 particles; the CPU twin steps the same batch.
//! `cargo run --release --example many_targets -- --allow-software`

use bytemuck::{Pod, Zeroable};
use pf_core::batch::{BatchConfig, BatchFilter, BatchShape, gaussian_clouds};
use pf_core::plugin::CpuModel;
use pf_core::resample::Systematic;
use pf_gpu::model::{ModelFilter, ModelSource};
use pf_gpu::{GpuContext, GpuResampler};

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

/// Tracks `targets` random walkers for `frames` frames; the mean position error over the last
/// half, on the GPU (when `ctx` is given) and on the CPU, and the raw observations' error.
pub fn run(
    ctx: Option<&GpuContext>,
    targets: usize,
    frames: usize,
) -> anyhow::Result<(Option<f32>, f32, f32)> {
    let shape = BatchShape::new(targets, 256, 2)?;
    let config = BatchConfig {
        shape,
        seed: 1,
        sigma: vec![STEP; 2],
        bounds: None,
        angular: vec![false; 2],
        ess_threshold: f64::INFINITY,
        best: 0,
    };
    let mut rng = pf_core::RandomStreams::new(2).stream(0, pf_core::Stage::Model(0));
    let mut truth: Vec<[f32; 2]> = (0..targets).map(|t| [t as f32, -(t as f32)]).collect();
    let start = gaussian_clouds(&shape, 3, truth.as_flattened(), &[1.0, 1.0]);
    let constants = Constants {
        inv_sigma: 1.0 / NOISE,
    };
    let gpu_filter = |ctx| {
        ModelFilter::new(
            ctx,
            &config,
            GpuResampler::Systematic,
            &start,
            MODEL,
            &constants,
        )
    };
    let mut gpu = ctx.map(gpu_filter).transpose()?;
    let mut cpu = BatchFilter::new(&config, Systematic, start.clone())?;
    let (mut gpu_error, mut cpu_error, mut raw_error) = (0.0, 0.0, 0.0);
    let weight = 1.0 / (targets * (frames - frames / 2)) as f32;
    for frame in 0..frames {
        for p in &mut truth {
            p[0] += STEP * rng.gaussian_f32();
            p[1] += STEP * rng.gaussian_f32();
        }
        let seen: Vec<Position> = (truth.iter())
            .map(|p| Position {
                x: p[0] + NOISE * rng.gaussian_f32(),
                y: p[1] + NOISE * rng.gaussian_f32(),
            })
            .collect();
        let w = if frame >= frames / 2 { weight } else { 0.0 };
        let error = |e: &[f32]| -> f32 {
            truth
                .iter()
                .enumerate()
                .map(|(t, p)| (e[2 * t] - p[0]).hypot(e[2 * t + 1] - p[1]))
                .sum::<f32>()
                * w
        };
        if let (Some(filter), Some(ctx)) = (gpu.as_mut(), ctx) {
            gpu_error += error(&filter.step(ctx, &seen)?.estimates);
        }
        cpu_error += error(&cpu.step_model(&NoisyPosition, &seen, &constants)?.estimates);
        raw_error += error(&seen.iter().flat_map(|p| [p.x, p.y]).collect::<Vec<_>>());
    }
    Ok((gpu.map(|_| gpu_error), cpu_error, raw_error))
}

#[allow(dead_code)]
fn main() -> anyhow::Result<()> {
    let allow_software = std::env::args().any(|a| a == "--allow-software");
    let options = pf_gpu::ContextOptions {
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
    Ok(())
}
