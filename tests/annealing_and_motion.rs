//! Annealed particle filtering (`pf_core::anneal`) and the constant-velocity drift
//! (`pf_core::batch::Motion`) in the engine, CPU twin and GPU driver alike.
//!
//! The problem: targets in 12 dimensions that move 0.1 per dimension and frame (a random walk of
//! σ = 0.1 is the filter's only model of it), seen through a sharp Gaussian (σ = 0.03 per
//! dimension). One round of 500 random-walk samples per frame is too thin to find the peak again
//! in 12-D; eight layers whose noise shrinks (×0.7 a layer) and whose exponent keeps 30 % of the
//! particles effective walk the cloud into it every frame. The test asserts both
//! sides of that (plain fails, annealing succeeds) on the CPU and on the GPU, and that the two
//! engines take the same annealed steps. The targets move in straight lines, so a
//! constant-velocity drift predicts them: with it even one layer keeps them.

mod common;

use bytemuck::{Pod, Zeroable};
use pf_core::anneal::Annealing;
use pf_core::batch::{BatchConfig, BatchFilter, BatchShape, Motion, gaussian_clouds};
use pf_core::plugin::CpuModel;
use pf_core::resample::Systematic;
use pf_gpu::GpuResampler;
use pf_gpu::model::{ModelFilter, ModelSource};

const DIMS: usize = 12;
const TARGETS: usize = 4;
const PARTICLES: usize = 500;
const FRAMES: usize = 10;
const START_SIGMA: f32 = 0.1;
/// The targets' motion per dimension and frame.
const SPEED: f32 = 0.1;

const MODEL: ModelSource = ModelSource {
    name: "12-D Gaussian observation",
    wgsl: "
struct Observation { z: array<f32, 12> }
struct Constants { sigma: f32 }
fn log_likelihood(x: State, o: Observation, c: Constants) -> f32 {
    var z = o.z;
    var sum = 0.0;
    for (var d = 0u; d < 12u; d++) {
        let e = (x[d] - z[d]) / c.sigma;
        sum += e * e;
    }
    return -0.5 * sum;
}",
};

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Observed {
    z: [f32; DIMS],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Constants {
    sigma: f32,
}

const CONSTANTS: Constants = Constants { sigma: 0.03 };

struct Gaussian12;
impl CpuModel<Observed, Constants> for Gaussian12 {
    fn log_likelihood(&self, x: &[f32], o: &Observed, c: &Constants) -> f32 {
        -0.5 * x
            .iter()
            .zip(&o.z)
            .map(|(a, b)| ((a - b) / c.sigma).powi(2))
            .sum::<f32>()
    }
}

/// Target t's true state at `frame`: a straight line, ±`SPEED` per dimension and frame.
fn truth(t: usize, frame: usize) -> Observed {
    Observed {
        z: std::array::from_fn(|d| {
            let phase = (t * DIMS + d) as f32 * 0.37;
            phase.sin() + SPEED * frame as f32 * phase.cos().signum()
        }),
    }
}

fn observed(frame: usize) -> Vec<Observed> {
    (0..TARGETS).map(|t| truth(t, frame)).collect()
}

fn config(annealing: Annealing) -> BatchConfig {
    let mut config = BatchConfig::new(
        BatchShape::new(TARGETS, PARTICLES, DIMS).unwrap(),
        11,
        vec![SPEED; DIMS],
    );
    config.annealing = annealing;
    config
}

/// The CPU twin over the shared starting cloud.
fn cpu_filter(config: &BatchConfig) -> BatchFilter<Systematic> {
    BatchFilter::new(config, Systematic, start(config)).unwrap()
}

/// The GPU driver with the WGSL model over the same starting cloud.
fn gpu_filter(ctx: &pf_gpu::GpuContext, config: &BatchConfig) -> ModelFilter<Observed, Constants> {
    let states = start(config);
    ModelFilter::new(
        ctx,
        config,
        GpuResampler::Systematic,
        &states,
        MODEL,
        &CONSTANTS,
    )
    .unwrap()
}

fn annealed() -> Annealing {
    Annealing::survival(8, 0.3, 0.7)
}

fn start(config: &BatchConfig) -> Vec<f32> {
    let means: Vec<f32> = (0..TARGETS).flat_map(|t| truth(t, 0).z).collect();
    gaussian_clouds(&config.shape, 3, &means, &[START_SIGMA; DIMS])
}

/// The mean over targets of the distance of the estimates from the truths at `frame`.
fn error(estimates: &[f32], frame: usize) -> f32 {
    let distance = |t: usize| {
        let z = truth(t, frame).z;
        (0..DIMS)
            .map(|d| (estimates[t * DIMS + d] - z[d]).powi(2))
            .sum::<f32>()
            .sqrt()
    };
    (0..TARGETS).map(distance).sum::<f32>() / TARGETS as f32
}

/// The mean error over the second half of the frames.
fn second_half(errors: &[f32]) -> f32 {
    errors[FRAMES / 2..].iter().sum::<f32>() / (FRAMES - FRAMES / 2) as f32
}

fn cpu_error(annealing: Annealing) -> f32 {
    cpu_error_with(config(annealing))
}

fn cpu_error_with(config: BatchConfig) -> f32 {
    let mut filter = cpu_filter(&config);
    let errors: Vec<f32> = (1..=FRAMES)
        .map(|frame| {
            let report = filter.step_model(&Gaussian12, &observed(frame), &CONSTANTS);
            error(&report.unwrap().estimates, frame)
        })
        .collect();
    second_half(&errors)
}

fn gpu_error(ctx: &pf_gpu::GpuContext, annealing: Annealing) -> f32 {
    gpu_error_with(ctx, config(annealing))
}

fn gpu_error_with(ctx: &pf_gpu::GpuContext, config: BatchConfig) -> f32 {
    let mut filter = gpu_filter(ctx, &config);
    let errors: Vec<f32> = (1..=FRAMES)
        .map(|frame| {
            let report = filter.step(&observed(frame)).unwrap();
            error(&report.estimates, frame)
        })
        .collect();
    second_half(&errors)
}

/// Plain Condensation's error stays several times the observation's σ·√D (0.10): it loses the
/// targets; annealing's comes within it. Measured (mean over frames 6–10): plain 0.84, annealed
/// 0.08 on both engines.
fn assert_annealing_wins(engine: &str, plain: f32, annealed: f32) {
    eprintln!("{engine}: plain {plain:.3}, annealed {annealed:.3}");
    let sharp = CONSTANTS.sigma * (DIMS as f32).sqrt();
    assert!(
        plain > 2.0 * sharp,
        "{engine}: plain Condensation found the peak ({plain})"
    );
    assert!(
        annealed < sharp,
        "{engine}: annealing did not find the peak ({annealed})"
    );
    assert!(annealed < 0.3 * plain, "{engine}: {annealed} vs {plain}");
}

#[test]
fn annealing_finds_a_sharp_peak_in_twelve_dimensions_where_plain_condensation_does_not() {
    assert_annealing_wins("CPU", cpu_error(Annealing::none()), cpu_error(annealed()));
    let Some(ctx) = common::gpu_context("annealing finds a sharp peak on the GPU") else {
        return;
    };
    assert_annealing_wins(
        "GPU",
        gpu_error(&ctx, Annealing::none()),
        gpu_error(&ctx, annealed()),
    );
}

#[test]
fn a_fixed_schedule_runs_its_betas() {
    let Some(ctx) = common::gpu_context("a fixed schedule runs its betas") else {
        return;
    };
    let betas = vec![0.05, 0.2, 0.5];
    let config = config(Annealing {
        layers: 3,
        tempering: pf_core::anneal::Tempering::Fixed(betas.clone()),
        sigma_decay: 0.5,
        diffused: Vec::new(),
    });
    let mut cpu = cpu_filter(&config);
    let report = cpu
        .step_model(&Gaussian12, &observed(1), &CONSTANTS)
        .unwrap();
    assert_eq!(report.beta, vec![0.5; TARGETS]);
    assert_eq!(report.resampled, vec![true; TARGETS]);
    let mut gpu = gpu_filter(&ctx, &config);
    let report = gpu.step(&observed(1)).unwrap();
    assert_eq!(report.beta, vec![0.5; TARGETS]);
    assert_eq!(report.resampled, vec![true; TARGETS]);
}

/// A whole annealed step (four layers) on both engines from the same particles: the same β per
/// target and the same estimates (resampling flips near a CDF boundary are allowed by the
/// tolerance policy; at these sizes none moved an estimate by more than the bound).
#[test]
fn annealed_step_matches_cpu() {
    let Some(ctx) = common::gpu_context("annealed step matches the CPU") else {
        return;
    };
    let config = config(Annealing::survival(4, 0.4, 0.7));
    let mut cpu = cpu_filter(&config);
    let mut gpu = gpu_filter(&ctx, &config);
    for frame in 1..=2 {
        let a = cpu
            .step_model(&Gaussian12, &observed(frame), &CONSTANTS)
            .unwrap();
        let b = gpu.step(&observed(frame)).unwrap();
        for t in 0..TARGETS {
            let (cb, gb) = (a.beta[t], b.beta[t]);
            assert!(
                (cb - gb).abs() <= 1e-2 * cb,
                "frame {frame} target {t}: beta CPU {cb} vs GPU {gb}"
            );
        }
        for (i, (x, y)) in a.estimates.iter().zip(&b.estimates).enumerate() {
            assert!(
                (x - y).abs() <= 2e-3,
                "frame {frame} value {i}: CPU {x} vs GPU {y}"
            );
        }
    }
}

fn constant_velocity(annealing: Annealing) -> BatchConfig {
    let mut config = config(annealing);
    config.motion = Motion::ConstantVelocity { gain: 1.0 };
    config
}

/// The drift predicts the straight-line targets: with one layer it keeps most of what the random
/// walk loses, and with annealing it halves the error again. Measured (mean over frames 6–10):
/// one layer 0.84 (random walk) and 0.39 (constant velocity); eight layers 0.08 and 0.04, on both
/// engines.
#[test]
fn a_constant_velocity_drift_follows_straight_line_targets() {
    let check = |engine: &str, errors: [f32; 4]| {
        let [walk, drift, annealed_walk, annealed_drift] = errors;
        eprintln!(
            "{engine}: one layer {walk:.3} / {drift:.3}, annealed {annealed_walk:.3} / {annealed_drift:.3} (random walk / constant velocity)"
        );
        assert!(drift < 0.6 * walk, "{engine}: {drift} vs {walk}");
        assert!(
            annealed_drift < 0.8 * annealed_walk,
            "{engine}: {annealed_drift} vs {annealed_walk}"
        );
    };
    check(
        "CPU",
        [
            cpu_error(Annealing::none()),
            cpu_error_with(constant_velocity(Annealing::none())),
            cpu_error(annealed()),
            cpu_error_with(constant_velocity(annealed())),
        ],
    );
    let Some(ctx) = common::gpu_context("constant velocity on the GPU") else {
        return;
    };
    check(
        "GPU",
        [
            gpu_error(&ctx, Annealing::none()),
            gpu_error_with(&ctx, constant_velocity(Annealing::none())),
            gpu_error(&ctx, annealed()),
            gpu_error_with(&ctx, constant_velocity(annealed())),
        ],
    );
}

/// The drift on both engines from the same particles, three frames (the third is the first
/// that drifts), a target reset in between: the same estimates; a bad gain is refused.
#[test]
fn constant_velocity_matches_cpu_and_resets_with_its_target() {
    let Some(ctx) = common::gpu_context("constant velocity matches the CPU") else {
        return;
    };
    let config = constant_velocity(Annealing::none());
    let mut cpu = cpu_filter(&config);
    let mut gpu = gpu_filter(&ctx, &config);
    let compare = |frame: usize,
                   cpu: &mut BatchFilter<Systematic>,
                   gpu: &mut ModelFilter<Observed, Constants>| {
        let a = cpu
            .step_model(&Gaussian12, &observed(frame), &CONSTANTS)
            .unwrap();
        let b = gpu.step(&observed(frame)).unwrap();
        for (i, (x, y)) in a.estimates.iter().zip(&b.estimates).enumerate() {
            assert!(
                (x - y).abs() <= 2e-3,
                "frame {frame} value {i}: CPU {x} vs GPU {y}"
            );
        }
    };
    compare(1, &mut cpu, &mut gpu);
    compare(2, &mut cpu, &mut gpu);
    compare(3, &mut cpu, &mut gpu);
    // Target 0 restarts from its frame-3 cloud: no drift until it has two estimates again.
    let block: Vec<f32> = cpu.states[..DIMS * PARTICLES].to_vec();
    cpu.reset_target(0, &block).unwrap();
    gpu.reset_target(0, &block).unwrap();
    compare(4, &mut cpu, &mut gpu);
    compare(5, &mut cpu, &mut gpu);

    let mut bad = constant_velocity(Annealing::none());
    bad.motion = Motion::ConstantVelocity { gain: 1.5 };
    assert!(bad.validate().unwrap_err().to_string().contains("gain"));
    bad.motion = Motion::ConstantVelocity { gain: f32::NAN };
    assert!(bad.validate().is_err());
}

/// A target restarted on something already seen moving (`set_target_motion`: as if its last
/// two estimates had been `estimate − motion` and `estimate`) drifts by gain · motion in its very
/// next step, on both engines alike (gain 0.5, one angular value), where a plain restart stays
/// put a step; an angle's motion counts wrapped, the random walk ignores the call, a NaN
/// estimate (no earlier one) is taken, and bad motions are refused with an error.
#[test]
fn a_restarted_target_set_moving_drifts_in_its_next_step_on_both_engines() {
    const GAIN: f32 = 0.5;
    let mut config = config(Annealing::none());
    config.motion = Motion::ConstantVelocity { gain: GAIN };
    config.angular[0] = true;
    // Twice the truth's step: the drift (half of it) is the step.
    let motion: Vec<f32> = (0..DIMS)
        .map(|d| (truth(0, 4).z[d] - truth(0, 3).z[d]) / GAIN)
        .collect();
    let estimate = truth(0, 3).z;
    let block = gaussian_clouds(
        &BatchShape::new(1, PARTICLES, DIMS).unwrap(),
        5,
        &estimate,
        &[START_SIGMA; DIMS],
    );
    // Target 0 restarted at frame 3's truth (set moving by `motion`, if any), then frame 4.
    let step_after_restart = |config: &BatchConfig, motion: Option<&[f32]>| {
        let mut cpu = cpu_filter(config);
        for frame in 1..=3 {
            cpu.step_model(&Gaussian12, &observed(frame), &CONSTANTS)
                .unwrap();
        }
        cpu.reset_target(0, &block).unwrap();
        if let Some(motion) = motion {
            cpu.set_target_motion(0, &estimate, motion).unwrap();
        }
        let report = cpu
            .step_model(&Gaussian12, &observed(4), &CONSTANTS)
            .unwrap();
        (cpu, report.estimates)
    };
    let target_error = |estimates: &[f32]| {
        let z = truth(0, 4).z;
        (0..DIMS)
            .map(|d| (estimates[d] - z[d]).powi(2))
            .sum::<f32>()
            .sqrt()
    };
    let (_, at_rest) = step_after_restart(&config, None);
    let (mut cpu, moving) = step_after_restart(&config, Some(&motion));
    let (rest_error, moving_error) = (target_error(&at_rest), target_error(&moving));
    assert!(
        moving_error < 0.75 * rest_error,
        "set moving: {moving_error}, at rest: {rest_error}"
    );
    // The angle's motion a turn larger drifts the same.
    let mut turned = motion.clone();
    turned[0] += std::f32::consts::TAU;
    let (_, turned_estimates) = step_after_restart(&config, Some(&turned));
    for (x, y) in moving.iter().zip(&turned_estimates) {
        assert!((x - y).abs() <= 1e-4, "{x} vs {y} a turn apart");
    }
    // The random walk ignores it.
    let mut walk = config.clone();
    walk.motion = Motion::RandomWalk;
    assert_eq!(
        step_after_restart(&walk, Some(&motion)).1,
        step_after_restart(&walk, None).1
    );
    let shape = &config.shape;
    let mut unknown = estimate;
    unknown[1] = f32::NAN;
    assert!(cpu.set_target_motion(0, &unknown, &motion).is_ok());
    for (t, e, m) in [
        (TARGETS, estimate.to_vec(), motion.clone()),
        (0, estimate[..3].to_vec(), motion.clone()),
        (0, estimate.to_vec(), vec![f32::NAN; DIMS]),
        (0, vec![f32::INFINITY; DIMS], motion.clone()),
    ] {
        assert!(pf_core::batch::check_target_motion(shape, t, &e, &m).is_err());
        assert!(cpu.set_target_motion(t, &e, &m).is_err());
    }

    let Some(ctx) = common::gpu_context("a target set moving on the GPU") else {
        return;
    };
    let mut gpu = gpu_filter(&ctx, &config);
    for frame in 1..=3 {
        gpu.step(&observed(frame)).unwrap();
    }
    gpu.reset_target(0, &block).unwrap();
    gpu.set_target_motion(0, &estimate, &turned).unwrap();
    let on_gpu = gpu.step(&observed(4)).unwrap();
    for (i, (x, y)) in moving.iter().zip(&on_gpu.estimates).enumerate() {
        assert!((x - y).abs() <= 2e-3, "value {i}: CPU {x} vs GPU {y}");
    }
    assert!(gpu.set_target_motion(TARGETS, &estimate, &motion).is_err());
    assert!(
        gpu.set_target_motion(0, &estimate, &[f32::INFINITY; DIMS])
            .is_err()
    );
}

/// Whether every particle's values in `still` dimensions are, exactly, some particle's values
/// before the step (resampling copies whole particles; a layer that does not diffuse a dimension
/// leaves it as it was), for every target. States are `[(t·D + d)·M + m]`.
fn only_partition_moved(before: &[f32], after: &[f32], still: &[usize]) -> bool {
    (0..TARGETS).all(|t| {
        let value = |states: &[f32], d: usize, m: usize| states[(t * DIMS + d) * PARTICLES + m];
        (0..PARTICLES).all(|m| {
            (0..PARTICLES).any(|a| {
                still
                    .iter()
                    .all(|&d| value(after, d, m) == value(before, d, a))
            })
        })
    })
}

/// Partitioned sampling (`Annealing::diffused`): a layer moves only its own dimensions, on the
/// CPU twin and on the GPU alike (the others are copies of the particles before, bit for bit),
/// it does move those, and the two engines take the same partitioned annealed steps.
#[test]
fn a_partitioned_layer_moves_only_its_dimensions_on_both_engines() {
    let moved = vec![0, 3, 5];
    let still: Vec<usize> = (0..DIMS).filter(|d| !moved.contains(d)).collect();
    let one_layer = config(Annealing::none().partitioned(vec![moved.clone()]));
    let mut cpu = cpu_filter(&one_layer);
    let before = cpu.states.clone();
    cpu.step_model(&Gaussian12, &observed(1), &CONSTANTS)
        .unwrap();
    assert!(only_partition_moved(&before, &cpu.states, &still), "CPU");
    assert!(
        !only_partition_moved(&before, &cpu.states, &moved),
        "CPU: the partition did not move"
    );
    let Some(ctx) = common::gpu_context("partitioned sampling on the GPU") else {
        return;
    };
    let mut gpu = gpu_filter(&ctx, &one_layer);
    let before = gpu.particles().unwrap().0;
    gpu.step(&observed(1)).unwrap();
    let after = gpu.particles().unwrap().0;
    assert!(only_partition_moved(&before, &after, &still), "GPU");
    assert!(
        !only_partition_moved(&before, &after, &moved),
        "GPU: the partition did not move"
    );
    // Four layers: the first half of the dimensions, then the second half.
    let halves = [(0..6).collect::<Vec<_>>(), (6..DIMS).collect()];
    let schedule = Annealing::survival(4, 0.4, 0.7).partitioned(vec![
        halves[0].clone(),
        halves[0].clone(),
        halves[1].clone(),
        halves[1].clone(),
    ]);
    let config = config(schedule);
    // One step from the same particles: the same β and estimates to f32 rounding (measured: at
    // most 1.2e-7). A second step may part ways where the β bisection's f32 and f64 sums differ
    // in the last bits and resampling flips a draw (the tolerance policy), so it is not compared.
    let mut cpu = cpu_filter(&config);
    let mut gpu = gpu_filter(&ctx, &config);
    let a = cpu
        .step_model(&Gaussian12, &observed(1), &CONSTANTS)
        .unwrap();
    let b = gpu.step(&observed(1)).unwrap();
    for t in 0..TARGETS {
        let (cb, gb) = (a.beta[t], b.beta[t]);
        assert!(
            (cb - gb).abs() <= 1e-3 * cb,
            "target {t}: beta CPU {cb} vs GPU {gb}"
        );
    }
    for (i, (x, y)) in a.estimates.iter().zip(&b.estimates).enumerate() {
        assert!((x - y).abs() <= 1e-5, "value {i}: CPU {x} vs GPU {y}");
    }
    // A partition naming a dimension the state lacks is refused by both engines.
    let bad = config_with_partition(vec![vec![DIMS]]);
    assert!(BatchFilter::new(&bad, Systematic, start(&bad)).is_err());
    assert!(pf_gpu::GpuFilter::new(&ctx, &bad, GpuResampler::Systematic, &start(&bad)).is_err());
}

fn config_with_partition(diffused: Vec<Vec<usize>>) -> BatchConfig {
    config(Annealing::none().partitioned(diffused))
}
