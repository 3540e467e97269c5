//! Point estimates of a weighted particle set.
//!
//! Angle dimensions (marked in [`StateSpace`]) are averaged on the circle — the weighted mean of
//! unit vectors, `atan2(Σ w sin θ, Σ w cos θ)` — so that particles at +179° and −179° average to
//! 180°, not 0°. Sums are accumulated in f64.

use nalgebra::SVector;

use crate::error::PfError;
use crate::particles::ParticleSet;

/// Which state dimensions are angles in radians (wrapped to (−π, π]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StateSpace<const D: usize> {
    /// Whether each dimension is an angle.
    pub angular: [bool; D],
}

impl<const D: usize> Default for StateSpace<D> {
    fn default() -> Self {
        Self::euclidean()
    }
}

impl<const D: usize> StateSpace<D> {
    /// No angle dimension.
    pub fn euclidean() -> Self {
        Self {
            angular: [false; D],
        }
    }

    /// The listed dimensions are angles; an index ≥ D is an error.
    pub fn with_angles(dims: &[usize]) -> Result<Self, PfError> {
        let mut angular = [false; D];
        for &d in dims {
            if d >= D {
                return Err(PfError::InvalidConfig(format!(
                    "angle dimension {d} is out of range for a {D}-D state"
                )));
            }
            angular[d] = true;
        }
        Ok(Self { angular })
    }

    /// Wraps the angle dimensions of `x` into (−π, π].
    pub fn wrap(&self, x: &mut SVector<f32, D>) {
        for d in 0..D {
            if self.angular[d] {
                x[d] = wrap_angle(x[d]);
            }
        }
    }

    /// The difference `a − b`, with angle dimensions taken the short way round.
    pub fn difference(&self, a: &SVector<f32, D>, b: &SVector<f32, D>) -> SVector<f32, D> {
        let mut diff = a - b;
        self.wrap(&mut diff);
        diff
    }
}

/// An angle in (−π, π].
pub fn wrap_angle(theta: f32) -> f32 {
    if !theta.is_finite() {
        return theta;
    }
    let pi = std::f32::consts::PI;
    let wrapped = (theta + pi).rem_euclid(std::f32::consts::TAU) - pi;
    if wrapped <= -pi {
        wrapped + std::f32::consts::TAU
    } else {
        wrapped
    }
}

/// The weighted mean of the particles listed in `indices` (all of them when `None`), with those
/// particles' weights renormalised to sum to 1.
fn weighted_mean_of<const D: usize>(
    particles: &ParticleSet<D>,
    weights: &[f64],
    indices: Option<&[usize]>,
    space: &StateSpace<D>,
) -> SVector<f32, D> {
    let mut linear = [0.0f64; D];
    let mut sin = [0.0f64; D];
    let mut cos = [0.0f64; D];
    let mut total = 0.0f64;
    let mut add = |i: usize| {
        let w = weights[i];
        total += w;
        for d in 0..D {
            let x = f64::from(particles.dim(d)[i]);
            if space.angular[d] {
                sin[d] += w * x.sin();
                cos[d] += w * x.cos();
            } else {
                linear[d] += w * x;
            }
        }
    };
    match indices {
        Some(list) => list.iter().for_each(|&i| add(i)),
        None => (0..particles.len()).for_each(&mut add),
    }
    SVector::from_fn(|d, _| {
        if space.angular[d] {
            sin[d].atan2(cos[d]) as f32
        } else if total > 0.0 {
            (linear[d] / total) as f32
        } else {
            0.0
        }
    })
}

fn check_lengths<const D: usize>(
    particles: &ParticleSet<D>,
    weights: &[f64],
) -> Result<(), PfError> {
    if weights.len() != particles.len() {
        return Err(PfError::LengthMismatch {
            what: "weights",
            expected: particles.len(),
            got: weights.len(),
        });
    }
    Ok(())
}

/// The weighted mean of all particles (eq. 1 of the body paper).
pub fn weighted_mean<const D: usize>(
    particles: &ParticleSet<D>,
    weights: &[f64],
    space: &StateSpace<D>,
) -> Result<SVector<f32, D>, PfError> {
    check_lengths(particles, weights)?;
    Ok(weighted_mean_of(particles, weights, None, space))
}

/// The weighted mean of the `best` heaviest particles, their weights renormalised (eq. 14 of the
/// face paper). Ties are broken by the lower index, so the result is deterministic.
pub fn best_weighted_mean<const D: usize>(
    particles: &ParticleSet<D>,
    weights: &[f64],
    best: usize,
    space: &StateSpace<D>,
) -> Result<SVector<f32, D>, PfError> {
    check_lengths(particles, weights)?;
    if best == 0 {
        return Err(PfError::InvalidConfig(
            "the best-M' estimate needs M' >= 1".into(),
        ));
    }
    let order = heaviest(weights, best);
    Ok(weighted_mean_of(particles, weights, Some(&order), space))
}

/// The indices of the `best` heaviest weights (all when `best` ≥ len), ties to the lower index:
/// the selection rule of the best-M′ estimate, shared with `batch::best_weighted_means`.
pub fn heaviest(weights: &[f64], best: usize) -> Vec<usize> {
    let best = best.min(weights.len());
    let mut order: Vec<usize> = (0..weights.len()).collect();
    let heavier_first = |&a: &usize, &b: &usize| weights[b].total_cmp(&weights[a]).then(a.cmp(&b));
    if best > 0 && best < order.len() {
        order.select_nth_unstable_by(best - 1, heavier_first);
    }
    order.truncate(best);
    order
}

/// The state of the heaviest particle (lowest index on ties).
pub fn max_weight<const D: usize>(
    particles: &ParticleSet<D>,
    weights: &[f64],
) -> Result<SVector<f32, D>, PfError> {
    check_lengths(particles, weights)?;
    let heaviest = weights
        .iter()
        .enumerate()
        .fold(0, |best, (i, &w)| if w > weights[best] { i } else { best });
    Ok(particles.state(heaviest))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrap_angle_maps_into_half_open_interval() {
        use std::f32::consts::PI;
        assert_eq!(wrap_angle(0.0), 0.0);
        assert!((wrap_angle(3.0 * PI) - PI).abs() < 1e-5);
        assert!((wrap_angle(-PI) - PI).abs() < 1e-5);
        assert!((wrap_angle(2.0 * PI + 0.5) - 0.5).abs() < 1e-5);
        assert!((wrap_angle(-2.0 * PI - 0.5) + 0.5).abs() < 1e-5);
    }

    #[test]
    fn angle_mean_crosses_the_wrap() {
        let deg = std::f32::consts::PI / 180.0;
        let set = ParticleSet::<2>::from_fn(2, |i| {
            let a = if i == 0 { 179.0 * deg } else { -179.0 * deg };
            nalgebra::vector![a, i as f32]
        })
        .unwrap();
        let space = StateSpace::with_angles(&[0]).unwrap();
        let mean = weighted_mean(&set, &[0.5, 0.5], &space).unwrap();
        assert!(mean[0].abs() > 179.9 * deg, "angle mean {}", mean[0] / deg);
        assert!((mean[1] - 0.5).abs() < 1e-6);
        // Uneven weights pull the circular mean toward the heavier particle, across the wrap.
        let mean = weighted_mean(&set, &[0.75, 0.25], &space).unwrap();
        assert!((mean[0] - 179.5 * deg).abs() < 1e-3, "{}", mean[0] / deg);
    }

    #[test]
    fn best_mean_uses_only_the_heaviest() {
        let set = ParticleSet::<1>::from_fn(4, |i| nalgebra::vector![i as f32 * 10.0]).unwrap();
        let w = [0.1, 0.4, 0.1, 0.4];
        let space = StateSpace::euclidean();
        let best2 = best_weighted_mean(&set, &w, 2, &space).unwrap();
        assert!((best2[0] - 20.0).abs() < 1e-5);
        let best1 = best_weighted_mean(&set, &w, 1, &space).unwrap();
        assert_eq!(best1[0], 10.0, "tie goes to the lower index");
        assert_eq!(max_weight(&set, &w).unwrap()[0], 10.0);
        let all = best_weighted_mean(&set, &w, 100, &space).unwrap();
        assert!((all[0] - weighted_mean(&set, &w, &space).unwrap()[0]).abs() < 1e-5);
        assert!(best_weighted_mean(&set, &w, 0, &space).is_err());
    }
}
