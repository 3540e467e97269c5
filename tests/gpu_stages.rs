//! Every GPU stage against its CPU twin, on random inputs (proptest): Philox blocks and Gaussian
//! draws, diffusion, normalisation, the three GPU resamplers, the gather and the weighted mean.
//! Shapes include a single particle, non-powers of two and up to 16 targets. Tolerances follow
//! the tolerance policy (`pf_gpu::model::tolerance`, ARCHITECTURE.md) per term, same ancestors except
//! where a resampling point lies within float rounding of a CDF boundary.

mod common;

use pf_core::batch::{self, BatchConfig, BatchShape};
use pf_core::random::{CounterUniforms, counter_gaussian, philox4x32_10};
use pf_core::resample::{Metropolis, Stratified, Systematic};
use pf_core::{PfError, Resampler, Stage};
use pf_gpu::model::{ABSOLUTE_TOLERANCE, agrees, tolerance};
use pf_gpu::{GpuContext, GpuFilter, GpuResampler, GpuStage, NoLikelihood, TargetStats};
use proptest::prelude::*;
use proptest::test_runner::TestCaseError;

/// Runs `check` over `cases` random cases of `strategy` on one GPU context; a failure panics
/// with the case to pin (`common::property`).
fn property<S>(
    name: &str,
    cases: u32,
    strategy: S,
    check: impl Fn(&GpuContext, S::Value) -> Result<(), TestCaseError>,
) where
    S: Strategy,
    S::Value: std::fmt::Debug,
{
    let Some(ctx) = common::gpu_context(name) else {
        return;
    };
    common::property::check_cases(name, cases, strategy, |value| check(&ctx, value));
}

fn shapes() -> impl Strategy<Value = BatchShape> {
    (
        1usize..=16,
        prop_oneof![Just(1usize), Just(256), Just(1000), 2usize..300],
        1usize..=8,
    )
        .prop_map(|(t, m, d)| BatchShape::new(t, m, d).unwrap())
}

fn config(
    shape: BatchShape,
    angular: Vec<bool>,
    sigma: Vec<f32>,
    bounds: Option<(Vec<f32>, Vec<f32>)>,
) -> BatchConfig {
    BatchConfig {
        shape,
        seed: 5,
        sigma,
        bounds,
        angular,
        ess_threshold: f64::INFINITY,
        best: 0,
        annealing: Default::default(),
        motion: Default::default(),
    }
}

/// The tolerance policy (`pf_gpu::model::agrees`), with `extra` more allowed where a stage's
/// inputs make it wider (the diffusion's σ).
fn close(gpu: f32, cpu: f64, extra: f64) -> bool {
    if cpu.is_nan() {
        return gpu.is_nan();
    }
    agrees(f64::from(gpu), cpu) || (f64::from(gpu) - cpu).abs() <= tolerance(cpu) + extra
}

// ---- counter-based random numbers -------------------------------------------------------------

#[test]
fn philox_blocks_bit_exact_vs_cpu() {
    let strategy = (
        any::<[u32; 2]>(),
        prop::collection::vec(
            prop_oneof![any::<[u32; 4]>(), Just([u32::MAX; 4]), Just([0; 4])],
            1..200,
        ),
    );
    property(
        "philox_blocks_bit_exact_vs_cpu",
        16,
        strategy,
        |ctx: &GpuContext, (key, counters)| {
            let gpu = pf_gpu::random::philox_blocks(ctx, key, &counters).unwrap();
            for (c, g) in counters.iter().zip(&gpu) {
                prop_assert_eq!(*g, philox4x32_10(*c, key));
            }
            Ok(())
        },
    );
}

#[test]
fn gaussian_draws_match_cpu_within_tolerance() {
    property(
        "gaussian_draws_match_cpu_within_tolerance",
        12,
        (any::<[u32; 2]>(), 1u32..2000, 1u32..9, any::<u64>()),
        |ctx: &GpuContext, (key, particles, dims, step)| {
            let gpu = pf_gpu::random::gaussians(ctx, key, particles, dims, step).unwrap();
            for m in 0..particles {
                for d in 0..dims {
                    let cpu = counter_gaussian(key, m, d, step);
                    let g = gpu[(m * dims + d) as usize];
                    prop_assert!(
                        close(g, cpu, 0.0),
                        "m {} d {}: GPU {} vs CPU {}",
                        m,
                        d,
                        g,
                        cpu
                    );
                }
            }
            Ok(())
        },
    );
}

// ---- diffusion ----------------------------------------------------------------------------------

fn state_value() -> impl Strategy<Value = f32> {
    prop_oneof![8 => -10.0f32..10.0, 1 => -1e6f32..1e6, 1 => Just(f32::NAN), 1 => Just(std::f32::consts::PI)]
}

#[test]
fn diffusion_matches_cpu_within_tolerance() {
    let strategy = shapes().prop_flat_map(|shape| {
        let d = shape.dims;
        (
            Just(shape),
            prop::collection::vec(state_value(), shape.state_len()),
            prop::collection::vec(0.0f32..5.0, d),
            prop::collection::vec(any::<bool>(), d),
            any::<bool>(),
            any::<u64>(),
        )
    });
    property(
        "diffusion_matches_cpu_within_tolerance",
        16,
        strategy,
        |ctx: &GpuContext, (shape, states, sigma, angular, bounded, step)| {
            let bounds = bounded.then(|| (vec![-3.0; shape.dims], vec![3.0; shape.dims]));
            let cfg = config(shape, angular.clone(), sigma.clone(), bounds.clone());
            let mut gpu = GpuFilter::new(ctx, &cfg, GpuResampler::Systematic, &states).unwrap();
            gpu.set_step(step);
            gpu.run_stages(ctx, &[GpuStage::Diffuse], &NoLikelihood)
                .unwrap();
            let got = gpu.download_states(ctx).unwrap();
            let mut want = states.clone();
            let keys = batch::stage_keys(5, shape.targets, Stage::Diffusion);
            let b = bounds.as_ref().map(|(l, h)| (l.as_slice(), h.as_slice()));
            batch::diffuse(&shape, &mut want, &sigma, 1.0, b, &angular, &keys, step);
            for t in 0..shape.targets {
                for d in 0..shape.dims {
                    for m in 0..shape.particles {
                        let i = shape.state_index(t, d, m);
                        let (g, c) = (got[i], want[i]);
                        let ok = if c.is_nan() {
                            g.is_nan()
                        } else if angular[d] {
                            // Wrapping keeps the absolute rounding of the unwrapped sum:
                            // a few ulps of |start| (an angle of 941 rad has ulps of 6e-5).
                            batch::wrap_angle_floor(g - c).abs()
                                <= 1e-5 * (1.0 + sigma[d]) + 2.5e-7 * states[i].abs()
                        } else {
                            close(
                                g,
                                f64::from(c),
                                ABSOLUTE_TOLERANCE * f64::from(1.0 + sigma[d]),
                            )
                        };
                        prop_assert!(
                            ok,
                            "t {} d {} m {}: GPU {} vs CPU {} (start {})",
                            t,
                            d,
                            m,
                            g,
                            c,
                            states[i]
                        );
                    }
                }
            }
            Ok(())
        },
    );
}

// ---- normalisation ------------------------------------------------------------------------------

fn log_value() -> impl Strategy<Value = f32> {
    prop_oneof![
        20 => -60.0f32..10.0,
        2 => Just(f32::NEG_INFINITY),
        1 => Just(-1e30f32),
        1 => -1e6f32..1e6,
        1 => Just(f32::NAN),
        1 => Just(f32::INFINITY),
    ]
}

#[test]
fn normalisation_matches_cpu_within_tolerance() {
    let strategy = shapes().prop_flat_map(|shape| {
        let n = shape.particle_len();
        (
            Just(shape),
            prop::collection::vec(log_value(), n),
            prop::collection::vec(log_value(), n),
        )
    });
    property(
        "normalisation_matches_cpu_within_tolerance",
        24,
        strategy,
        |ctx: &GpuContext, (shape, log_weights, log_likelihood)| {
            let cfg = config(shape, vec![false; shape.dims], vec![0.0; shape.dims], None);
            let mut gpu = GpuFilter::new(
                ctx,
                &cfg,
                GpuResampler::Systematic,
                &vec![0.0; shape.state_len()],
            )
            .unwrap();
            gpu.streams().log_weights.upload(ctx, &log_weights).unwrap();
            gpu.streams()
                .log_likelihood
                .upload(ctx, &log_likelihood)
                .unwrap();
            let report = gpu
                .run_stages(ctx, &[GpuStage::Normalise], &NoLikelihood)
                .unwrap();
            let weights = gpu.download_weights(ctx).unwrap();
            let m = shape.particles;
            for t in 0..shape.targets {
                let range = t * m..(t + 1) * m;
                let mut lw = log_weights[range.clone()].to_vec();
                let mut w = vec![0.0; m];
                let cpu = batch::normalise_target(
                    &mut lw,
                    &log_likelihood[range.clone()],
                    &mut w,
                    batch::LayerBeta::Fixed(1.0),
                )
                .map(|n| n.ess);
                let stats = report.stats[t];
                // The frame's log evidence (layer 0) at β = 1, whatever the status: beyond the
                // policy, the f32 sum of M terms and the rounding of the max.
                let evidence = batch::frame_log_evidence(
                    &log_weights[range.clone()],
                    &log_likelihood[range.clone()],
                );
                let rounding = 1e-4 + 2.0 * f64::from(f32::EPSILON) * evidence.abs();
                prop_assert!(
                    close(stats.log_evidence, evidence, rounding)
                        || (evidence.is_infinite() && f64::from(stats.log_evidence) == evidence),
                    "target {}: log evidence GPU {} vs CPU {}",
                    t,
                    stats.log_evidence,
                    evidence
                );
                match &cpu {
                    Ok(ess) => {
                        prop_assert_eq!(stats.status, 0, "target {}", t);
                        prop_assert!(
                            close(stats.ess, *ess, ABSOLUTE_TOLERANCE),
                            "ESS {} vs {}",
                            stats.ess,
                            ess
                        );
                    }
                    Err(e) => prop_assert_eq!(stats.result(m).unwrap_err(), e.clone()),
                }
                for (i, (&g, &c)) in weights[range].iter().zip(&w).enumerate() {
                    prop_assert!(
                        close(g, c, 0.0),
                        "target {} particle {}: GPU {} vs CPU {}",
                        t,
                        i,
                        g,
                        c
                    );
                }
            }
            Ok(())
        },
    );
}

#[test]
fn normalisation_names_the_first_nan_particle() {
    let Some(ctx) = common::gpu_context("normalisation_names_the_first_nan_particle") else {
        return;
    };
    let shape = BatchShape::new(3, 300, 1).unwrap();
    let cfg = config(shape, vec![false], vec![0.0], None);
    let mut gpu = GpuFilter::new(&ctx, &cfg, GpuResampler::Systematic, &vec![0.0; 900]).unwrap();
    let mut ll = vec![0.0f32; 900];
    ll[300 + 123] = f32::NAN;
    ll[300 + 200] = f32::NAN;
    ll[600..].fill(f32::NEG_INFINITY);
    gpu.streams().log_likelihood.upload(&ctx, &ll).unwrap();
    let report = gpu
        .run_stages(&ctx, &[GpuStage::Normalise], &NoLikelihood)
        .unwrap();
    assert_eq!(report.stats[0].result(300), Ok(()));
    assert_eq!(
        report.stats[1].result(300),
        Err(PfError::NanLogWeight { particle: 123 })
    );
    assert_eq!(
        report.stats[2].result(300),
        Err(PfError::AllWeightsZero { particles: 300 })
    );
    // Their evidence: log Σ (1/M)·1 = 0 for the flat target, NaN, and −∞ (nothing fits).
    assert!(report.stats[0].log_evidence.abs() < 1e-5);
    assert!(report.stats[1].log_evidence.is_nan());
    assert_eq!(report.stats[2].log_evidence, f32::NEG_INFINITY);
}

// ---- resampling ---------------------------------------------------------------------------------

/// Normalised f32 weights (what the GPU holds) with zeros and a dominating particle, and their f64
/// renormalisation (what the CPU twin reads).
fn weight_sets(shape: BatchShape) -> impl Strategy<Value = (Vec<f32>, Vec<f64>)> {
    let m = shape.particles;
    prop::collection::vec(
        prop_oneof![6 => 0.0f32..1.0, 1 => Just(0.0f32), 1 => Just(50.0f32)],
        shape.particle_len(),
    )
    .prop_map(move |raw| {
        let mut gpu = raw.clone();
        let mut cpu = vec![0.0f64; raw.len()];
        for t in 0..raw.len() / m {
            let r = t * m..(t + 1) * m;
            if raw[r.clone()].iter().all(|&x| x == 0.0) {
                gpu[t * m] = 1.0;
            }
            let sum: f32 = gpu[r.clone()].iter().sum();
            for i in r.clone() {
                gpu[i] /= sum;
            }
            let sum64: f64 = gpu[r.clone()].iter().map(|&x| f64::from(x)).sum();
            for i in r {
                cpu[i] = f64::from(gpu[i]) / sum64;
            }
        }
        (gpu, cpu)
    })
}

/// Whether `point` lies within `eps` of one of the cumulative sums at `indices`.
fn near_boundary(cdf: &[f64], point: f64, indices: &[usize], eps: f64) -> bool {
    indices.iter().any(|&i| {
        (cdf[i] - point).abs() <= eps
            || (i > 0 && (cdf[i - 1] - point).abs() <= eps)
            || (i == 0 && point.abs() <= eps)
    })
}

/// Targets large enough for the device-wide scan (more than 4096 particles).
fn large_shapes() -> impl Strategy<Value = BatchShape> {
    (
        1usize..=3,
        prop_oneof![Just(4097usize), 4097usize..20_000],
        1usize..=2,
    )
        .prop_map(|(t, m, d)| BatchShape::new(t, m, d).unwrap())
}

fn check_ordered(stratified: bool, large: bool) {
    let shape_strategy = if large {
        large_shapes().boxed()
    } else {
        shapes().boxed()
    };
    let strategy = shape_strategy
        .prop_flat_map(|shape| (Just(shape), weight_sets(shape), any::<u64>(), any::<bool>()));
    property(
        "ordered resampling",
        if large { 6 } else { 16 },
        strategy,
        |ctx: &GpuContext, (shape, (w32, w64), step, due)| -> Result<(), TestCaseError> {
            let m = shape.particles;
            let cfg = BatchConfig {
                ess_threshold: 0.5,
                ..config(shape, vec![false; shape.dims], vec![0.0; shape.dims], None)
            };
            let kind = if stratified {
                GpuResampler::Stratified
            } else {
                GpuResampler::Systematic
            };
            let mut gpu = GpuFilter::new(ctx, &cfg, kind, &vec![0.0; shape.state_len()]).unwrap();
            gpu.streams().weights.upload(ctx, &w32).unwrap();
            // With a threshold of M/2, ESS 0 makes every target due and ESS M none.
            let stats = TargetStats {
                ess: if due { 0.0 } else { m as f32 },
                ..TargetStats::default()
            };
            gpu.streams()
                .stats
                .upload(ctx, &vec![stats; shape.targets])
                .unwrap();
            gpu.set_step(step);
            let report = gpu
                .run_stages(ctx, &[GpuStage::Resample], &NoLikelihood)
                .unwrap();
            let got = gpu.download_ancestors(ctx).unwrap();
            let keys = batch::stage_keys(5, shape.targets, Stage::Resampling);
            for t in 0..shape.targets {
                let r = t * m..(t + 1) * m;
                prop_assert_eq!(report.stats[t].resampled == 1, due);
                if !due {
                    prop_assert!(got[r].iter().enumerate().all(|(k, &a)| a as usize == k));
                    continue;
                }
                let uniforms = CounterUniforms::new(keys[t], step);
                let mut want = vec![0u32; m];
                if stratified {
                    Stratified
                        .resample(&w64[r.clone()], &uniforms, &mut want)
                        .unwrap();
                } else {
                    Systematic
                        .resample(&w64[r.clone()], &uniforms, &mut want)
                        .unwrap();
                }
                let cdf: Vec<f64> = w64[r.clone()]
                    .iter()
                    .scan(0.0, |acc, &w| {
                        *acc += w;
                        Some(*acc)
                    })
                    .collect();
                for k in 0..m {
                    let (g, c) = (got[t * m + k] as usize, want[k] as usize);
                    if g != c {
                        use pf_core::UniformSource;
                        let u = if stratified {
                            uniforms.uniform(k as u32, 0)
                        } else {
                            uniforms.uniform(0, 0)
                        };
                        let point = (k as f64 + u) / m as f64;
                        // f32 prefix sums (up to 20 000 weights) and f32 points: 1e-5 covers both.
                        prop_assert!(
                            near_boundary(&cdf, point, &[g.min(m - 1), c], 1e-5),
                            "target {} offspring {}: GPU {} vs CPU {} (point {}, cdf {:?})",
                            t,
                            k,
                            g,
                            c,
                            point,
                            &cdf[c.saturating_sub(1)..(c + 1).min(m)]
                        );
                    }
                    prop_assert!(
                        w64[t * m + g] > 0.0 || m == 1,
                        "GPU chose zero-weight particle {}",
                        g
                    );
                }
            }
            Ok(())
        },
    );
}

#[test]
fn systematic_resampling_same_ancestors_as_cpu() {
    check_ordered(false, false);
}

#[test]
fn stratified_resampling_same_ancestors_as_cpu() {
    check_ordered(true, false);
}

#[test]
fn systematic_resampling_device_wide_scan_same_ancestors_as_cpu() {
    check_ordered(false, true);
}

#[test]
fn stratified_resampling_device_wide_scan_same_ancestors_as_cpu() {
    check_ordered(true, true);
}

/// Metropolis on the CPU in f64, flagging chains that met a near-tie acceptance test (where the
/// GPU's f32 product may decide the other way).
fn metropolis_with_ties(
    weights: &[f64],
    uniforms: &CounterUniforms,
    steps: u32,
) -> Vec<(u32, bool)> {
    use pf_core::UniformSource;
    let n = weights.len();
    (0..n)
        .map(|k| {
            let mut current = k;
            let mut tie = false;
            for b in 0..steps {
                let block = uniforms.uniform4(k as u32, b / 2);
                let lane = 2 * (b % 2) as usize;
                let proposal = ((block[lane] * n as f64) as usize).min(n - 1);
                let lhs = block[lane + 1] * weights[current];
                let rhs = weights[proposal];
                tie |= (lhs - rhs).abs() <= 1e-5 * rhs.max(lhs);
                if lhs < rhs {
                    current = proposal;
                }
            }
            (current as u32, tie)
        })
        .collect()
}

#[test]
fn metropolis_resampling_same_ancestors_as_cpu() {
    let strategy =
        shapes().prop_flat_map(|shape| (Just(shape), weight_sets(shape), any::<u64>(), 1u32..40));
    property(
        "metropolis_resampling_same_ancestors_as_cpu",
        16,
        strategy,
        |ctx: &GpuContext, (shape, (w32, w64), step, steps)| {
            let m = shape.particles;
            let cfg = config(shape, vec![false; shape.dims], vec![0.0; shape.dims], None);
            let mut gpu = GpuFilter::new(
                ctx,
                &cfg,
                GpuResampler::Metropolis(steps),
                &vec![0.0; shape.state_len()],
            )
            .unwrap();
            gpu.streams().weights.upload(ctx, &w32).unwrap();
            let stats = TargetStats {
                ess: 0.0,
                ..TargetStats::default()
            };
            gpu.streams()
                .stats
                .upload(ctx, &vec![stats; shape.targets])
                .unwrap();
            gpu.set_step(step);
            gpu.run_stages(ctx, &[GpuStage::Resample], &NoLikelihood)
                .unwrap();
            let got = gpu.download_ancestors(ctx).unwrap();
            let keys = batch::stage_keys(5, shape.targets, Stage::Resampling);
            for t in 0..shape.targets {
                let r = t * m..(t + 1) * m;
                let uniforms = CounterUniforms::new(keys[t], step);
                // The library resampler and the traced chain agree with each other exactly.
                let mut lib = vec![0u32; m];
                Metropolis::new(steps)
                    .resample(&w64[r.clone()], &uniforms, &mut lib)
                    .unwrap();
                let traced = metropolis_with_ties(&w64[r.clone()], &uniforms, steps);
                for k in 0..m {
                    prop_assert_eq!(lib[k], traced[k].0);
                    let g = got[t * m + k];
                    prop_assert!(
                        g == lib[k] || traced[k].1,
                        "target {} offspring {}: GPU {} vs CPU {}",
                        t,
                        k,
                        g,
                        lib[k]
                    );
                }
            }
            Ok(())
        },
    );
}

// ---- gather and estimate ------------------------------------------------------------------------

#[test]
fn gather_bit_exact_vs_cpu() {
    let strategy = shapes().prop_flat_map(|shape| {
        (
            Just(shape),
            prop::collection::vec(state_value(), shape.state_len()),
            prop::collection::vec(0..shape.particles as u32, shape.particle_len()),
            prop::collection::vec(any::<bool>(), shape.targets),
        )
    });
    property(
        "gather_bit_exact_vs_cpu",
        12,
        strategy,
        |ctx: &GpuContext, (shape, states, ancestors, resampled)| {
            let m = shape.particles;
            let cfg = config(shape, vec![false; shape.dims], vec![0.0; shape.dims], None);
            let mut gpu = GpuFilter::new(ctx, &cfg, GpuResampler::Systematic, &states).unwrap();
            gpu.streams().ancestors.upload(ctx, &ancestors).unwrap();
            let stats: Vec<TargetStats> = resampled
                .iter()
                .map(|&r| TargetStats {
                    resampled: u32::from(r),
                    ..TargetStats::default()
                })
                .collect();
            gpu.streams().stats.upload(ctx, &stats).unwrap();
            gpu.streams()
                .log_weights
                .upload(ctx, &vec![-7.0; shape.particle_len()])
                .unwrap();
            gpu.run_stages(ctx, &[GpuStage::Gather], &NoLikelihood)
                .unwrap();
            let got = gpu.download_states(ctx).unwrap();
            let lw = gpu.streams().log_weights.download(ctx).unwrap();
            for t in 0..shape.targets {
                let mut set = pf_core::ParticleSet::<1>::zeros(m).unwrap();
                for d in 0..shape.dims {
                    set.dim_mut(0).copy_from_slice(
                        &states[shape.state_index(t, d, 0)..shape.state_index(t, d, 0) + m],
                    );
                    set.select(&ancestors[t * m..(t + 1) * m]).unwrap();
                    for k in 0..m {
                        prop_assert_eq!(
                            got[shape.state_index(t, d, k)].to_bits(),
                            set.dim(0)[k].to_bits()
                        );
                    }
                }
                let want_lw = if resampled[t] { -(m as f32).ln() } else { -7.0 };
                prop_assert!(
                    lw[t * m..(t + 1) * m]
                        .iter()
                        .all(|&x| (x - want_lw).abs() <= 1e-6 * want_lw.abs())
                );
            }
            Ok(())
        },
    );
}

#[test]
fn weighted_mean_and_spread_match_cpu_within_tolerance() {
    let strategy = shapes().prop_flat_map(|shape| {
        (
            Just(shape),
            prop::collection::vec(-100.0f32..100.0, shape.state_len()),
            weight_sets(shape),
            prop::collection::vec(any::<bool>(), shape.dims),
        )
    });
    property(
        "weighted_mean_and_spread_match_cpu_within_tolerance",
        16,
        strategy,
        |ctx: &GpuContext, (shape, states, (w32, w64), angular)| {
            let states: Vec<f32> = states
                .iter()
                .enumerate()
                .map(|(i, &x)| {
                    let d = (i / shape.particles) % shape.dims;
                    if angular[d] {
                        batch::wrap_angle_floor(x)
                    } else {
                        x
                    }
                })
                .collect();
            let cfg = config(shape, angular.clone(), vec![0.0; shape.dims], None);
            let mut gpu = GpuFilter::new(ctx, &cfg, GpuResampler::Systematic, &states).unwrap();
            gpu.streams().weights.upload(ctx, &w32).unwrap();
            let report = gpu
                .run_stages(ctx, &[GpuStage::Estimate], &NoLikelihood)
                .unwrap();
            let (want, spreads) =
                batch::weighted_means_and_spreads(&shape, &states, &w64, &angular);
            for (i, (&g, &c)) in report.estimates.iter().zip(&want).enumerate() {
                let d = i % shape.dims;
                // Angles: the circular mean is ill-conditioned when the resultant vector is short
                // (weights spread around the circle), so compare the resultant direction loosely.
                let ok = if angular[d] {
                    batch::wrap_angle_floor(g - c).abs() <= 2e-3
                } else {
                    (g - c).abs() <= 1e-4 * 100.0
                };
                prop_assert!(ok, "estimate {}: GPU {} vs CPU {}", i, g, c);
            }
            // The spreads about the CPU's means: standard deviations within 1e-3 of the value
            // range; for angles the resultant length R = exp(-s²/2) within 1e-3 (R is what is
            // summed; s = √(−2 ln R) is steep as R → 0).
            for (i, (&g, &c)) in report.spreads.iter().zip(&spreads).enumerate() {
                let ok = if angular[i % shape.dims] {
                    let r = |s: f32| (-0.5 * s * s).exp();
                    (r(g) - r(c)).abs() <= 1e-3
                } else {
                    (g - c).abs() <= 1e-3 * 100.0
                };
                prop_assert!(ok, "spread {}: GPU {} vs CPU {}", i, g, c);
            }
            Ok(())
        },
    );
}

#[test]
fn best_weighted_mean_matches_cpu_within_tolerance() {
    let strategy = shapes().prop_flat_map(|shape| {
        (
            Just(shape),
            prop::collection::vec(-100.0f32..100.0, shape.state_len()),
            // Few distinct levels, so that ties at the M'-th weight are common.
            prop::collection::vec(
                prop_oneof![Just(0.0f32), Just(1.0), Just(2.0), Just(4.0), 0.0f32..8.0],
                shape.particle_len(),
            ),
            1..=shape.particles,
        )
    });
    property(
        "best_weighted_mean_matches_cpu_within_tolerance",
        16,
        strategy,
        |ctx: &GpuContext, (shape, states, raw, best)| {
            let m = shape.particles;
            // Normalise per target in f32 (what the GPU holds); the CPU reads the same values.
            let mut w32 = raw.clone();
            for t in 0..shape.targets {
                let r = t * m..(t + 1) * m;
                let sum: f32 = w32[r.clone()].iter().sum();
                for i in r {
                    w32[i] = if sum > 0.0 {
                        w32[i] / sum
                    } else {
                        1.0 / m as f32
                    };
                }
            }
            let w64: Vec<f64> = w32.iter().map(|&w| f64::from(w)).collect();
            let angular = vec![false; shape.dims];
            let cfg = BatchConfig {
                best,
                ..config(shape, angular.clone(), vec![0.0; shape.dims], None)
            };
            let mut gpu = GpuFilter::new(ctx, &cfg, GpuResampler::Systematic, &states).unwrap();
            gpu.streams().weights.upload(ctx, &w32).unwrap();
            let report = gpu
                .run_stages(ctx, &[GpuStage::Estimate], &NoLikelihood)
                .unwrap();
            let want = batch::best_weighted_means(&shape, &states, &w64, &angular, best);
            for (i, (&g, &c)) in report.best_estimates.iter().zip(&want).enumerate() {
                prop_assert!(
                    (g - c).abs() <= 1e-4 * 100.0,
                    "estimate {} (M' = {}): GPU {} vs CPU {}",
                    i,
                    best,
                    g,
                    c
                );
            }
            Ok(())
        },
    );
}
