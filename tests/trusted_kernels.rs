//! The project's kernels are built without wgpu's runtime checks (`pf_gpu::kernels::ShaderChecks::
//! Trusted`: no index clamps, no loop counters). Those checks only ever change an index that was
//! out of range, so a kernel that keeps its promise computes the same bits either way. Two filters
//! of one fresh random configuration (shapes with edge cases: one particle, a workgroup's 256 and
//! one past it, 1 000; one to three layers, fixed or survival β, the fused and the staged layout,
//! the lineage kept or not), one on a context that trusts the project's kernels and one on a
//! context that checks every kernel (`ContextOptions::check_every_kernel`), take the same steps:
//! their reports, particles, weights, log-likelihoods, ancestors and lineage must be the same
//! bytes. A kernel that read past an array would read another value unchecked than checked.
//! (crates/streampf/tests/trusted_kernels_cli.rs does the same through the face and body
//! trackers' own kernels.)

mod common;

use pf_core::anneal::{Annealing, Tempering};
use pf_core::batch::{BatchConfig, BatchShape, gaussian_clouds};
use pf_gpu::toy::ToyGaussianLikelihood;
use pf_gpu::{ContextOptions, GpuContext, GpuFilter, GpuLikelihood, GpuResampler, StepLayout};
use proptest::prelude::*;

const D: usize = 7;
const SIGMA: [f32; D] = [0.3, 0.2, 0.4, 0.1, 0.25, 0.15, 0.35];

#[derive(Debug, Clone)]
struct Case {
    targets: usize,
    particles: usize,
    layers: usize,
    survival: bool,
    staged: bool,
    lineage: bool,
    stratified: bool,
    seed: u64,
    steps: usize,
}

fn case() -> impl Strategy<Value = Case> {
    (
        (
            1usize..4,
            prop_oneof![Just(1usize), 2usize..300, Just(256), Just(257), Just(1000)],
            1usize..4,
        ),
        (any::<bool>(), any::<bool>(), any::<bool>(), any::<bool>()),
        (any::<u64>(), 1usize..4),
    )
        .prop_map(
            |(
                (targets, particles, layers),
                (survival, staged, lineage, stratified),
                (seed, steps),
            )| Case {
                targets,
                particles,
                layers,
                survival,
                staged,
                lineage,
                stratified,
                seed,
                steps,
            },
        )
}

fn filter(ctx: &GpuContext, case: &Case) -> (GpuFilter, ToyGaussianLikelihood) {
    let shape = BatchShape::new(case.targets, case.particles, D).unwrap();
    let mut annealing = Annealing::survival(case.layers, 0.5, 0.7);
    if !case.survival {
        annealing.tempering =
            Tempering::Fixed((0..case.layers).map(|l| 0.3 + 0.2 * l as f32).collect());
    }
    let config = BatchConfig {
        shape,
        seed: case.seed,
        sigma: SIGMA.to_vec(),
        bounds: None,
        angular: vec![false, false, false, true, false, false, false],
        ess_threshold: 0.5,
        best: case.particles.div_ceil(10),
        annealing,
        motion: Default::default(),
    };
    let means = vec![0.0; case.targets * D];
    let initial = gaussian_clouds(&shape, case.seed, &means, &[1.0; D]);
    let resampler = match case.stratified {
        true => GpuResampler::Stratified,
        false => GpuResampler::Systematic,
    };
    let mut filter = GpuFilter::new(ctx, &config, resampler, &initial).unwrap();
    if case.staged {
        filter.set_step_layout(StepLayout::Staged).unwrap();
    }
    if case.lineage {
        filter.keep_lineage(ctx).unwrap();
    }
    let mut likelihood = ToyGaussianLikelihood::new(ctx, case.targets, &SIGMA).unwrap();
    likelihood
        .prepare(ctx, &filter.likelihood_inputs())
        .unwrap();
    (filter, likelihood)
}

/// Every step's report and the particles after it, as bytes.
fn run(ctx: &GpuContext, case: &Case) -> Vec<Vec<u8>> {
    let (mut filter, likelihood) = filter(ctx, case);
    let mut steps = Vec::new();
    for step in 0..case.steps {
        let z: Vec<f32> = (0..case.targets * D)
            .map(|k| ((k * 7 + step * 13) % 17) as f32 * 0.05 - 0.4)
            .collect();
        likelihood.upload_observations(ctx, &z).unwrap();
        let report = filter.step(ctx, &likelihood).unwrap();
        let mut bytes: Vec<u8> = Vec::new();
        bytes.extend(bytemuck::cast_slice(&report.estimates));
        bytes.extend(bytemuck::cast_slice(&report.best_estimates));
        bytes.extend(bytemuck::cast_slice(&report.spreads));
        bytes.extend(bytemuck::cast_slice(&report.stats));
        bytes.extend(bytemuck::cast_slice(&filter.download_states(ctx).unwrap()));
        bytes.extend(bytemuck::cast_slice(&filter.download_weights(ctx).unwrap()));
        let log_likelihood = filter.download_log_likelihood(ctx).unwrap();
        bytes.extend(bytemuck::cast_slice(&log_likelihood));
        bytes.extend(bytemuck::cast_slice(
            &filter.download_ancestors(ctx).unwrap(),
        ));
        if let Some(lineage) = filter.download_lineage(ctx).unwrap() {
            bytes.extend(bytemuck::cast_slice(&lineage));
        }
        steps.push(bytes);
    }
    steps
}

/// A context on the tests' adapter that trusts the project's kernels or checks every one.
fn context(check_every_kernel: bool) -> GpuContext {
    let options = ContextOptions {
        check_every_kernel,
        ..ContextOptions::for_tests()
    };
    let ctx = GpuContext::new(&options).unwrap();
    assert_eq!(ctx.checks_every_kernel(), check_every_kernel);
    ctx
}

#[test]
fn trusted_kernels_compute_the_same_bits_as_checked_ones() {
    if common::gpu_context("trusted kernels").is_none() {
        return;
    }
    let (trusted, checked) = (context(false), context(true));
    let mut runner = proptest::test_runner::TestRunner::new(common::property::config(8));
    runner
        .run(&case(), |case| {
            let (fast, slow) = (run(&trusted, &case), run(&checked, &case));
            for (k, (a, b)) in fast.iter().zip(&slow).enumerate() {
                prop_assert!(a == b, "step {k}: trusted and checked kernels differ");
            }
            prop_assert_eq!(fast.len(), case.steps);
            Ok(())
        })
        .unwrap();
}
