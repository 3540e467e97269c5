//! The resamplers: time against N (M = N offspring), and how far each one's offspring counts
//! stray from their expectation N·wᵢ, on the CPU (all six of pf-core) and on the GPU (the
//! driver's systematic, stratified and Metropolis stages alone, wait and readback included).
//!
//! The spread is the root mean square of (nᵢ − N·wᵢ) over the particles, where nᵢ counts the
//! offspring of particle i: about √(1 − wᵢ) ≈ 1 for multinomial resampling, under ½ for the
//! systematic and stratified schemes, which is why they are preferred. It is the median over
//! several draws (different uniforms), with the quartiles as its spread.

use pf_core::batch::{BatchConfig, BatchShape};
use pf_core::{RandomStreams, Resampler, ResamplerKind, Stage};
use pf_gpu::{GpuContext, GpuFilter, GpuResampler, GpuStage, NoLikelihood};

use super::Run;
use crate::record::{Figure, Panel, Point};
use crate::timing::{measure, summarise};

fn sizes(quick: bool) -> &'static [usize] {
    if quick {
        &[1_000, 10_000, 100_000]
    } else {
        &[1_000, 10_000, 100_000, 1_000_000]
    }
}

/// Draws per size for the spread.
fn draws(quick: bool) -> u64 {
    if quick { 5 } else { 20 }
}

/// Every resampler the GPU runs (`GpuResampler::KINDS`), with its series' name.
fn gpu_resamplers() -> Vec<(String, GpuResampler)> {
    GpuResampler::KINDS
        .into_iter()
        .filter_map(|kind| GpuResampler::for_kind(kind).ok())
        .map(|resampler| {
            let name = match resampler {
                GpuResampler::Metropolis(steps) => format!("GPU Metropolis (B = {steps})"),
                GpuResampler::Systematic => "GPU systematic".to_string(),
                GpuResampler::Stratified => "GPU stratified".to_string(),
            };
            (name, resampler)
        })
        .collect()
}

pub fn steps(quick: bool) -> u64 {
    (ResamplerKind::ALL.len() + GpuResampler::KINDS.len()) as u64 * sizes(quick).len() as u64
}

/// Weights of a Gaussian likelihood over a Gaussian cloud (mean/max ≈ 0.3, the shape a tracker
/// sees), normalised, and the cloud itself.
fn weights(n: usize) -> (Vec<f32>, Vec<f64>) {
    let mut rng = RandomStreams::new(1).stream(0, Stage::Model(0));
    let states: Vec<f32> = (0..n).map(|_| rng.gaussian_f32()).collect();
    let raw: Vec<f64> = states
        .iter()
        .map(|&x| (-0.5 * f64::from(x).powi(2)).exp())
        .collect();
    let sum: f64 = raw.iter().sum();
    (states, raw.into_iter().map(|w| w / sum).collect())
}

/// Root mean square of (nᵢ − N·wᵢ).
fn offspring_spread(ancestors: &[u32], weights: &[f64]) -> f64 {
    let mut counts = vec![0u32; weights.len()];
    for &a in ancestors {
        if let Some(c) = counts.get_mut(a as usize) {
            *c += 1;
        }
    }
    let n = ancestors.len() as f64;
    let sum: f64 = counts
        .iter()
        .zip(weights)
        .map(|(&c, &w)| (f64::from(c) - n * w).powi(2))
        .sum();
    (sum / weights.len() as f64).sqrt()
}

fn cpu_kind(kind: ResamplerKind) -> &'static str {
    // Multinomial, Metropolis and rejection run on all cores; the rest are one sequential pass.
    match kind {
        ResamplerKind::Multinomial | ResamplerKind::Metropolis | ResamplerKind::Rejection => {
            "cpu-all"
        }
        _ => "cpu-1",
    }
}

pub fn run(run: &mut Run) -> anyhow::Result<Figure> {
    let mut time = Panel::new(
        "time against particles (M = N)",
        ("particles N", "particles"),
        ("resampling time (ms)", "ms"),
    )
    .log_axes(true, true)
    .timings();
    let mut spread = Panel::new(
        "offspring counts around N·wᵢ",
        ("particles N", "particles"),
        ("RMS of (nᵢ − N·wᵢ) (offspring)", "offspring"),
    )
    .log_axes(true, false);
    for &n in sizes(run.quick) {
        let (states, w) = weights(n);
        let x = n as f64;
        let mut ancestors = vec![0u32; n];
        for kind in ResamplerKind::ALL {
            run.step(&format!("resamplers: CPU {} at N = {n}", kind.name()));
            let r = kind.build();
            let uniforms = RandomStreams::new(2).counter_uniforms(0, Stage::Resampling, 0);
            let plan = if n >= 100_000 && kind == ResamplerKind::Metropolis {
                run.plan.slow()
            } else {
                run.plan
            };
            let p = measure(plan, x, || r.resample(&w, &uniforms, &mut ancestors))?;
            let name = format!("CPU {}", kind.name());
            time.series_mut(&name, cpu_kind(kind))
                .points
                .push(p.scaled(1e3));
            let mut spreads = Vec::new();
            for draw in 0..draws(run.quick) {
                let uniforms = RandomStreams::new(3).counter_uniforms(0, Stage::Resampling, draw);
                r.resample(&w, &uniforms, &mut ancestors)?;
                spreads.push(offspring_spread(&ancestors, &w));
            }
            spread
                .series_mut(&name, "")
                .points
                .push(summarise(x, spreads));
        }
        for (name, resampler) in gpu_resamplers() {
            run.step(&format!("resamplers: {name} at N = {n}"));
            let Some(ctx) = run.gpu else { continue };
            let (t, s) = gpu_resampler(ctx, run, resampler, &states, &w, x)?;
            time.series_mut(&name, "gpu").points.push(t.scaled(1e3));
            spread.series_mut(&name, "").points.push(s);
        }
    }
    Ok(Figure {
        name: "resamplers",
        title: "Resamplers: time and offspring spread, CPU and GPU".into(),
        description: "Weights of a Gaussian likelihood over a Gaussian cloud (mean/max ≈ 0.3). CPU: \
            pf-core's six resamplers (multinomial, Metropolis and rejection on all cores; the others \
            one sequential pass). GPU: the filter's resample stage alone in one submission, wait \
            included (systematic and stratified by a prefix sum and binary search, Metropolis with \
            32 steps per offspring). The spread is the RMS of (nᵢ − N·wᵢ) over the particles, the \
            median over several draws."
            .into(),
        panels: vec![time, spread],
    })
}

fn gpu_resampler(
    ctx: &GpuContext,
    run: &Run,
    resampler: GpuResampler,
    states: &[f32],
    weights: &[f64],
    x: f64,
) -> anyhow::Result<(Point, Point)> {
    let n = states.len();
    let config = BatchConfig {
        shape: BatchShape::new(1, n, 1)?,
        seed: 2,
        sigma: vec![0.0],
        bounds: None,
        angular: vec![false],
        ess_threshold: f64::INFINITY,
        best: 0,
        annealing: Default::default(),
        motion: Default::default(),
    };
    let mut gpu = GpuFilter::new(ctx, &config, resampler, states)?;
    let w32: Vec<f32> = weights.iter().map(|&w| w as f32).collect();
    gpu.streams().weights.upload(ctx, &w32)?;
    let t = measure(run.plan, x, || {
        gpu.run_stages(ctx, &[GpuStage::Resample], &NoLikelihood)
            .map(|_| ())
    })?;
    let mut spreads = Vec::new();
    for draw in 0..draws(run.quick) {
        gpu.set_step(1000 + draw);
        gpu.run_stages(ctx, &[GpuStage::Resample], &NoLikelihood)?;
        let ancestors = gpu.download_ancestors(ctx)?;
        spreads.push(offspring_spread(&ancestors, weights));
    }
    Ok((t, summarise(x, spreads)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spread_is_zero_for_exact_offspring_and_counts_deviations() {
        let w = [0.5, 0.25, 0.25];
        // N = 4: expected 2, 1, 1.
        assert_eq!(offspring_spread(&[0, 0, 1, 2], &w), 0.0);
        // 3, 1, 0: deviations 1, 0, −1.
        let s = offspring_spread(&[0, 0, 0, 1], &w);
        assert!((s - (2.0f64 / 3.0).sqrt()).abs() < 1e-12);
    }
}
