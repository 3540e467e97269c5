//! Each frame's log evidence in the engine's report, on the CPU and the GPU engines, for a
//! researcher's plug-in model: a linear-Gaussian model (constant velocity, position observed)
//! written in WGSL with its CPU twin, whose exact sequence log-likelihood the Kalman filter gives.
//!
//! - Over many independent filters (the targets of one batch, all given the same observations),
//!   log Ẑ − log Z has mean −Var/2 within four standard errors on either engine: the product of
//!   the frames' evidence estimates is unbiased for Z, so its log is biased by about −Var/2.
//! - The two engines draw the same random numbers: the first frame's evidence agrees target by
//!   target within the tolerance policy.
//! - With annealing the evidence is the first layer's at β = 1, before tempering: the first
//!   frame's is the same as without annealing, on both engines, though the survival rule weighs
//!   that layer with a β below 1.

mod common;

use bytemuck::{Pod, Zeroable};
use pf_core::anneal::Annealing;
use pf_core::batch::{BatchConfig, BatchShape, gaussian_clouds};
use pf_core::plugin::CpuModel;
use pf_core::resample::ResamplerKind;
use pf_core::{RandomStreams, Stage};
use pf_gpu::engine::{EngineReport, Filter};
use pf_gpu::model::{ModelSource, Plugin, agrees};
use pf_gpu::{GpuContext, GpuResampler};

const MODEL: ModelSource = ModelSource {
    name: "constant velocity, position observed",
    wgsl: "
struct Observation { y: f32 }
struct Constants { sigma_p: f32, sigma_v: f32, sigma_r: f32, log_norm: f32 }
fn log_likelihood(x: State, z: Observation, c: Constants) -> f32 {
    let e = (x[0] - z.y) / c.sigma_r;
    return -0.5 * e * e + c.log_norm;
}
fn propagate(x: State, n: State, c: Constants) -> State {
    return State(x[0] + x[1] + c.sigma_p * n[0], x[1] + c.sigma_v * n[1]);
}",
};

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct Position {
    y: f32,
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct Constants {
    sigma_p: f32,
    sigma_v: f32,
    sigma_r: f32,
    /// −log(σ_r·√(2π)): the density's constant, so that the evidence is the true likelihood's.
    log_norm: f32,
}

const SIGMA_P: f64 = 0.3;
const SIGMA_V: f64 = 0.1;
const SIGMA_R: f64 = 0.5;
const FRAMES: usize = 40;
const M0: [f32; 2] = [0.0, 1.0];
const S0: [f32; 2] = [1.0, 0.5];

fn constants() -> Constants {
    Constants {
        sigma_p: SIGMA_P as f32,
        sigma_v: SIGMA_V as f32,
        sigma_r: SIGMA_R as f32,
        log_norm: -(SIGMA_R.ln() + 0.5 * std::f64::consts::TAU.ln()) as f32,
    }
}

struct ConstantVelocity;
impl CpuModel<Position, Constants> for ConstantVelocity {
    const PROPAGATES: bool = true;
    fn log_likelihood(&self, x: &[f32], z: &Position, c: &Constants) -> f32 {
        let e = (x[0] - z.y) / c.sigma_r;
        -0.5 * e * e + c.log_norm
    }
    fn propagate(&self, x: &[f32], n: &[f32], c: &Constants, next: &mut [f32]) {
        next[0] = x[0] + x[1] + c.sigma_p * n[0];
        next[1] = x[1] + c.sigma_v * n[1];
    }
}

fn simulate(seed: u64) -> Vec<f64> {
    let mut rng = RandomStreams::new(seed).stream(0, Stage::Model(0));
    let (mut p, mut v) = (0.0, 1.0);
    (0..FRAMES)
        .map(|_| {
            p += v + SIGMA_P * rng.gaussian();
            v += SIGMA_V * rng.gaussian();
            p + SIGMA_R * rng.gaussian()
        })
        .collect()
}

/// The exact log-likelihood of the observations (Kalman filter, f64).
fn kalman_log_likelihood(ys: &[f64]) -> f64 {
    let (mut m, mut p) = (
        [f64::from(M0[0]), f64::from(M0[1])],
        [[1.0, 0.0], [0.0, 0.25]],
    );
    let mut total = 0.0;
    for &y in ys {
        // Predict: x ← A x + q, A = [[1, 1], [0, 1]].
        m = [m[0] + m[1], m[1]];
        p = [
            [
                p[0][0] + 2.0 * p[0][1] + p[1][1] + SIGMA_P * SIGMA_P,
                p[0][1] + p[1][1],
            ],
            [p[0][1] + p[1][1], p[1][1] + SIGMA_V * SIGMA_V],
        ];
        let s = p[0][0] + SIGMA_R * SIGMA_R;
        let innovation = y - m[0];
        total -= 0.5 * (innovation * innovation / s + s.ln() + std::f64::consts::TAU.ln());
        let k = [p[0][0] / s, p[1][0] / s];
        m = [m[0] + k[0] * innovation, m[1] + k[1] * innovation];
        p = [
            [p[0][0] - k[0] * p[0][0], p[0][1] - k[0] * p[0][1]],
            [p[1][0] - k[1] * p[0][0], p[1][1] - k[1] * p[0][1]],
        ];
    }
    total
}

fn config(filters: usize, particles: usize, seed: u64) -> BatchConfig {
    BatchConfig::new(
        BatchShape::new(filters, particles, 2).unwrap(),
        seed,
        vec![0.0; 2],
    )
}

fn start(config: &BatchConfig) -> Vec<f32> {
    let means: Vec<f32> = (0..config.shape.targets).flat_map(|_| M0).collect();
    gaussian_clouds(&config.shape, config.seed, &means, &S0)
}

type Model = Plugin<Position, Constants, ConstantVelocity>;

fn on_cpu(config: &BatchConfig) -> Filter<Model> {
    let model = Plugin::cpu(ConstantVelocity, constants());
    Filter::on_cpu(config, ResamplerKind::Systematic, start(config), model).unwrap()
}

fn on_gpu(ctx: &GpuContext, config: &BatchConfig) -> Filter<Model> {
    let model = Plugin::gpu(ctx, MODEL, &config.shape, ConstantVelocity, constants()).unwrap();
    Filter::on_gpu(
        ctx.clone(),
        config,
        GpuResampler::Systematic,
        &start(config),
        model,
    )
    .unwrap()
}

fn frame(filter: &mut Filter<Model>, y: f64) -> EngineReport {
    let targets = filter.shape().targets;
    let report = filter
        .step(&vec![Position { y: y as f32 }; targets])
        .unwrap();
    assert!(
        report.status.iter().all(Result::is_ok),
        "{:?}",
        report.status
    );
    report
}

/// Every frame's log evidence, `[frame][target]`.
fn evidence(filter: &mut Filter<Model>, ys: &[f64]) -> Vec<Vec<f64>> {
    ys.iter().map(|&y| frame(filter, y).log_evidence).collect()
}

/// Each filter's log Ẑ − log Z over the whole sequence.
fn errors(evidence: &[Vec<f64>], ys: &[f64]) -> Vec<f64> {
    let log_z = kalman_log_likelihood(ys);
    (0..evidence[0].len())
        .map(|t| evidence.iter().map(|frame| frame[t]).sum::<f64>() - log_z)
        .collect()
}

fn assert_unbiased_likelihood(engine: &str, deltas: &[f64]) {
    let n = deltas.len() as f64;
    let mean = deltas.iter().sum::<f64>() / n;
    let var = deltas.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / (n - 1.0);
    let (expected, standard_error) = (-0.5 * var, (var / n).sqrt());
    eprintln!("{engine}: log Ẑ − log Z = {mean:.4} ± {:.4}", var.sqrt());
    assert!(
        (mean - expected).abs() <= 4.0 * standard_error,
        "{engine}: mean error {mean:.4}, expected −Var/2 = {expected:.4} within four standard errors ({standard_error:.4})"
    );
}

#[test]
fn the_log_evidence_sums_to_the_kalman_log_likelihood_on_both_engines() {
    let Some(ctx) = common::gpu_context("log evidence against the Kalman filter") else {
        return;
    };
    let ys = simulate(5);
    let config = config(160, 1000, 21);
    let gpu = evidence(&mut on_gpu(&ctx, &config), &ys);
    let cpu = evidence(&mut on_cpu(&config), &ys);
    // The first frame, target by target: the same random numbers on both engines.
    for (t, (&g, &c)) in gpu[0].iter().zip(&cpu[0]).enumerate() {
        assert!(agrees(g, c), "target {t}: GPU {g} vs CPU {c}");
    }
    assert_unbiased_likelihood("GPU", &errors(&gpu, &ys));
    assert_unbiased_likelihood("CPU", &errors(&cpu, &ys));
}

#[test]
fn with_annealing_the_evidence_is_the_first_layers_before_tempering() {
    let Some(ctx) = common::gpu_context("log evidence with annealing") else {
        return;
    };
    let ys = simulate(6);
    let plain = config(8, 500, 3);
    let mut annealed = plain.clone();
    // The survival rule keeps half the particles effective: β < 1 in the first layer.
    annealed.annealing = Annealing::survival(3, 0.5, 0.5);
    // An observation far from the start makes the first layer's likelihood sharp.
    let y = ys[0] + 3.0;
    let reference = frame(&mut on_cpu(&plain), y);
    // Both weigh the same particles in the first layer; at β = 1 fewer than half would stay
    // effective, so the survival rule chose β < 1 there.
    assert!(
        reference.ess.iter().all(|&e| e < 0.5 * 500.0),
        "{:?}",
        reference.ess
    );
    for (engine, report) in [
        ("CPU", frame(&mut on_cpu(&annealed), y)),
        ("GPU", frame(&mut on_gpu(&ctx, &annealed), y)),
    ] {
        for (t, (&a, &p)) in report
            .log_evidence
            .iter()
            .zip(&reference.log_evidence)
            .enumerate()
        {
            assert!(
                agrees(a, p),
                "{engine} target {t}: annealed {a} vs plain {p}"
            );
        }
    }
}
