//! Observations in from numpy, the posterior out to numpy. Reads `OBS.npy` — noisy 2-D
//! positions, shape (frames, targets, 2), float32 or float64, any order — tracks every target
//! with a six-line WGSL likelihood, and writes `OUT/estimates.npy` (frames, targets, 2) and the
//! last frame's cloud (`OUT/particles_*.npy`, `OUT/log_weights_*.npy`) for `numpy.load`.
//! `cargo run --release --example numpy_io -- OBS.npy OUT [--allow-software]`

use std::path::{Path, PathBuf};

use anyhow::Context;
use bytemuck::{Pod, Zeroable};
use pf_core::batch::{BatchConfig, BatchShape, gaussian_clouds};
use pf_gpu::model::{ModelFilter, ModelSource};
use pf_gpu::{GpuContext, GpuResampler};

const MODEL: ModelSource = ModelSource {
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
#[derive(Clone, Copy, Pod, Zeroable)]
struct Position {
    x: f32,
    y: f32,
}

/// Tracks the observations in `observations` (σ of the noise `noise`, of each frame's move
/// `step`) and writes the posterior to `out`; returns the estimates, (frames, targets, 2).
pub fn run(
    ctx: &GpuContext,
    observations: &Path,
    out: &Path,
    noise: f32,
    step: f32,
) -> anyhow::Result<Vec<f32>> {
    let seen = pf_numpy::read_finite_f32(observations)?;
    seen.expect_shape(observations, &[None, None, Some(2)])?;
    let (frames, targets) = (seen.shape[0], seen.shape[1]);
    anyhow::ensure!(
        frames > 0 && targets > 0,
        "{}: no frames or no targets",
        observations.display()
    );
    let shape = BatchShape::new(targets, 512, 2)?;
    let config = BatchConfig {
        shape,
        seed: 1,
        sigma: vec![step; 2],
        bounds: None,
        angular: vec![false; 2],
        ess_threshold: f64::INFINITY,
        best: 0,
        annealing: Default::default(),
        motion: Default::default(),
    };
    // The first frame's observations, spread by the noise, start the clouds.
    let start = gaussian_clouds(&shape, 3, &seen.data[..2 * targets], &[noise; 2]);
    let constants = 1.0 / noise;
    let mut filter = ModelFilter::new(
        ctx,
        &config,
        GpuResampler::Systematic,
        &start,
        MODEL,
        &constants,
    )?;
    let mut estimates = Vec::with_capacity(frames * targets * 2);
    for frame in seen.data.chunks(2 * targets) {
        let positions: Vec<Position> = frame
            .chunks(2)
            .map(|p| Position { x: p[0], y: p[1] })
            .collect();
        estimates.extend(filter.step(&positions)?.estimates);
    }
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    pf_numpy::write_f32(
        &out.join("estimates.npy"),
        &[frames, targets, 2],
        &estimates,
    )?;
    let (cloud, log_weights) = filter.particles()?;
    pf_numpy::write_particles(out, frames - 1, &shape, &cloud, &log_weights)?;
    Ok(estimates)
}

#[allow(dead_code)]
fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| a != "--allow-software")
        .collect();
    let [observations, out] = args.as_slice() else {
        anyhow::bail!("usage: numpy_io OBS.npy OUT_DIR [--allow-software]");
    };
    let allow_software = std::env::args().any(|a| a == "--allow-software");
    let ctx = GpuContext::new(&pf_gpu::ContextOptions {
        allow_software,
        ..Default::default()
    })?;
    let estimates = run(&ctx, Path::new(observations), &PathBuf::from(out), 0.5, 0.3)?;
    println!(
        "wrote {} estimates to {out}/estimates.npy",
        estimates.len() / 2
    );
    Ok(())
}
