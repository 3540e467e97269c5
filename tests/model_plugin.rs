//! The model plug-in (`pf_gpu::model`): a WGSL model against its CPU twin through the public
//! helper, the range-only example's tracking error on the GPU and the CPU, and the typed errors
//! of bad models.
//!
//! The example's bound. Eight targets, 1000 particles, three beacons 20 m apart measuring range
//! with σ = 0.2 m: the mean position error over the last half of 40 frames measured about
//! 0.1 m on both paths (see the test's output); the test asks for at most 0.35 m, under two
//! range σ, and that both paths are there.

mod common;

#[path = "../examples/range_only.rs"]
mod range_only;

use pf_core::batch::BatchShape;
use pf_gpu::GpuError;
use pf_gpu::model::{CheckInputs, ModelSource, WgslModel, check_against_cpu};
use proptest::prelude::*;
use range_only::{CONSTANTS, MODEL, RangeOnly, Ranges};

const MAX_ERROR_M: f32 = 0.35;

#[test]
fn range_only_example_tracks_on_gpu_and_cpu() {
    let Some(ctx) = common::gpu_context("range_only_example_tracks_on_gpu_and_cpu") else {
        return;
    };
    let (gpu, cpu) = range_only::run(Some(&ctx), 8, 40).unwrap();
    let gpu = gpu.expect("the GPU path ran");
    eprintln!("range-only: GPU {gpu:.3} m, CPU {cpu:.3} m");
    assert!(gpu <= MAX_ERROR_M, "GPU error {gpu} m");
    assert!(cpu <= MAX_ERROR_M, "CPU error {cpu} m");
}

/// Particle values: ordinary, on a beacon (range 0), huge, and exactly zero velocity.
fn value() -> impl Strategy<Value = f32> {
    prop_oneof![
        6 => -30.0f32..50.0,
        1 => Just(0.0f32),
        1 => Just(20.0f32),
        1 => prop_oneof![Just(1e6f32), Just(-1e6f32)],
    ]
}

fn inputs() -> impl Strategy<Value = (usize, usize, Vec<f32>, Vec<Ranges>)> {
    (1usize..4, 1usize..200).prop_flat_map(|(targets, particles)| {
        (
            Just(targets),
            Just(particles),
            prop::collection::vec(value(), targets * particles * 4),
            prop::collection::vec(
                prop::array::uniform3(0.0f32..60.0).prop_map(|r| Ranges { r }),
                targets,
            ),
        )
    })
}

proptest! {
    #![proptest_config(common::property::config(12))]

    #[test]
    fn range_only_model_matches_cpu_within_tolerance((targets, particles, states, observed) in inputs()) {
        let Some(ctx) = common::gpu_context("range_only_model_matches_cpu_within_tolerance") else {
            return Ok(());
        };
        let check = check_against_cpu(
            &ctx,
            MODEL,
            &RangeOnly,
            &CheckInputs {
                shape: BatchShape::new(targets, particles, 4).unwrap(),
                states: &states,
                observations: &observed,
                constants: &CONSTANTS,
                angular: &[false; 4],
                seed: 5,
            },
        )
        .unwrap();
        prop_assert!(check.checked_propagate);
        prop_assert!(check.passed(), "{check}");
    }
}

fn build(
    ctx: &pf_gpu::GpuContext,
    wgsl: &str,
) -> Result<WgslModel<Ranges, range_only::Constants>, GpuError> {
    WgslModel::new(
        ctx,
        ModelSource { name: "bad", wgsl },
        &BatchShape::new(2, 8, 4).unwrap(),
        &CONSTANTS,
    )
}

#[test]
fn bad_models_are_typed_errors_with_the_users_line() {
    let Some(ctx) = common::gpu_context("bad_models_are_typed_errors_with_the_users_line") else {
        return;
    };
    let structs = "struct Observation { r: array<f32, 3> }\n\
                   struct Constants { beacons: array<f32, 6>, dt: f32, accel: f32, range_sigma: f32 }\n";
    // A syntax error on the user's line 4.
    let err = build(&ctx, &format!("{structs}\nfn log_likelihood(x: State, z: Observation, c: Constants) -> f32 {{ return x[0] +; }}"))
        .err()
        .expect("a syntax error");
    let GpuError::Shader { message, .. } = &err else {
        panic!("{err}")
    };
    assert!(message.contains("bad:4:"), "{message}");
    // A type error on line 3.
    let err = build(&ctx, &format!("{structs}fn log_likelihood(x: State, z: Observation, c: Constants) -> f32 {{ let k: u32 = x[0]; return 0.0; }}"))
        .err()
        .expect("a type error");
    assert!(err.to_string().contains("bad:3:"), "{err}");
    // No log_likelihood.
    let err = build(&ctx, structs).err().expect("no likelihood");
    assert!(
        err.to_string().contains("must define fn log_likelihood"),
        "{err}"
    );
    // An Observation whose WGSL layout is not the Rust type's (16 bytes against 12).
    let err = build(&ctx, "struct Observation { r: vec4<f32> }\n\
                           struct Constants { beacons: array<f32, 6>, dt: f32, accel: f32, range_sigma: f32 }\n\
                           fn log_likelihood(x: State, z: Observation, c: Constants) -> f32 { return z.r.x; }")
        .err()
        .expect("a layout mismatch");
    assert!(
        err.to_string()
            .contains("struct Observation is 16 bytes in WGSL"),
        "{err}"
    );
    // A wrong signature is reported in the generated code, with the expected signatures.
    let err = build(
        &ctx,
        &format!("{structs}fn log_likelihood(x: State) -> f32 {{ return x[0]; }}"),
    )
    .err()
    .expect("a wrong signature");
    assert!(
        err.to_string()
            .contains("log_likelihood(x: State, z: Observation, c: Constants)"),
        "{err}"
    );
    // Observations: one per target.
    let model = build(&ctx, MODEL.wgsl).unwrap();
    let err = model
        .set_observations(&ctx, &[Ranges { r: [1.0; 3] }])
        .unwrap_err();
    assert!(
        matches!(
            err,
            GpuError::LengthMismatch {
                expected: 2,
                got: 1,
                ..
            }
        ),
        "{err}"
    );
}

#[test]
fn a_likelihood_that_was_never_prepared_is_an_error_not_stale_weights() {
    let Some(ctx) = common::gpu_context("never prepared") else {
        return;
    };
    let shape = BatchShape::new(2, 8, 4).unwrap();
    let config = pf_core::batch::BatchConfig {
        shape,
        seed: 1,
        sigma: vec![0.1; 4],
        bounds: None,
        angular: vec![false; 4],
        ess_threshold: f64::INFINITY,
        best: 0,
        annealing: Default::default(),
        motion: Default::default(),
    };
    let mut filter = pf_gpu::GpuFilter::new(
        &ctx,
        &config,
        pf_gpu::GpuResampler::Systematic,
        &vec![0.0; shape.state_len()],
    )
    .unwrap();
    let model = build(&ctx, MODEL.wgsl).unwrap();
    let err = filter.step(&ctx, &model).unwrap_err();
    assert!(err.to_string().contains("prepare"), "{err}");
}

/// The helper must catch a twin that disagrees: here one whose dynamics forget the velocity.
struct WrongTwin;

impl pf_core::plugin::CpuModel<Ranges, range_only::Constants> for WrongTwin {
    const PROPAGATES: bool = true;

    fn log_likelihood(&self, x: &[f32], z: &Ranges, c: &range_only::Constants) -> f32 {
        pf_core::plugin::CpuModel::log_likelihood(&RangeOnly, x, z, c)
    }

    fn propagate(&self, x: &[f32], _: &[f32], _: &range_only::Constants, next: &mut [f32]) {
        next.copy_from_slice(x);
    }
}

#[test]
fn the_check_reports_a_twin_that_disagrees() {
    let Some(ctx) = common::gpu_context("the_check_reports_a_twin_that_disagrees") else {
        return;
    };
    let shape = BatchShape::new(2, 16, 4).unwrap();
    let states: Vec<f32> = (0..shape.state_len())
        .map(|i| (i % 13) as f32 - 3.0)
        .collect();
    let observed = [Ranges { r: [5.0, 6.0, 7.0] }; 2];
    let check = check_against_cpu(
        &ctx,
        MODEL,
        &WrongTwin,
        &CheckInputs {
            shape,
            states: &states,
            observations: &observed,
            constants: &CONSTANTS,
            angular: &[false; 4],
            seed: 5,
        },
    )
    .unwrap();
    assert!(!check.passed());
    assert!(
        check
            .mismatches
            .iter()
            .all(|m| m.what.starts_with("propagate")),
        "{check}"
    );
}

proptest! {
    #![proptest_config(common::property::config(8))]

    /// The toy model through the plug-in against its twin, angles wrapped the short way round.
    #[test]
    fn toy_model_matches_cpu_within_tolerance(
        (targets, particles) in (1usize..5, 1usize..300),
        seed in any::<u64>(),
    ) {
        let Some(ctx) = common::gpu_context("toy_model_matches_cpu_within_tolerance") else {
            return Ok(());
        };
        use pf_gpu::toy::{TOY_MODEL, ToyConstants, ToyObservation, ToyTwin};
        let shape = BatchShape::new(targets, particles, 7).unwrap();
        let mut rng = pf_core::RandomStreams::new(seed).stream(0, pf_core::Stage::Model(0));
        let states: Vec<f32> = (0..shape.state_len()).map(|_| 10.0 * rng.gaussian_f32()).collect();
        let observations: Vec<ToyObservation> = (0..targets)
            .map(|_| ToyObservation { z: std::array::from_fn(|_| 10.0 * rng.gaussian_f32()) })
            .collect();
        let angular = [false, false, false, true, true, true, false];
        let constants = ToyConstants::from_sigma(&[4.0, 4.0, 0.5, 0.1, 0.1, 0.1, 0.5]).unwrap();
        let check = check_against_cpu(
            &ctx,
            TOY_MODEL,
            &ToyTwin { angular },
            &CheckInputs { shape, states: &states, observations: &observations, constants: &constants, angular: &angular, seed },
        )
        .unwrap();
        prop_assert!(!check.checked_propagate);
        prop_assert!(check.passed(), "{check}");
    }
}
