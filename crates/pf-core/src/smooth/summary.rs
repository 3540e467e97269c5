//! A smoothed (or filtered) frame's summary per value: the weighted mean, on the circle for an
//! angle, and the 95 % credible interval from the weighted 2.5 % and 97.5 % quantiles.

use super::Cloud;
use crate::batch::wrap_angle_floor;
use crate::error::PfError;

/// One value's posterior summary.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Summary {
    /// The weighted mean (on the circle for an angle).
    pub mean: f32,
    /// The weighted 2.5 % quantile.
    pub lower: f32,
    /// The weighted 97.5 % quantile.
    pub upper: f32,
}

/// The mean and 95 % credible interval of every dimension of `cloud` under `weights`. An angle's
/// quantiles are taken on its differences from the circular mean (wrapped), so an interval
/// across ±π stays narrow; its ends may lie outside [−π, π). An error for weights that are not
/// one per particle, or a cloud whose states are not its drift's dimensions × its particles.
pub fn summarise(
    cloud: &Cloud,
    weights: &[f64],
    angular: &[bool],
) -> Result<Vec<Summary>, PfError> {
    let (dims, particles) = (cloud.drift.len(), cloud.particles());
    if cloud.states.len() != dims * particles {
        return Err(PfError::InvalidConfig(format!(
            "a cloud of {} states is not {dims} dimensions x {particles} particles",
            cloud.states.len()
        )));
    }
    (0..dims)
        .map(|d| summarise_value(cloud, weights, angular, d))
        .collect()
}

/// Value `d`'s summary alone (what [`summarise`] gives for it): a blocked smoother's value has
/// weights of its own, so it is summarised on its own. An error names a value the cloud does not
/// have or weights that are not one per particle.
pub fn summarise_value(
    cloud: &Cloud,
    weights: &[f64],
    angular: &[bool],
    d: usize,
) -> Result<Summary, PfError> {
    let particles = cloud.particles();
    if weights.len() != particles || cloud.states.len() < (d + 1) * particles {
        return Err(PfError::InvalidConfig(format!(
            "summarising value {d} of a cloud of {} states and {particles} particles with {} weights",
            cloud.states.len(),
            weights.len()
        )));
    }
    Ok(value_summary(cloud, weights, angular, d))
}

/// One value's weighted mean, on the circle for an angle.
fn value_mean(xs: &[f32], weights: &[f64], is_angle: bool) -> f64 {
    if is_angle {
        let (s, c) = xs.iter().zip(weights).fold((0.0, 0.0), |(s, c), (&x, &w)| {
            (s + w * f64::from(x).sin(), c + w * f64::from(x).cos())
        });
        s.atan2(c)
    } else {
        xs.iter()
            .zip(weights)
            .map(|(&x, &w)| w * f64::from(x))
            .sum()
    }
}

/// [`summarise_value`] of a cloud already checked against its weights and values. Particles of
/// zero weight are left out of the sort: they move no cumulative sum (a cloud smoothed from the
/// ancestry has most of its weights zero, and the sort is the summary's cost).
pub(super) fn value_summary(cloud: &Cloud, weights: &[f64], angular: &[bool], d: usize) -> Summary {
    let particles = cloud.particles();
    let xs = &cloud.states[d * particles..(d + 1) * particles];
    let is_angle = angular.get(d).copied().unwrap_or(false);
    let mean = value_mean(xs, weights, is_angle);
    let mut offsets: Vec<(f64, f64)> = (xs.iter().zip(weights))
        .filter(|(_, w)| **w != 0.0)
        .map(|(&x, &w)| {
            let e = f64::from(x) - mean;
            let e = if is_angle {
                f64::from(wrap_angle_floor(e as f32))
            } else {
                e
            };
            (e, w)
        })
        .collect();
    offsets.sort_by(|a, b| a.0.total_cmp(&b.0));
    Summary {
        mean: mean as f32,
        lower: (mean + weighted_quantile(&offsets, 0.025)) as f32,
        upper: (mean + weighted_quantile(&offsets, 0.975)) as f32,
    }
}

/// The smallest value whose cumulative weight reaches `q` (values sorted, weights summing to 1).
fn weighted_quantile(sorted: &[(f64, f64)], q: f64) -> f64 {
    let mut cumulative = 0.0;
    for &(value, weight) in sorted {
        cumulative += weight;
        if cumulative >= q {
            return value;
        }
    }
    sorted.last().map_or(f64::NAN, |&(value, _)| value)
}
