//! The batch filter's loop: bit-identical runs from one seed, the resampling policy, the failure
//! policy (a typed error and an honest evidence per target, the other targets untouched, a reset
//! that resumes tracking) and the estimates.

use pf_core::batch::{BatchConfig, BatchFilter, BatchReport, BatchShape, gaussian_clouds};
use pf_core::resample::{Rejection, Systematic};
use pf_core::{PfError, Resampler, StateSpace};

const D: usize = 7;
const M: usize = 1000;
const TARGETS: usize = 2;
const ANGLES: [usize; 3] = [3, 4, 5];

fn config(seed: u64, ess_threshold: f64) -> BatchConfig {
    let shape = BatchShape::new(TARGETS, M, D).unwrap();
    let mut config = BatchConfig::new(shape, seed, vec![0.1; D]);
    config.angular = (0..D).map(|d| ANGLES.contains(&d)).collect();
    config.ess_threshold = ess_threshold;
    config.best = 100;
    config
}

fn filter<R: Resampler>(seed: u64, ess_threshold: f64, resampler: R) -> BatchFilter<R> {
    let config = config(seed, ess_threshold);
    let start = gaussian_clouds(&config.shape, seed, &[0.0; D * TARGETS], &[0.3; D]);
    BatchFilter::new(&config, resampler, start).unwrap()
}

/// Target t's observation at step s: a point moving on every dimension, Rx by 0.1 rad a step.
fn observed(t: usize, s: usize) -> [f32; D] {
    let s = s as f32 * 0.05 + 0.1 * t as f32;
    let mut z = [s, -s, 1.0, 2.0 * s, 0.2, -0.1, 0.9];
    z[3] = pf_core::estimate::wrap_angle(z[3]);
    z
}

fn space() -> StateSpace<D> {
    StateSpace::with_angles(&ANGLES).unwrap()
}

/// A Gaussian likelihood (σ = 0.1, angles the short way round) about each target's observation.
fn step<R: Resampler>(f: &mut BatchFilter<R>, s: usize) -> BatchReport {
    f.step(|t, _, x| {
        let z = observed(t, s);
        let diff = space().difference(
            &nalgebra::SVector::<f32, D>::from_column_slice(x),
            &nalgebra::SVector::from(z),
        );
        -0.5 * diff.iter().map(|d| (d / 0.1).powi(2)).sum::<f32>()
    })
    .unwrap()
}

fn run<R: Resampler>(f: &mut BatchFilter<R>, steps: usize) -> Vec<u32> {
    for s in 0..steps {
        step(f, s);
    }
    f.states.iter().map(|x| x.to_bits()).collect()
}

#[test]
fn same_seed_gives_bit_identical_runs() {
    // Rejection resampling runs in parallel on the rayon pool: still bit-identical.
    let a = run(&mut filter(42, 0.5, Rejection::default()), 30);
    let b = run(&mut filter(42, 0.5, Rejection::default()), 30);
    assert_eq!(a, b);
    let c = run(&mut filter(43, 0.5, Rejection::default()), 30);
    assert_ne!(a, c, "a different seed must give a different run");
}

#[test]
fn the_filter_follows_a_7d_target_across_the_angle_wrap() {
    let mut f = filter(5, f64::INFINITY, Systematic);
    // Rx moves 0.1 rad per step: it crosses +π after ~31 steps. A random-walk prior lags a ramp by
    // about v(1 − K)/K ≈ 0.06 rad here (steady-state Kalman gain K ≈ 0.62), plus noise.
    for s in 0..50 {
        let report = step(&mut f, s);
        for t in 0..TARGETS {
            let estimate = nalgebra::SVector::<f32, D>::from_column_slice(
                &report.estimates[t * D..(t + 1) * D],
            );
            let err = space().difference(&estimate, &nalgebra::SVector::from(observed(t, s)));
            if s >= 5 {
                assert!(err.amax() < 0.25, "step {s} target {t}: error {err:?}");
            }
        }
    }
}

#[test]
fn ess_policy_resamples_only_below_the_threshold() {
    let mut f = filter(9, 0.3, Systematic);
    let mut previous_ess: Option<Vec<f64>> = None;
    for s in 0..20 {
        let report = step(&mut f, s);
        for t in 0..TARGETS {
            match &previous_ess {
                Some(prev) => assert_eq!(report.resampled[t], prev[t] < 0.3 * M as f64, "step {s}"),
                None => assert!(
                    !report.resampled[t],
                    "nothing to resample before the first measurement"
                ),
            }
        }
        previous_ess = Some(report.ess);
    }
}

#[test]
fn invalid_configuration_is_a_typed_error() {
    assert!(matches!(
        BatchShape::new(TARGETS, 0, D),
        Err(PfError::InvalidConfig(_))
    ));
    for threshold in [0.0, -1.0, f64::NAN] {
        let bad = BatchConfig {
            ess_threshold: threshold,
            ..config(1, 1.0)
        };
        assert!(matches!(bad.validate(), Err(PfError::InvalidConfig(_))));
    }
    for sigma in [-1.0, f32::NAN] {
        let mut bad = config(1, 1.0);
        bad.sigma[1] = sigma;
        assert!(matches!(bad.validate(), Err(PfError::InvalidConfig(_))));
    }
    let short = vec![0.0; D * M];
    assert!(matches!(
        BatchFilter::new(&config(1, 1.0), Systematic, short),
        Err(PfError::LengthMismatch { .. })
    ));
}

#[test]
fn a_rejecting_likelihood_fails_its_target_alone_and_a_reset_resumes_tracking() {
    let mut f = filter(17, f64::INFINITY, Systematic);
    for s in 0..10 {
        step(&mut f, s);
    }
    // Target 1 rejects every particle; target 0 sees its observation as before.
    let report = f
        .step(|t, _, x| match t {
            0 => -0.5 * ((x[0] - observed(0, 10)[0]) / 0.1).powi(2),
            _ => f32::NEG_INFINITY,
        })
        .unwrap();
    assert_eq!(report.status[0], Ok(()));
    assert_eq!(
        report.status[1],
        Err(PfError::AllWeightsZero { particles: M })
    );
    assert!(report.log_evidence[0].is_finite());
    assert_eq!(report.log_evidence[1], f64::NEG_INFINITY);
    // The failed target is left well formed and equally weighted.
    assert!(
        f.weights[M..]
            .iter()
            .all(|&w| (w - 1.0 / M as f64).abs() < 1e-12)
    );
    // A reset around its last good estimate resumes tracking.
    let good = &report.estimates[D..2 * D];
    let shape = BatchShape::new(1, M, D).unwrap();
    let cloud = gaussian_clouds(&shape, 99, good, &[0.05; D]);
    f.reset_target(1, &cloud).unwrap();
    for s in 11..16 {
        let report = step(&mut f, s);
        assert!(report.status.iter().all(Result::is_ok));
        assert!(report.estimates.iter().all(|x| x.is_finite()));
    }
}

#[test]
fn a_nan_likelihood_names_the_particle_and_its_evidence_is_nan() {
    let mut f = filter(19, f64::INFINITY, Systematic);
    let report = f
        .step(|t, m, _| if t == 1 && m == 123 { f32::NAN } else { 0.0 })
        .unwrap();
    assert_eq!(
        report.status[1],
        Err(PfError::NanLogWeight { particle: 123 })
    );
    assert!(report.log_evidence[1].is_nan());
    // A flat likelihood of 0 has evidence log Σ w = 0 (up to the f32 log-weights' rounding).
    assert!(
        report.log_evidence[0].abs() < 1e-5,
        "{}",
        report.log_evidence[0]
    );
    // Stepping again works on the equally weighted set.
    assert!(step(&mut f, 0).status.iter().all(Result::is_ok));
}

#[test]
fn best_estimates_agree_with_the_mean_on_a_peaked_posterior() {
    let mut f = filter(23, f64::INFINITY, Systematic);
    let mut report = step(&mut f, 0);
    for s in 1..10 {
        report = step(&mut f, s);
    }
    for t in 0..TARGETS {
        let mean = nalgebra::SVector::<f32, D>::from_column_slice(&report.estimates[t * D..][..D]);
        let best =
            nalgebra::SVector::<f32, D>::from_column_slice(&report.best_estimates[t * D..][..D]);
        assert!(space().difference(&best, &mean).amax() < 0.1);
    }
}
