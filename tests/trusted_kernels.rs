//! The project's kernels are built without wgpu's runtime checks (`pf_gpu::kernels::ShaderChecks::
//! Trusted`: no index clamps, no loop counters). Those checks only ever change an index that was
//! out of range, so a kernel that keeps its promise computes the same bits either way. Two filters
//! of one fresh random configuration (shapes with edge cases: one particle, a workgroup's 256 and
//! one past it, 1 000; one to three layers, fixed or survival β, the fused and the staged layout,
//! the lineage kept or not), one on a context that trusts the project's kernels and one on a
//! context that checks every kernel (`ContextOptions::check_every_kernel`), take the same steps:
//! their reports, particles, weights, log-likelihoods, ancestors and lineage must be the same
//! bytes. A kernel that read past an array would read another value unchecked than checked.
//! A plug-in model's WGSL is held the same way when a context trusts models too. (crates/
//! streampf/tests/trusted_kernels_cli.rs does the same through the face and body trackers' own
//! kernels.)

mod common;

use pf_core::anneal::{Annealing, Tempering};
use pf_core::batch::{BatchConfig, BatchShape, gaussian_clouds};
use pf_gpu::model::ModelFilter;
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

/// A context on the tests' adapter that trusts the project's kernels (and a plug-in model's,
/// when `trust_model_kernels`) or checks every one.
fn context(check_every_kernel: bool, trust_model_kernels: bool) -> GpuContext {
    let options = ContextOptions {
        check_every_kernel,
        trust_model_kernels,
        ..ContextOptions::for_tests()
    };
    let ctx = GpuContext::new(&options).unwrap();
    assert_eq!(ctx.checks_every_kernel(), check_every_kernel);
    ctx
}

/// The toy WGSL plug-in (`pf_gpu::toy::TOY_MODEL`) stepped `frames` times, every report as bits.
fn plugin_run(ctx: &GpuContext, case: &Case) -> Vec<Vec<u32>> {
    use pf_gpu::toy::{TOY_MODEL, ToyConstants, ToyObservation};
    let shape = BatchShape::new(case.targets, case.particles, D).unwrap();
    let mut config = BatchConfig::new(shape, case.seed, SIGMA.to_vec());
    config.annealing = Annealing::survival(case.layers, 0.5, 0.7);
    config.best = case.particles.div_ceil(10);
    let initial = gaussian_clouds(&shape, case.seed, &vec![0.0; case.targets * D], &[1.0; D]);
    let constants = ToyConstants::from_sigma(&SIGMA).unwrap();
    let (systematic, model) = (GpuResampler::Systematic, TOY_MODEL);
    let mut filter =
        ModelFilter::new(ctx, &config, systematic, &initial, model, &constants).unwrap();
    (0..case.steps)
        .map(|step| {
            let observed: Vec<ToyObservation> = (0..case.targets)
                .map(|t| ToyObservation {
                    z: std::array::from_fn(|d| 0.1 * (t + d) as f32 - 0.05 * step as f32),
                })
                .collect();
            let report = filter.step(&observed).unwrap();
            [report.estimates, report.spreads, report.best_estimates]
                .concat()
                .iter()
                .map(|x| x.to_bits())
                .collect()
        })
        .collect()
}

#[test]
fn trusted_kernels_compute_the_same_bits_as_checked_ones() {
    if common::gpu_context("trusted kernels").is_none() {
        return;
    }
    let (trusted, checked) = (context(false, false), context(true, false));
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

/// A plug-in model's kernels keep wgpu's checks unless the context trusts models
/// (`ContextOptions::trust_model_kernels`), and `check_every_kernel` wins over that: the toy WGSL
/// model gives the same bits trusted and checked, on fresh random shapes.
#[test]
fn a_trusted_plugin_model_computes_the_same_bits_as_a_checked_one() {
    if common::gpu_context("trusted plug-in kernels").is_none() {
        return;
    }
    use pf_gpu::kernels::ShaderChecks::{Checked, Trusted};
    let trusting = context(false, true);
    let checking = context(true, true);
    // What each context builds the toy model's kernels with: trusted only where models are
    // trusted and not every kernel is checked.
    let toy = |ctx: &GpuContext| {
        let shape = BatchShape::new(2, 8, D).unwrap();
        let constants = pf_gpu::toy::ToyConstants::from_sigma(&SIGMA).unwrap();
        let model: pf_gpu::model::WgslModel<pf_gpu::toy::ToyObservation, _> =
            pf_gpu::model::WgslModel::new(ctx, pf_gpu::toy::TOY_MODEL, &shape, &constants).unwrap();
        model.kernel_checks()
    };
    assert_eq!(toy(&trusting), Trusted);
    assert_eq!(toy(&checking), Checked);
    assert_eq!(toy(&context(false, false)), Checked);
    let mut runner = proptest::test_runner::TestRunner::new(common::property::config(6));
    runner
        .run(&case(), |case| {
            let (fast, slow) = (plugin_run(&trusting, &case), plugin_run(&checking, &case));
            prop_assert_eq!(fast.len(), case.steps);
            prop_assert!(fast == slow, "trusted and checked plug-in kernels differ");
            Ok(())
        })
        .unwrap();
}
