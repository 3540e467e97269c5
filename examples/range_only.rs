//! Range-only 2-D tracking: targets heard by three beacons that measure only their distance,
//! tracked with a constant-velocity model written in WGSL (`MODEL`: the whole GPU side) and its
//! CPU twin (`RangeOnly`), paired as one `Plugin` and run by the same `Filter` type on a GPU and
//! on the CPU, side by side on the same random numbers.
//! `cargo run --release --example range_only [-- --allow-software]` (Mesa's lavapipe, no GPU).

use bytemuck::{Pod, Zeroable};
use pf_core::batch::{BatchConfig, BatchShape, gaussian_clouds};
use pf_core::{plugin::CpuModel, resample::ResamplerKind};
use pf_gpu::engine::Filter;
use pf_gpu::model::{ModelSource, Plugin};
use pf_gpu::{ContextOptions, GpuContext, GpuResampler};

// The user's GPU model: the 17 lines of WGSL below and the two bytemuck types it reads.
pub const MODEL: ModelSource = ModelSource {
    name: "range-only constant velocity",
    wgsl: "
struct Observation { r: array<f32, 3> }
struct Constants { beacons: array<f32, 6>, dt: f32, accel: f32, range_sigma: f32 }
fn log_likelihood(x: State, z: Observation, c: Constants) -> f32 {
    var b = c.beacons;
    var r = z.r;
    var sum = 0.0;
    for (var k = 0u; k < 3u; k++) {
        let e = (length(vec2(x[0] - b[2u * k], x[1] - b[2u * k + 1u])) - r[k]) / c.range_sigma;
        sum += e * e;
    }
    return -0.5 * sum;
}
fn propagate(x: State, n: State, c: Constants) -> State {
    let vx = x[2] + c.accel * c.dt * n[2];
    let vy = x[3] + c.accel * c.dt * n[3];
    return State(x[0] + vx * c.dt, x[1] + vy * c.dt, vx, vy);
}",
};
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct Ranges {
    pub r: [f32; 3],
}
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
pub struct Constants {
    pub beacons: [f32; 6],
    pub dt: f32,
    pub accel: f32,
    pub range_sigma: f32,
}

/// The CPU twin of `MODEL`.
pub struct RangeOnly;
impl CpuModel<Ranges, Constants> for RangeOnly {
    const PROPAGATES: bool = true;
    fn log_likelihood(&self, x: &[f32], z: &Ranges, c: &Constants) -> f32 {
        -0.5 * (0..3)
            .map(|k| ((range(x, c, k) - z.r[k]) / c.range_sigma).powi(2))
            .sum::<f32>()
    }
    fn propagate(&self, x: &[f32], n: &[f32], c: &Constants, next: &mut [f32]) {
        let (vx, vy) = (x[2] + c.accel * c.dt * n[2], x[3] + c.accel * c.dt * n[3]);
        next.copy_from_slice(&[x[0] + vx * c.dt, x[1] + vy * c.dt, vx, vy]);
    }
}

fn range(x: &[f32], c: &Constants, k: usize) -> f32 {
    (x[0] - c.beacons[2 * k]).hypot(x[1] - c.beacons[2 * k + 1])
}

pub const CONSTANTS: Constants = Constants {
    beacons: [0.0, 0.0, 20.0, 0.0, 0.0, 20.0],
    dt: 0.1,
    accel: 0.5,
    range_sigma: 0.2,
};

/// Target t's true state at `time` (s): a straight line from a start that depends on t.
fn truth(t: usize, time: f32) -> [f32; 4] {
    let (vx, vy) = ((t as f32 * 0.7).cos(), (t as f32 * 0.7).sin());
    let start = [6.0 + t as f32, 8.0 + (t % 3) as f32];
    [start[0] + vx * time, start[1] + vy * time, vx, vy]
}

/// The mean distance of the estimates `[t·4 + d]` from the true positions.
fn position_error(truths: &[[f32; 4]], estimates: &[f32]) -> f32 {
    let e = |t: usize, p: &[f32; 4]| (estimates[4 * t] - p[0]).hypot(estimates[4 * t + 1] - p[1]);
    truths.iter().enumerate().map(|(t, p)| e(t, p)).sum::<f32>() / truths.len() as f32
}

/// Tracks `targets` targets for `frames` frames; the mean position error (m) over the second
/// half of the frames, on the GPU (when `ctx` is given) and on the CPU.
pub fn run(
    ctx: Option<&GpuContext>,
    targets: usize,
    frames: usize,
) -> anyhow::Result<(Option<f32>, f32)> {
    let config = BatchConfig::new(BatchShape::new(targets, 1000, 4)?, 3, vec![0.0; 4]);
    let means: Vec<f32> = (0..targets).flat_map(|t| truth(t, 0.0)).collect();
    let start = gaussian_clouds(&config.shape, 4, &means, &[1.0, 1.0, 0.5, 0.5]);
    let on_gpu = |ctx: &GpuContext| -> Result<_, pf_gpu::GpuError> {
        let model = Plugin::gpu(ctx, MODEL, &config.shape, RangeOnly, CONSTANTS)?;
        Filter::on_gpu(
            ctx.clone(),
            &config,
            GpuResampler::Systematic,
            &start,
            model,
        )
    };
    let mut gpu = ctx.map(on_gpu).transpose()?;
    let model = Plugin::cpu(RangeOnly, CONSTANTS);
    let mut cpu = Filter::on_cpu(&config, ResamplerKind::Systematic, start.clone(), model)?;
    let mut noise = pf_core::RandomStreams::new(9).stream(0, pf_core::Stage::Model(0));
    let mut sensor = |p: &[f32; 4]| Ranges {
        r: std::array::from_fn(|k| {
            range(p, &CONSTANTS, k) + CONSTANTS.range_sigma * noise.gaussian_f32()
        }),
    };
    let (mut gpu_errors, mut cpu_errors) = (Vec::new(), Vec::new());
    for frame in 1..=frames {
        let truths: Vec<[f32; 4]> = (0..targets)
            .map(|t| truth(t, frame as f32 * CONSTANTS.dt))
            .collect();
        let observed: Vec<Ranges> = truths.iter().map(&mut sensor).collect();
        if let Some(filter) = gpu.as_mut() {
            gpu_errors.push(position_error(&truths, &filter.step(&observed)?.estimates));
        }
        cpu_errors.push(position_error(&truths, &cpu.step(&observed)?.estimates));
    }
    let second_half =
        |e: &[f32]| e[frames / 2..].iter().sum::<f32>() / (frames - frames / 2) as f32;
    Ok((
        gpu.map(|_| second_half(&gpu_errors)),
        second_half(&cpu_errors),
    ))
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
    let (gpu, cpu) = run(ctx.as_ref(), 8, 60)?;
    if let (Some(g), Some(ctx)) = (gpu, &ctx) {
        println!("GPU ({}): mean position error {g:.3} m", ctx.adapter().name);
    }
    println!("CPU: mean position error {cpu:.3} m");
    Ok(())
}
