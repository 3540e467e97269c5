//! The filter loop: bit-identical runs from one seed, the resampling policy, and the failure
//! policy (typed errors, recovery).

use nalgebra::{SVector, vector};
use pf_core::resample::{Rejection, Systematic};
use pf_core::{
    FilterConfig, GaussianDiffusion, GaussianObservation, Likelihood, ParticleFilter, PfError,
    ResamplePolicy, Resampler, StateSpace,
};

const D: usize = 7;

fn config(seed: u64, policy: ResamplePolicy) -> FilterConfig<D> {
    FilterConfig {
        particles: 1000,
        policy,
        seed,
        target: 3,
        space: StateSpace::with_angles(&[3, 4, 5]).unwrap(),
    }
}

fn filter<R: Resampler>(
    seed: u64,
    policy: ResamplePolicy,
    resampler: R,
) -> ParticleFilter<D, GaussianDiffusion<D>, R> {
    let sigma = SVector::<f32, D>::repeat(0.1);
    ParticleFilter::new(
        config(seed, policy),
        GaussianDiffusion::new(sigma).unwrap(),
        resampler,
        &SVector::zeros(),
        &SVector::repeat(0.3),
    )
    .unwrap()
}

fn observation(t: usize) -> GaussianObservation<D> {
    let s = t as f32 * 0.05;
    GaussianObservation {
        observed: vector![s, -s, 1.0, 2.0 * s, 0.2, -0.1, 0.9],
        sigma: SVector::repeat(0.1),
        space: StateSpace::with_angles(&[3, 4, 5]).unwrap(),
    }
}

fn run<R: Resampler>(f: &mut ParticleFilter<D, GaussianDiffusion<D>, R>, steps: usize) -> Vec<u32> {
    for t in 0..steps {
        f.step(&observation(t)).unwrap();
    }
    f.particles()
        .states_raw()
        .iter()
        .map(|x| x.to_bits())
        .collect()
}

#[test]
fn same_seed_gives_bit_identical_runs() {
    // Rejection resampling runs in parallel on the rayon pool: still bit-identical.
    let policy = ResamplePolicy::EssBelow(0.5);
    let a = run(&mut filter(42, policy, Rejection::default()), 30);
    let b = run(&mut filter(42, policy, Rejection::default()), 30);
    assert_eq!(a, b);
    let c = run(&mut filter(43, policy, Rejection::default()), 30);
    assert_ne!(a, c, "a different seed must give a different run");
}

#[test]
fn the_filter_follows_a_7d_target_across_the_angle_wrap() {
    let mut f = filter(5, ResamplePolicy::EveryStep, Systematic);
    // Rx moves 0.1 rad per step: it crosses +π after ~31 steps. A random-walk prior lags a ramp by
    // about v(1 − K)/K ≈ 0.06 rad here (steady-state Kalman gain K ≈ 0.62), plus noise.
    for t in 0..50 {
        let report = f.step(&observation(t)).unwrap();
        let err = StateSpace::<D>::with_angles(&[3, 4, 5])
            .unwrap()
            .difference(&report.estimate, &observation(t).observed);
        if t >= 5 {
            assert!(err.amax() < 0.25, "step {t}: error {err:?}");
        }
    }
}

#[test]
fn ess_policy_resamples_only_below_the_threshold() {
    let mut f = filter(9, ResamplePolicy::EssBelow(0.3), Systematic);
    let mut previous_ess = None;
    for t in 0..20 {
        let report = f.step(&observation(t)).unwrap();
        if let Some(prev) = previous_ess {
            assert_eq!(report.resampled, prev < 0.3 * 1000.0, "step {t}");
        } else {
            assert!(
                !report.resampled,
                "nothing to resample before the first measurement"
            );
        }
        previous_ess = Some(report.ess);
    }
}

#[test]
fn invalid_configuration_is_a_typed_error() {
    let make = |particles, policy| {
        ParticleFilter::new(
            FilterConfig {
                particles,
                ..config(1, policy)
            },
            GaussianDiffusion::new(SVector::<f32, D>::repeat(0.1)).unwrap(),
            Systematic,
            &SVector::zeros(),
            &SVector::repeat(0.1),
        )
    };
    assert!(matches!(
        make(0, ResamplePolicy::EveryStep),
        Err(PfError::EmptyParticleSet)
    ));
    assert!(matches!(
        make(10, ResamplePolicy::EssBelow(0.0)),
        Err(PfError::InvalidConfig(_))
    ));
    assert!(matches!(
        make(10, ResamplePolicy::EssBelow(f64::NAN)),
        Err(PfError::InvalidConfig(_))
    ));
    assert!(GaussianDiffusion::new(vector![0.1, -1.0]).is_err());
    assert!(GaussianDiffusion::new(vector![0.1, f32::NAN]).is_err());
}

struct Rejects;
impl Likelihood<D> for Rejects {
    fn log_likelihood(&self, _: &SVector<f32, D>) -> f32 {
        f32::NEG_INFINITY
    }
}

struct NanFor(usize);
impl Likelihood<D> for NanFor {
    fn log_likelihood(&self, _: &SVector<f32, D>) -> f32 {
        0.0
    }
    fn log_likelihoods(&self, _: &pf_core::ParticleSet<D>, out: &mut [f32]) {
        out.fill(0.0);
        out[self.0] = f32::NAN;
    }
}

#[test]
fn a_rejecting_likelihood_gives_a_typed_error_and_recovery_resumes_tracking() {
    let mut f = filter(17, ResamplePolicy::EveryStep, Systematic);
    for t in 0..10 {
        f.step(&observation(t)).unwrap();
    }
    let good = *f.last_estimate();
    assert_eq!(
        f.step(&Rejects),
        Err(PfError::AllWeightsZero { particles: 1000 })
    );
    // The failed step left a well-formed, equally weighted set and the last good estimate.
    assert_eq!(*f.last_estimate(), good);
    assert!(f.weights().iter().all(|&w| (w - 1e-3).abs() < 1e-12));
    f.recover(&SVector::repeat(0.05)).unwrap();
    let spread = (0..1000)
        .map(|i| {
            StateSpace::<D>::with_angles(&[3, 4, 5])
                .unwrap()
                .difference(&f.particles().state(i), &good)
                .amax()
        })
        .fold(0.0f32, f32::max);
    assert!(
        spread < 0.05 * 6.0,
        "recovered particles lie around the last estimate (spread {spread})"
    );
    for t in 10..15 {
        let report = f.step(&observation(t)).unwrap();
        assert!(report.estimate.iter().all(|x| x.is_finite()));
    }
    assert!(f.recover(&SVector::repeat(f32::NAN)).is_err());
}

#[test]
fn a_nan_likelihood_names_the_particle() {
    let mut f = filter(19, ResamplePolicy::EveryStep, Systematic);
    assert_eq!(
        f.step(&NanFor(123)),
        Err(PfError::NanLogWeight { particle: 123 })
    );
    // Stepping again without recovery works on the equally weighted set.
    assert!(f.step(&observation(0)).is_ok());
}

#[test]
fn best_and_max_weight_estimates_agree_with_the_mean_on_a_peaked_posterior() {
    let mut f = filter(23, ResamplePolicy::EveryStep, Systematic);
    for t in 0..10 {
        f.step(&observation(t)).unwrap();
    }
    let mean = *f.last_estimate();
    let space = StateSpace::<D>::with_angles(&[3, 4, 5]).unwrap();
    let best = f.best_estimate(100).unwrap();
    let max = f.max_weight_estimate().unwrap();
    assert!(space.difference(&best, &mean).amax() < 0.1);
    assert!(space.difference(&max, &mean).amax() < 0.2);
}
