//! A track's confidence that it is on its face ([`super::FaceEstimate::confidence`]): its fit
//! against its template's fit off its face, times how sharply the frame's likelihood tells the
//! particles apart.
//!
//! Why the second factor: a track that has slid off its face onto smooth skin, an ear or dark
//! background can still fit its template about as well as on the face (a turned pose explains
//! the smooth patch), but there the likelihood barely changes from one particle to the next. The
//! survival rule tempers each annealing layer so that its effective sample size is `rate`·M;
//! where even the full likelihood (β at its cap) leaves more than that, the likelihood is too
//! flat for the rule to bite. On Megamind.avi (CPU defaults, 344 tracking rows judged against
//! MediaPipe's face mesh or face detector, gaps of up to 8 frames bridged: docs/ACCURACY.md
//! "Tracks on faces") the rows on a face had a last
//! layer's ESS of 500 of 1 000 (the rule's target) up to the 75th percentile and 764 at the
//! 95th, the rows off a face 613–951 (5th–95th).

use pf_core::anneal::{Annealing, Tempering};

/// How sharply a frame's likelihood tells the particles apart, in [0, 1], from the last annealing
/// layer's effective sample size `ess` of `particles`: 1 where the survival rule held the ESS at
/// its target `rate`·M (or below), falling linearly to 0 as the ESS reaches M at the rule's
/// largest β (a likelihood equal for every particle). 1 for fixed tempering, whose ESS has no
/// target to compare with.
pub fn likelihood_sharpness(ess: f64, particles: usize, annealing: &Annealing) -> f64 {
    let Tempering::Survival { rate, .. } = annealing.tempering else {
        return 1.0;
    };
    let rate = f64::from(rate);
    // A rate of 1 or more (or NaN) sets no target below M.
    if particles == 0 || rate.is_nan() || rate >= 1.0 || !ess.is_finite() {
        return 1.0;
    }
    let flat = ess / particles as f64;
    ((1.0 - flat) / (1.0 - rate)).clamp(0.0, 1.0)
}

/// The confidence of a fit with ε `error` by a template whose ε off its face is `off_face_error`,
/// under a likelihood of [`likelihood_sharpness`] `sharpness`: (1 − ε/ε_off) · sharpness, in
/// [0, 1] (0 for a template without an off-face fit).
pub fn confidence(error: f64, off_face_error: f64, sharpness: f64) -> f32 {
    if off_face_error > 0.0 {
        ((1.0 - error / off_face_error).clamp(0.0, 1.0) * sharpness.clamp(0.0, 1.0)) as f32
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn survival(rate: f32) -> Annealing {
        Annealing::survival(5, rate, 0.6)
    }

    proptest! {
        #[test]
        fn sharpness_is_one_at_the_rules_target_and_falls_to_zero_at_m(
            particles in 1usize..5000,
            rate in 0.05f32..0.95,
            a in 0.0f64..1.0,
            b in 0.0f64..1.0,
        ) {
            let m = particles as f64;
            let annealing = survival(rate);
            let target = f64::from(rate) * m;
            prop_assert_eq!(likelihood_sharpness(target * a, particles, &annealing), 1.0);
            prop_assert!(likelihood_sharpness(m, particles, &annealing).abs() < 1e-9);
            // Monotone: a flatter likelihood (larger ESS) is never sharper.
            let (lo, hi) = (a.min(b) * m, a.max(b) * m);
            prop_assert!(likelihood_sharpness(hi, particles, &annealing)
                <= likelihood_sharpness(lo, particles, &annealing));
        }

        #[test]
        fn confidence_stays_in_the_unit_interval(
            error in 0.0f64..2.0,
            off in 0.0f64..1.0,
            sharpness in -1.0f64..2.0,
        ) {
            let c = confidence(error, off, sharpness);
            prop_assert!((0.0..=1.0).contains(&c), "{c}");
            if off > 0.0 && error < off && sharpness > 0.0 {
                prop_assert!(c > 0.0);
            }
        }
    }

    #[test]
    fn fixed_tempering_and_odd_inputs_leave_the_fit_alone() {
        let fixed = Annealing {
            tempering: Tempering::Fixed(vec![1.0; 3]),
            ..survival(0.5)
        };
        assert_eq!(likelihood_sharpness(999.0, 1000, &fixed), 1.0);
        assert_eq!(likelihood_sharpness(f64::NAN, 1000, &survival(0.5)), 1.0);
        assert_eq!(likelihood_sharpness(500.0, 0, &survival(0.5)), 1.0);
        assert_eq!(likelihood_sharpness(750.0, 1000, &survival(0.5)), 0.5);
        assert_eq!(confidence(0.1, 0.0, 1.0), 0.0);
        assert_eq!(confidence(0.05, 0.2, 0.5), 0.375);
    }
}
