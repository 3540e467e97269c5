//! Log-weights at the extremes: no NaN ever, and the right typed error where there is nothing to
//! normalise.

use pf_core::PfError;
use pf_core::weights::{effective_sample_size, log_sum_exp, normalise};
use proptest::prelude::*;

fn normalised(log_weights: &[f32]) -> Result<Vec<f64>, PfError> {
    let mut w = vec![0.0; log_weights.len()];
    normalise(log_weights, &mut w)?;
    Ok(w)
}

#[test]
fn all_equal_huge_negative_log_weights_give_uniform_weights() {
    let w = normalised(&[-1e30; 5]).unwrap();
    for x in &w {
        assert!((x - 0.2).abs() < 1e-12, "{w:?}");
    }
    assert!((effective_sample_size(&w) - 5.0).abs() < 1e-9);
}

#[test]
fn a_huge_negative_log_weight_next_to_a_finite_one_gets_zero_weight() {
    let w = normalised(&[-1e30, 0.0, -1e30]).unwrap();
    assert_eq!(w, vec![0.0, 1.0, 0.0]);
    assert!((effective_sample_size(&w) - 1.0).abs() < 1e-12);
}

#[test]
fn one_finite_among_minus_infinity_takes_all_the_weight() {
    let w = normalised(&[f32::NEG_INFINITY, f32::NEG_INFINITY, 5.0, f32::NEG_INFINITY]).unwrap();
    assert_eq!(w, vec![0.0, 0.0, 1.0, 0.0]);
}

#[test]
fn extreme_finite_log_weights_do_not_overflow() {
    let w = normalised(&[f32::MAX, -f32::MAX, f32::MAX, 0.0]).unwrap();
    assert_eq!(w, vec![0.5, 0.0, 0.5, 0.0]);
    let lse = log_sum_exp(&[f32::MAX, f32::MAX]).unwrap();
    assert!(
        lse.log_sum.is_finite(),
        "f64 accumulation keeps log(2·e^MAX) finite"
    );
}

#[test]
fn all_minus_infinity_is_all_weights_zero() {
    assert_eq!(
        normalised(&[f32::NEG_INFINITY; 3]),
        Err(PfError::AllWeightsZero { particles: 3 })
    );
}

#[test]
fn nan_is_named_with_its_particle() {
    assert_eq!(
        normalised(&[0.0, -1.0, f32::NAN, f32::NEG_INFINITY]),
        Err(PfError::NanLogWeight { particle: 2 })
    );
    // A NaN wins over "all zero": the NaN is the real cause.
    assert_eq!(
        normalised(&[f32::NEG_INFINITY, f32::NAN]),
        Err(PfError::NanLogWeight { particle: 1 })
    );
}

#[test]
fn plus_infinity_is_an_error_not_a_nan() {
    assert_eq!(
        normalised(&[0.0, f32::INFINITY]),
        Err(PfError::InfiniteLogWeight { particle: 1 })
    );
}

#[test]
fn empty_and_mismatched_buffers_are_errors() {
    assert_eq!(normalised(&[]), Err(PfError::EmptyParticleSet));
    let mut short = [0.0; 1];
    assert!(matches!(
        normalise(&[0.0, 0.0], &mut short),
        Err(PfError::LengthMismatch { .. })
    ));
}

fn log_weight() -> impl Strategy<Value = f32> {
    prop_oneof![
        4 => -50.0..50.0f32,
        1 => Just(f32::NEG_INFINITY),
        1 => Just(-1e30f32),
        1 => Just(-f32::MAX),
        1 => Just(f32::MAX),
        1 => -1e38..1e38f32,
    ]
}

proptest! {
    #[test]
    fn normalised_weights_are_finite_sum_to_one_and_keep_their_order(
        log_weights in prop::collection::vec(log_weight(), 1..200)
    ) {
        match normalised(&log_weights) {
            Ok(w) => {
                prop_assert!(w.iter().all(|x| x.is_finite() && *x >= 0.0));
                prop_assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-9);
                let ess = effective_sample_size(&w);
                prop_assert!(ess >= 1.0 - 1e-9 && ess <= w.len() as f64 + 1e-9);
                for i in 0..w.len() {
                    for j in 0..w.len() {
                        if log_weights[i] < log_weights[j] {
                            prop_assert!(w[i] <= w[j]);
                        }
                    }
                }
            }
            Err(e) => {
                prop_assert!(log_weights.iter().all(|&x| x == f32::NEG_INFINITY));
                prop_assert_eq!(e, PfError::AllWeightsZero { particles: log_weights.len() });
            }
        }
    }
}
