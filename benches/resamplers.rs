//! Resampler throughput, N = 10^3 … 10^6 particles (M = N offspring), in particles per second.
//!
//! Weights are those of a Gaussian likelihood over a Gaussian cloud (the typical shape a tracker
//! sees: mean/max ≈ 0.3), so the rejection and Metropolis resamplers do their usual amount of
//! work. Multinomial, Metropolis and rejection run on all cores (rayon); stratified, systematic
//! and residual are one sequential merge pass.

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use pf_core::resample::{Metropolis, Rejection, Residual};
use pf_core::{RandomStreams, Resampler, ResamplerKind, Stage};

fn weights(n: usize) -> Vec<f64> {
    let mut rng = RandomStreams::new(1).stream(0, Stage::Model(0));
    let raw: Vec<f64> = (0..n)
        .map(|_| (-0.5 * rng.gaussian().powi(2)).exp())
        .collect();
    let sum: f64 = raw.iter().sum();
    raw.into_iter().map(|w| w / sum).collect()
}

fn resamplers() -> Vec<Box<dyn Resampler>> {
    vec![
        ResamplerKind::Multinomial.build(),
        ResamplerKind::Stratified.build(),
        ResamplerKind::Systematic.build(),
        Box::new(Residual::default()),
        Box::new(Metropolis::new(Metropolis::DEFAULT_STEPS)),
        Box::new(Rejection::default()),
    ]
}

fn bench_resamplers(c: &mut Criterion) {
    let mut group = c.benchmark_group("resample");
    for &n in &[1_000usize, 10_000, 100_000, 1_000_000] {
        let w = weights(n);
        let uniforms = RandomStreams::new(2).counter_uniforms(0, Stage::Resampling, 0);
        let mut ancestors = vec![0u32; n];
        group.throughput(Throughput::Elements(n as u64));
        if n >= 100_000 {
            group.sample_size(10);
        }
        for r in resamplers() {
            group.bench_with_input(BenchmarkId::new(r.name(), n), &n, |b, _| {
                b.iter(|| {
                    r.resample(&w, &uniforms, &mut ancestors)
                        .expect("valid weights");
                    std::hint::black_box(&ancestors);
                })
            });
        }
    }
    group.finish();
}

criterion_group!(benches, bench_resamplers);
criterion_main!(benches);
