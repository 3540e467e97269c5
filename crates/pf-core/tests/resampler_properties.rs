//! Property tests of every resampler: index range, offspring-count bounds, determinism given the
//! uniforms, and unbiasedness in distribution (chi-square at a fixed seed).

use pf_core::resample::{
    Metropolis, Multinomial, Rejection, Residual, ResidualRemainder, Stratified, Systematic,
};
use pf_core::{CounterUniforms, RandomStreams, Resampler, Stage, UniformSource};
use proptest::prelude::*;

fn all_resamplers() -> Vec<Box<dyn Resampler>> {
    vec![
        Box::new(Multinomial),
        Box::new(Stratified),
        Box::new(Systematic),
        Box::new(Residual::new(ResidualRemainder::Systematic)),
        Box::new(Residual::new(ResidualRemainder::Multinomial)),
        Box::new(Metropolis::new(16)),
        Box::new(Rejection::default()),
    ]
}

/// Raw weights with the edge cases a filter meets: exact zeros, tiny values, one dominating
/// particle, and a single particle.
fn raw_weight() -> impl Strategy<Value = f64> {
    prop_oneof![
        3 => 0.0..1.0f64,
        1 => Just(0.0),
        1 => 1e-300..1e-200f64,
        1 => 1e-9..1e-6f64,
        1 => Just(1e6),
    ]
}

fn normalised_weights() -> impl Strategy<Value = Vec<f64>> {
    prop::collection::vec(raw_weight(), 1..300)
        .prop_filter("at least one positive weight", |w| {
            w.iter().any(|&x| x > 0.0)
        })
        .prop_map(|w| {
            let sum: f64 = w.iter().sum();
            w.into_iter().map(|x| x / sum).collect()
        })
}

fn offspring_counts(ancestors: &[u32], n: usize) -> Vec<usize> {
    let mut counts = vec![0; n];
    for &a in ancestors {
        counts[a as usize] += 1;
    }
    counts
}

fn uniforms(seed: u64) -> CounterUniforms {
    RandomStreams::new(seed).counter_uniforms(0, Stage::Resampling, 0)
}

/// Room for rounding when M·w_i sits on an integer.
const EPS: f64 = 1e-9;

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    #[test]
    fn every_resampler_gives_m_indices_in_range_and_is_a_function_of_its_uniforms(
        weights in normalised_weights(),
        offspring in prop_oneof![Just(0usize), 1..400usize],
        seed in any::<u64>(),
    ) {
        // offspring == 0 stands for "as many offspring as particles".
        let m = if offspring == 0 { weights.len() } else { offspring };
        let source = uniforms(seed);
        for r in all_resamplers() {
            let mut first = vec![u32::MAX; m];
            r.resample(&weights, &source, &mut first).unwrap();
            prop_assert!(first.iter().all(|&a| (a as usize) < weights.len()), "{}", r.name());
            if r.name() != "metropolis" {
                // Only the Metropolis chain can stop on a particle of zero weight.
                prop_assert!(first.iter().all(|&a| weights[a as usize] > 0.0),
                    "{} picked a zero-weight particle", r.name());
            }
            let mut second = vec![0; m];
            r.resample(&weights, &uniforms(seed), &mut second).unwrap();
            prop_assert_eq!(&first, &second, "{} is not a function of its uniforms", r.name());
        }
    }

    #[test]
    fn systematic_and_residual_counts_are_floor_or_ceil_of_m_w(
        weights in normalised_weights(),
        offspring in 1..400usize,
        seed in any::<u64>(),
    ) {
        let source = uniforms(seed);
        for r in [&Systematic as &dyn Resampler, &Residual::new(ResidualRemainder::Systematic)] {
            let mut ancestors = vec![0; offspring];
            r.resample(&weights, &source, &mut ancestors).unwrap();
            for (i, &c) in offspring_counts(&ancestors, weights.len()).iter().enumerate() {
                let expected = offspring as f64 * weights[i];
                prop_assert!(c as f64 >= (expected - EPS).floor() && c as f64 <= (expected + EPS).ceil(),
                    "{}: particle {i} has {c} offspring, M w = {expected}", r.name());
            }
        }
    }

    #[test]
    fn residual_multinomial_keeps_the_deterministic_copies(
        weights in normalised_weights(),
        offspring in 1..400usize,
        seed in any::<u64>(),
    ) {
        let mut ancestors = vec![0; offspring];
        Residual::new(ResidualRemainder::Multinomial)
            .resample(&weights, &uniforms(seed), &mut ancestors).unwrap();
        let floors: f64 = weights.iter().map(|w| (offspring as f64 * w).floor()).sum();
        let remainder = offspring as f64 - floors;
        for (i, &c) in offspring_counts(&ancestors, weights.len()).iter().enumerate() {
            let floor = (offspring as f64 * weights[i] - EPS).floor();
            prop_assert!(c as f64 >= floor && c as f64 <= floor + remainder + 1.0);
        }
    }

    /// Stratified resampling is not bounded by floor/ceil: a particle whose CDF interval straddles
    /// two strata can get a draw from both or from neither. It is bounded one further out.
    #[test]
    fn stratified_counts_are_within_one_of_floor_and_ceil(
        weights in normalised_weights(),
        offspring in 1..400usize,
        seed in any::<u64>(),
    ) {
        let mut ancestors = vec![0; offspring];
        Stratified.resample(&weights, &uniforms(seed), &mut ancestors).unwrap();
        for (i, &c) in offspring_counts(&ancestors, weights.len()).iter().enumerate() {
            let expected = offspring as f64 * weights[i];
            prop_assert!(c as f64 >= (expected - EPS).floor() - 1.0 && c as f64 <= (expected + EPS).ceil() + 1.0);
        }
    }

    #[test]
    fn unnormalised_or_invalid_weights_are_rejected(
        mut weights in normalised_weights(),
        which in any::<prop::sample::Index>(),
        bad in prop_oneof![Just(f64::NAN), Just(-0.5), Just(f64::INFINITY), Just(2.0)],
    ) {
        let i = which.index(weights.len());
        weights[i] = bad;
        for r in all_resamplers() {
            let mut ancestors = vec![0; 8];
            let err = r.resample(&weights, &uniforms(1), &mut ancestors).unwrap_err();
            prop_assert!(matches!(err, pf_core::PfError::InvalidWeights { .. }), "{}: {err}", r.name());
        }
    }
}

#[test]
fn systematic_follows_hand_computed_cases() {
    let half = |_: u32, _: u32| 0.5;
    let mut a = [0u32; 4];
    Systematic
        .resample(&[0.25, 0.25, 0.25, 0.25], &half, &mut a)
        .unwrap();
    assert_eq!(a, [0, 1, 2, 3]);
    Systematic
        .resample(&[0.0, 0.5, 0.0, 0.5], &half, &mut a)
        .unwrap();
    assert_eq!(a, [1, 1, 3, 3]);
    // Points (k + 0.9)/4 = 0.225, 0.475, 0.725, 0.975 against the CDF 0.1, 0.2, 1.0.
    let late = |_: u32, _: u32| 0.9;
    let mut b = [0u32; 4];
    Systematic
        .resample(&[0.1, 0.1, 0.8], &late, &mut b)
        .unwrap();
    assert_eq!(b, [2, 2, 2, 2]);
    // A uniform of 0 must not select the zero-weight first particle.
    let zero = |_: u32, _: u32| 0.0;
    Systematic
        .resample(&[0.0, 0.5, 0.0, 0.5], &zero, &mut a)
        .unwrap();
    assert_eq!(a, [1, 1, 3, 3]);
}

#[test]
fn empty_inputs_are_errors() {
    for r in all_resamplers() {
        let mut none: [u32; 0] = [];
        assert_eq!(
            r.resample(&[1.0], &uniforms(0), &mut none),
            Err(pf_core::PfError::EmptyParticleSet)
        );
        let mut one = [0u32];
        assert_eq!(
            r.resample(&[], &uniforms(0), &mut one),
            Err(pf_core::PfError::EmptyParticleSet)
        );
    }
}

#[test]
fn rejection_gives_up_with_a_typed_error_on_adversarial_uniforms() {
    // Acceptance uniforms (even draws) stuck at 0.999 and index uniforms (odd draws) at 0: every
    // try proposes the light particle 0, which is accepted only when u·0.9 < 0.1.
    let stuck = |_: u32, draw: u32| if draw % 2 == 1 { 0.0 } else { 0.999 };
    let mut a = [0u32; 1];
    let err = Rejection { max_tries: 100 }
        .resample(&[0.1, 0.9], &stuck, &mut a)
        .unwrap_err();
    assert_eq!(
        err,
        pf_core::PfError::RejectionGaveUp {
            particle: 0,
            tries: 100
        }
    );
}

// ---- unbiasedness in distribution -------------------------------------------------------------

/// Weights of the chi-square test: uneven, with one zero (which must get no offspring).
fn test_weights() -> Vec<f64> {
    let raw = [5.0, 1.0, 0.0, 3.0, 0.5, 2.0, 8.0, 0.25, 1.5, 4.0, 0.75, 2.5];
    let sum: f64 = raw.iter().sum();
    raw.iter().map(|x| x / sum).collect()
}

/// Offspring counts pooled over `rounds` resamplings of M = N offspring, fresh uniforms each
/// round (a fixed seed, so the test is deterministic).
fn pooled_counts(r: &dyn Resampler, weights: &[f64], rounds: u64) -> Vec<u64> {
    let streams = RandomStreams::new(2024);
    let mut counts = vec![0u64; weights.len()];
    let mut ancestors = vec![0u32; weights.len()];
    for round in 0..rounds {
        let source = streams.counter_uniforms(0, Stage::Resampling, round);
        r.resample(weights, &source, &mut ancestors).unwrap();
        for &a in &ancestors {
            counts[a as usize] += 1;
        }
    }
    counts
}

/// The chi-square statistic of `counts` against their expectation under `weights`, over the
/// particles of positive weight, and its degrees of freedom.
fn chi_square(counts: &[u64], weights: &[f64]) -> (f64, usize) {
    let total = counts.iter().sum::<u64>() as f64;
    let cells: Vec<(f64, u64)> = weights
        .iter()
        .copied()
        .zip(counts.iter().copied())
        .filter(|(w, _)| *w > 0.0)
        .collect();
    let stat = cells
        .iter()
        .map(|&(w, c)| (c as f64 - total * w).powi(2) / (total * w))
        .sum();
    (stat, cells.len() - 1)
}

/// The upper 0.1 % point of the chi-square distribution (Wilson–Hilferty, z = 3.090).
fn chi_square_critical_0_001(dof: usize) -> f64 {
    let k = dof as f64;
    let z = 3.090;
    k * (1.0 - 2.0 / (9.0 * k) + z * (2.0 / (9.0 * k)).sqrt()).powi(3)
}

fn assert_unbiased(r: &dyn Resampler) {
    let weights = test_weights();
    let counts = pooled_counts(r, &weights, 5_000);
    for (i, (&w, &c)) in weights.iter().zip(&counts).enumerate() {
        assert!(
            w > 0.0 || c == 0,
            "{}: zero-weight particle {i} got {c} offspring",
            r.name()
        );
    }
    let (stat, dof) = chi_square(&counts, &weights);
    let critical = chi_square_critical_0_001(dof);
    assert!(
        stat < critical,
        "{}: chi-square {stat:.1} >= {critical:.1} ({dof} dof)",
        r.name()
    );
}

#[test]
fn multinomial_is_unbiased_in_distribution() {
    assert_unbiased(&Multinomial);
}

#[test]
fn rejection_is_unbiased_in_distribution() {
    assert_unbiased(&Rejection::default());
}

#[test]
fn metropolis_with_enough_steps_is_unbiased_in_distribution() {
    let weights = test_weights();
    let steps = Metropolis::steps_for(&weights, 1e-4);
    assert!(steps > 1);
    assert_unbiased(&Metropolis::new(steps));
}

#[test]
fn metropolis_with_one_step_is_detected_as_biased() {
    // The power check of the tests above: a one-step chain mostly stays where it started (uniform
    // over particles), far from the weights, and the same statistic must catch it.
    let weights = test_weights();
    let counts = pooled_counts(&Metropolis::new(1), &weights, 5_000);
    let (stat, dof) = chi_square(&counts, &weights);
    assert!(
        stat > 10.0 * chi_square_critical_0_001(dof),
        "chi-square {stat:.1}"
    );
}

#[test]
fn ordered_and_residual_resamplers_are_unbiased_in_distribution() {
    assert_unbiased(&Stratified);
    assert_unbiased(&Systematic);
    assert_unbiased(&Residual::new(ResidualRemainder::Systematic));
    assert_unbiased(&Residual::new(ResidualRemainder::Multinomial));
}

#[test]
fn metropolis_step_count_follows_murray_lee_jacob() {
    // Equal weights: β = 1, one step is enough.
    assert_eq!(Metropolis::steps_for(&[0.25; 4], 0.01), 1);
    // β = mean/max = 0.25 / 0.5 = 0.5: B = ⌈ln 0.01 / ln 0.5⌉ = ⌈6.64⌉ = 7.
    assert_eq!(Metropolis::steps_for(&[0.5, 0.25, 0.125, 0.125], 0.01), 7);
}

#[test]
fn counter_uniforms_feed_every_resampler_the_same_numbers_on_every_call() {
    let u = uniforms(99);
    assert_eq!(
        u.uniform(3, 7).to_bits(),
        uniforms(99).uniform(3, 7).to_bits()
    );
    assert_ne!(u.uniform(3, 7), u.uniform(3, 8));
}
