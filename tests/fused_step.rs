//! The fused step (`shaders/engine/layer.wgsl`, `pf_gpu::StepLayout::Fused`: a layer's select
//! normalises the layer before, resamples and gathers, its move diffuses) against the staged step it
//! replaces and against the CPU twin, on fresh random configurations: shapes with edge cases (one
//! particle, one target, particles around the workgroup's 256), one to four layers of fixed or
//! survival β, partitioned layers, bounds, angles, the constant-velocity drift, a model with its
//! own dynamics, systematic and stratified resampling, and resampling every step or by ESS.
//!
//! Fused and staged draw the same random numbers in the same order, so they must pick the same
//! ancestors and give the same particles (to rounding: the two are different pipelines, so a
//! compiler may fuse a multiply-add in one and not the other). Against the CPU, the estimates
//! and each layer's β agree within the tolerance the whole-step tests use.

mod common;

use bytemuck::{Pod, Zeroable};
use pf_core::anneal::Annealing;
use pf_core::batch::{BatchConfig, BatchFilter, BatchShape, Motion, gaussian_clouds};
use pf_core::plugin::CpuModel;
use pf_core::resample::{Stratified, Systematic};
use pf_gpu::model::{ModelFilter, ModelSource};
use pf_gpu::{GpuResampler, StepLayout};
use proptest::prelude::*;

/// Observed dimensions (a state's first eight at most).
const OBSERVED: usize = 8;
const FRAMES: usize = 3;

const GAUSSIAN: &str = "
struct Observation { z: array<f32, 8> }
struct Constants { sigma: f32, decay: f32 }
fn log_likelihood(x: State, o: Observation, c: Constants) -> f32 {
    var z = o.z;
    var sum = 0.0;
    for (var d = 0u; d < min(DIMS, 8u); d++) {
        let e = (x[d] - z[d]) / c.sigma;
        sum += e * e;
    }
    return -0.5 * sum;
}";

const DYNAMICS: &str = "
fn propagate(x: State, noise: State, c: Constants) -> State {
    var next: State;
    for (var d = 0u; d < DIMS; d++) {
        next[d] = c.decay * x[d] + 0.05 * noise[d];
    }
    return next;
}";

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Observed {
    z: [f32; OBSERVED],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Constants {
    sigma: f32,
    decay: f32,
}

const CONSTANTS: Constants = Constants {
    sigma: 0.2,
    decay: 0.9,
};

/// The CPU twin of both WGSL models (`DYNAMICS`: with the model's own dynamics).
struct Gaussian<const DYNAMICS: bool>;

impl<const DYNAMICS: bool> CpuModel<Observed, Constants> for Gaussian<DYNAMICS> {
    const PROPAGATES: bool = DYNAMICS;

    fn log_likelihood(&self, x: &[f32], o: &Observed, c: &Constants) -> f32 {
        -0.5 * x
            .iter()
            .zip(&o.z)
            .map(|(a, b)| ((a - b) / c.sigma).powi(2))
            .sum::<f32>()
    }

    fn propagate(&self, x: &[f32], noise: &[f32], c: &Constants, next: &mut [f32]) {
        for ((n, x), e) in next.iter_mut().zip(x).zip(noise) {
            *n = c.decay * x + 0.05 * e;
        }
    }
}

/// One drawn configuration.
#[derive(Debug, Clone)]
struct Case {
    config: BatchConfig,
    stratified: bool,
    propagates: bool,
}

fn particles() -> impl Strategy<Value = usize> {
    prop_oneof![
        Just(1usize),
        Just(2),
        Just(255),
        Just(256),
        Just(257),
        Just(1000),
        3usize..700
    ]
}

fn annealing(dims: usize) -> impl Strategy<Value = Annealing> {
    (
        1usize..=4,
        0.2f32..0.8,
        0.5f32..1.0,
        any::<bool>(),
        any::<bool>(),
    )
        .prop_map(move |(layers, rate, decay, fixed, partitioned)| {
            let mut a = Annealing::survival(layers, rate, decay);
            if fixed {
                let betas = (0..layers).map(|l| 0.3 + 0.2 * l as f32).collect();
                a.tempering = pf_core::anneal::Tempering::Fixed(betas);
            }
            if partitioned && dims > 1 {
                // Layer l moves every dimension but l mod D.
                a = a.partitioned(
                    (0..layers)
                        .map(|l| (0..dims).filter(|&d| d != l % dims).collect())
                        .collect(),
                );
            }
            a
        })
}

fn case() -> impl Strategy<Value = Case> {
    (1usize..=5, particles(), 1usize..=9)
        .prop_flat_map(|(targets, particles, dims)| {
            (
                Just((targets, particles, dims)),
                annealing(dims),
                any::<u64>(),
                (any::<bool>(), any::<bool>(), any::<bool>()),
                (any::<bool>(), any::<bool>(), any::<bool>()),
            )
        })
        .prop_map(
            |(
                (targets, particles, dims),
                annealing,
                seed,
                (stratified, propagates, by_ess),
                (bounded, angles, drift),
            )| {
                let shape = BatchShape::new(targets, particles, dims).unwrap();
                let mut config = BatchConfig::new(shape, seed, vec![0.1; dims]);
                config.annealing = annealing;
                if by_ess {
                    config.ess_threshold = 0.5;
                }
                if bounded {
                    config.bounds = Some((vec![-0.8; dims], vec![0.9; dims]));
                }
                if angles {
                    config.angular = (0..dims).map(|d| d % 2 == 1).collect();
                }
                if drift {
                    config.motion = Motion::ConstantVelocity { gain: 0.5 };
                }
                Case {
                    config,
                    stratified,
                    propagates,
                }
            },
        )
}

fn observation(t: usize, frame: usize) -> Observed {
    let mut z = [0.0; OBSERVED];
    for (d, v) in z.iter_mut().enumerate() {
        *v = 0.3 * ((t + 2 * d) as f32 * 0.7 + frame as f32 * 0.4).sin();
    }
    Observed { z }
}

fn observations(targets: usize, frame: usize) -> Vec<Observed> {
    (0..targets).map(|t| observation(t, frame)).collect()
}

fn start(config: &BatchConfig) -> Vec<f32> {
    let shape = config.shape;
    let means = vec![0.0; shape.targets * shape.dims];
    gaussian_clouds(&shape, 5, &means, &vec![0.3; shape.dims])
}

fn gpu_filter(
    ctx: &pf_gpu::GpuContext,
    case: &Case,
    layout: StepLayout,
) -> ModelFilter<Observed, Constants> {
    let wgsl = if case.propagates {
        format!("{GAUSSIAN}\n{DYNAMICS}")
    } else {
        GAUSSIAN.to_string()
    };
    let resampler = if case.stratified {
        GpuResampler::Stratified
    } else {
        GpuResampler::Systematic
    };
    let source = ModelSource {
        name: "Gaussian",
        wgsl: &wgsl,
    };
    let mut filter = ModelFilter::new(
        ctx,
        &case.config,
        resampler,
        &start(&case.config),
        source,
        &CONSTANTS,
    )
    .unwrap();
    let (_, gpu, _) = filter.gpu_parts().unwrap();
    gpu.set_step_layout(layout).unwrap();
    assert_eq!(gpu.step_layout(), layout);
    filter
}

/// Whether two values are the same to rounding (NaN only with NaN).
fn same(a: f32, b: f32) -> bool {
    if a.is_nan() || b.is_nan() {
        return a.is_nan() && b.is_nan();
    }
    a == b || (a - b).abs() <= 1e-5 * (1.0 + a.abs().max(b.abs()))
}

/// Where two slices differ beyond rounding: (index, a, b) of the first.
fn first_difference(a: &[f32], b: &[f32]) -> Option<(usize, f32, f32)> {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .enumerate()
        .find(|(_, (x, y))| !same(**x, **y))
        .map(|(i, (x, y))| (i, *x, *y))
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    /// Fused and staged from the same particles: the same ancestors, particles, weights,
    /// estimates, β, ESS and evidence after every frame.
    #[test]
    fn fused_step_gives_the_staged_steps_particles(case in case()) {
        let Some(ctx) = common::gpu_context("fused step against the staged step") else {
            return Ok(());
        };
        let mut fused = gpu_filter(&ctx, &case, StepLayout::Fused);
        let mut staged = gpu_filter(&ctx, &case, StepLayout::Staged);
        for frame in 1..=FRAMES {
            let z = observations(case.config.shape.targets, frame);
            let a = fused.step(&z).unwrap();
            let b = staged.step(&z).unwrap();
            let (_, fa, _) = fused.gpu_parts().unwrap();
            let ancestors_a = fa.download_ancestors(&ctx).unwrap();
            let states_a = fa.download_states(&ctx).unwrap();
            let log_w_a = fa.download_log_weights(&ctx).unwrap();
            let (_, fb, _) = staged.gpu_parts().unwrap();
            prop_assert_eq!(&ancestors_a, &fb.download_ancestors(&ctx).unwrap(), "frame {} ancestors", frame);
            let states_b = fb.download_states(&ctx).unwrap();
            prop_assert_eq!(first_difference(&states_a, &states_b), None, "frame {} states", frame);
            let log_w_b = fb.download_log_weights(&ctx).unwrap();
            prop_assert_eq!(first_difference(&log_w_a, &log_w_b), None, "frame {} log-weights", frame);
            prop_assert_eq!(first_difference(&a.estimates, &b.estimates), None, "frame {} estimates", frame);
            prop_assert_eq!(first_difference(&a.spreads, &b.spreads), None, "frame {} spreads", frame);
            // The survival rule's β, bisected over workgroup copies (fused) or over the storage
            // buffers (staged): the same floats, bit for bit.
            let bits = |beta: &[f32]| beta.iter().map(|b| b.to_bits()).collect::<Vec<_>>();
            prop_assert_eq!(bits(&a.beta), bits(&b.beta), "frame {} beta", frame);
            prop_assert_eq!(&a.resampled, &b.resampled);
            for (x, y) in a.ess.iter().zip(&b.ess).chain(a.log_evidence.iter().zip(&b.log_evidence)) {
                prop_assert!(same(*x as f32, *y as f32), "frame {}: ESS or evidence {} vs {}", frame, x, y);
            }
        }
    }
}

/// How far the GPU's last β may lie from the CPU's: 1 % where β does not depend on the
/// resampled cloud (fixed β, or survival β in a single layer: the same particles, f32 against f64
/// sums). A survival β after a resampled layer is solved on that layer's offspring, which a flip at
/// a CDF boundary changes (see `check_against_cpu`): the spread of the log-likelihoods it is
/// solved against moves by about its standard error, √(2/ESS) relative, so three of those are
/// allowed on top (measured: 0.5185 against 0.5297, 2.1 %, with 3 layers of 257 particles).
fn beta_bound(case: &Case, cpu_beta: f32, cpu_ess: f64) -> f32 {
    let exact = 1e-2 * cpu_beta.abs().max(1e-3);
    let annealing = &case.config.annealing;
    let solved_after_resampling = annealing.layers > 1
        && matches!(
            annealing.tempering,
            pf_core::anneal::Tempering::Survival { .. }
        );
    if solved_after_resampling {
        exact + 3.0 * (2.0 / cpu_ess.max(1.0)).sqrt() as f32 * cpu_beta.abs()
    } else {
        exact
    }
}

/// The fused step against the CPU twin, on the same drawn configurations, one frame (every layer
/// of it) from the same particles: the estimates within 2e-3 (the whole-step tests' bound) plus
/// three standard errors of the weighted mean (spread/√ESS), and each target's last β as `beta_bound`
/// allows.
/// The standard errors allow for resampling flips at a CDF boundary: a flipped offspring weighs
/// differently in the next layer, which shifts that layer's CDF and can flip more (measured on
/// lavapipe over 24 seeds of 4 targets × 1 000 particles × 3 fixed-β layers: most targets agree
/// exactly, the worst differed by 1.2 standard errors). One frame,
/// because the f32 and f64 sums of the weights part at a CDF boundary now and then, and a
/// flipped offspring changes the next frame's weights: over frames the two engines drift apart
/// (the staged step exactly as the fused one does). Later frames, the drift included, are the
/// staged-against-fused test's, and the staged stages are each checked against the CPU
/// (`gpu_stages`).
fn check_against_cpu<const DYNAMICS: bool>(case: &Case) -> Result<(), TestCaseError> {
    let Some(ctx) = common::gpu_context("fused step against the CPU") else {
        return Ok(());
    };
    let model = Gaussian::<DYNAMICS>;
    let mut gpu = gpu_filter(&ctx, case, StepLayout::Fused);
    let states = start(&case.config);
    let mut systematic = BatchFilter::new(&case.config, Systematic, states.clone()).unwrap();
    let mut stratified = BatchFilter::new(&case.config, Stratified, states).unwrap();
    {
        let frame = 1;
        let z = observations(case.config.shape.targets, frame);
        let cpu = if case.stratified {
            stratified.step_model(&model, &z, &CONSTANTS).unwrap()
        } else {
            systematic.step_model(&model, &z, &CONSTANTS).unwrap()
        };
        let g = gpu.step(&z).unwrap();
        for (t, (cb, gb)) in cpu.beta.iter().zip(&g.beta).enumerate() {
            let bound = beta_bound(case, *cb, cpu.ess[t]);
            prop_assert!(
                (cb - gb).abs() <= bound,
                "frame {frame} target {t}: beta CPU {cb} vs GPU {gb} (bound {bound})"
            );
        }
        let dims = case.config.shape.dims;
        for (i, (x, y)) in cpu.estimates.iter().zip(&g.estimates).enumerate() {
            let standard_error = cpu.spreads[i] as f64 / cpu.ess[i / dims].max(1.0).sqrt();
            prop_assert!(
                ((x - y).abs() as f64) <= 2e-3 + 3.0 * standard_error,
                "frame {frame} value {i}: CPU {x} vs GPU {y} (standard error {standard_error})"
            );
        }
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 16, ..ProptestConfig::default() })]

    #[test]
    fn fused_step_matches_cpu(case in case()) {
        if case.propagates {
            check_against_cpu::<true>(&case)?;
        } else {
            check_against_cpu::<false>(&case)?;
        }
    }
}

/// The configuration on which the 1 % bound on a later survival β failed (found by the property
/// test on lavapipe): three survival layers of 257 particles, 9 bounded dimensions.
#[test]
fn a_survival_beta_after_resampling_flips_stays_within_its_bound() {
    let shape = BatchShape::new(3, 257, 9).unwrap();
    let mut config = BatchConfig::new(shape, 16687176928982119186, vec![0.1; 9]);
    config.bounds = Some((vec![-0.8; 9], vec![0.9; 9]));
    config.annealing = Annealing::survival(3, 0.561_329_07, 0.588_483_6);
    let case = Case {
        config,
        stratified: true,
        propagates: true,
    };
    if let Err(failure) = check_against_cpu::<true>(&case) {
        panic!("{failure}");
    }
}

/// Where the fused step does not fit, it is refused with the reason and the staged step runs.
#[test]
fn metropolis_and_huge_clouds_keep_the_staged_step() {
    let Some(ctx) = common::gpu_context("fused step refusals") else {
        return;
    };
    let small = BatchShape::new(2, 100, 3).unwrap();
    let refusal = pf_gpu::fused_layout_refusal(&ctx, &small, GpuResampler::Metropolis(8));
    assert!(refusal.unwrap().contains("Metropolis"));
    let huge = BatchShape::new(1, 5000, 3).unwrap();
    let refusal = pf_gpu::fused_layout_refusal(&ctx, &huge, GpuResampler::Systematic);
    assert!(refusal.unwrap().contains("5000 particles"));
    assert_eq!(
        pf_gpu::fused_layout_refusal(&ctx, &small, GpuResampler::Stratified),
        None
    );
    // 1 000 particles × 8 400 dimensions: 65 625 workgroups of the move, past the 65 535 a
    // dimension WebGPU guarantees.
    let wide = BatchShape::new(1, 1000, 8400).unwrap();
    let limit = ctx.limits().max_compute_workgroups_per_dimension;
    let refusal = pf_gpu::fused_layout_refusal(&ctx, &wide, GpuResampler::Systematic);
    assert_eq!(
        refusal.is_some_and(|why| why.contains("workgroups of the move")),
        limit < 65_625,
        "adapter allows {limit} workgroups a dimension"
    );
    let config = BatchConfig::new(huge, 1, vec![0.1; 3]);
    let mut filter = pf_gpu::GpuFilter::new(
        &ctx,
        &config,
        GpuResampler::Systematic,
        &vec![0.0; huge.state_len()],
    )
    .unwrap();
    assert_eq!(filter.step_layout(), StepLayout::Staged);
    let error = filter.set_step_layout(StepLayout::Fused).unwrap_err();
    assert!(error.to_string().contains("does not fit"), "{error}");
}

/// The fused step is the default for few values a target, the staged one for many (where one
/// workgroup a target would gather and move them alone); both can be chosen where they fit.
#[test]
fn the_default_layout_follows_the_values_a_target() {
    let Some(ctx) = common::gpu_context("fused step default") else {
        return;
    };
    let layout_of = |particles: usize, dims: usize| {
        let shape = BatchShape::new(3, particles, dims).unwrap();
        let config = BatchConfig::new(shape, 1, vec![0.1; dims]);
        let states = vec![0.0; shape.state_len()];
        pf_gpu::GpuFilter::new(&ctx, &config, GpuResampler::Stratified, &states).unwrap()
    };
    let face_like = layout_of(1000, 7);
    assert_eq!(face_like.step_layout(), StepLayout::Fused);
    let values = pf_gpu::FUSED_DEFAULT_MAX_VALUES;
    let mut body_like = layout_of(values / 8 + 1, 8);
    assert_eq!(body_like.step_layout(), StepLayout::Staged);
    body_like.set_step_layout(StepLayout::Fused).unwrap();
    assert_eq!(body_like.step_layout(), StepLayout::Fused);
}

/// A profiled fused step of a model with its own dynamics and its lineage kept names layer 0's
/// copy back and dynamics and every layer's lineage (`GpuFilter::profile_dispatches`), and
/// keeps the unprofiled step's particles.
#[test]
fn a_profiled_step_names_the_dynamics_and_the_lineage() {
    let Some(ctx) = common::gpu_context("profiled dynamics and lineage") else {
        return;
    };
    let shape = BatchShape::new(2, 300, 5).unwrap();
    let mut config = BatchConfig::new(shape, 11, vec![0.1; 5]);
    config.annealing = Annealing::survival(2, 0.5, 0.7);
    let case = Case {
        config,
        stratified: false,
        propagates: true,
    };
    let mut plain = gpu_filter(&ctx, &case, StepLayout::Fused);
    let mut profiled = gpu_filter(&ctx, &case, StepLayout::Fused);
    let (ctx_p, gpu, _) = profiled.gpu_parts().unwrap();
    if !ctx_p.has_timestamps() {
        assert!(gpu.profile_dispatches(ctx_p, true).is_err());
        return;
    }
    gpu.keep_lineage(ctx_p).unwrap();
    // The lineage in dispatches of its own (the reference), named; the plain filter composes it
    // in its select.
    gpu.set_lineage_in_select(ctx_p, false).unwrap();
    gpu.profile_dispatches(ctx_p, true).unwrap();
    let (ctx_a, gpu_a, _) = plain.gpu_parts().unwrap();
    gpu_a.keep_lineage(ctx_a).unwrap();
    let fits = ctx_a.limits().max_storage_buffers_per_shader_stage >= 11;
    assert_eq!(gpu_a.lineage_in_select(), fits);
    for frame in 1..=2 {
        let z = observations(2, frame);
        let expected = plain.step(&z).unwrap();
        let got = profiled.step(&z).unwrap();
        assert_eq!(got.estimates, expected.estimates);
    }
    let (ctx_p, gpu, _) = profiled.gpu_parts().unwrap();
    let labels = dispatch_labels(gpu, ctx_p);
    assert_eq!(
        labels,
        [
            "layer 0: select",
            "layer 0: copy back",
            "layer 0: the likelihood's dynamics",
            "layer 0: lineage",
            "layer 0: likelihood",
            "layer 1: select",
            "layer 1: move",
            "layer 1: lineage",
            "layer 1: likelihood",
            "last normalise",
            "estimate",
        ]
    );
    let (ctx_a, gpu_a, _) = plain.gpu_parts().unwrap();
    let lineage = gpu_a.download_lineage(ctx_a).unwrap();
    let (ctx_p, gpu, _) = profiled.gpu_parts().unwrap();
    assert_eq!(gpu.download_lineage(ctx_p).unwrap(), lineage);
    assert_eq!(
        gpu.download_states(ctx_p).unwrap(),
        plain
            .gpu_parts()
            .map(|(c, g, _)| g.download_states(c).unwrap())
            .unwrap()
    );
    // Composed in the select: no lineage dispatch, the same lineage as the plain filter's.
    // The select composing the lineage binds 11 storage buffers; an adapter with fewer refuses
    // it (lavapipe and NVIDIA's allow it).
    if ctx_p.limits().max_storage_buffers_per_shader_stage < 11 {
        assert!(gpu.set_lineage_in_select(ctx_p, true).is_err());
        return;
    }
    gpu.set_lineage_in_select(ctx_p, true).unwrap();
    let z = observations(2, 3);
    plain.step(&z).unwrap();
    profiled.step(&z).unwrap();
    let (ctx_p, gpu, _) = profiled.gpu_parts().unwrap();
    let labels = dispatch_labels(gpu, ctx_p);
    assert_eq!(labels.len(), 9, "{labels:?}");
    assert!(!labels.iter().any(|l| l.contains("lineage")), "{labels:?}");
    let lineage = gpu.download_lineage(ctx_p).unwrap();
    let (ctx_a, gpu_a, _) = plain.gpu_parts().unwrap();
    assert_eq!(gpu_a.download_lineage(ctx_a).unwrap(), lineage);
}

/// Fused against staged at a high survival rate (most targets bisect below max_beta): the same
/// β bit for bit, and the same particles.
fn survival_beta_matches_the_staged_step(ctx: &pf_gpu::GpuContext, targets: usize) {
    let shape = BatchShape::new(targets, 40, 3).unwrap();
    let mut config = BatchConfig::new(shape, 23, vec![0.1; 3]);
    config.annealing = Annealing::survival(3, 0.95, 0.7);
    let case = Case {
        config,
        stratified: true,
        propagates: false,
    };
    let mut fused = gpu_filter(ctx, &case, StepLayout::Fused);
    let mut staged = gpu_filter(ctx, &case, StepLayout::Staged);
    for frame in 1..=FRAMES {
        let z = observations(targets, frame);
        let a = fused.step(&z).unwrap();
        let b = staged.step(&z).unwrap();
        let bits = |beta: &[f32]| beta.iter().map(|b| b.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&a.beta), bits(&b.beta), "frame {frame}");
        assert!(a.beta.iter().all(|b| *b > 0.0 && *b <= 1.0), "{:?}", a.beta);
        let bisected = a.beta.iter().filter(|b| **b < 1.0).count();
        assert!(bisected * 2 > targets, "{bisected} of {targets} bisected");
        let (_, fa, _) = fused.gpu_parts().unwrap();
        let states_a = fa.download_states(ctx).unwrap();
        let (_, fb, _) = staged.gpu_parts().unwrap();
        let states_b = fb.download_states(ctx).unwrap();
        // The same β and the same random numbers: the same particles, bit for bit.
        assert_eq!(bits(&states_a), bits(&states_b), "frame {frame}");
    }
}

/// The survival rule's β at a high survival rate, fused against staged, for one, three and 300
/// targets.
#[test]
fn a_bisected_survival_beta_is_the_staged_steps_bit_for_bit() {
    let Some(ctx) = common::gpu_context("survival β fused against staged") else {
        return;
    };
    for targets in [1, 3, 300] {
        survival_beta_matches_the_staged_step(&ctx, targets);
    }
}

/// The labels of the last profiled step's dispatches.
fn dispatch_labels(gpu: &pf_gpu::GpuFilter, ctx: &pf_gpu::GpuContext) -> Vec<String> {
    (gpu.dispatch_times(ctx).unwrap().into_iter())
        .map(|d| d.label)
        .collect()
}
