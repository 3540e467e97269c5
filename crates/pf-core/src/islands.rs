//! The host side of an island particle filter (Vergé, Dubarry, Del Moral & Moulines, "On
//! parallel implementation of sequential Monte Carlo methods: the island particle model",
//! Statistics and Computing 2015): a target's M samples split into islands (one per GPU), each a
//! whole filter with its own random numbers, combined on the host from their estimates.
//!
//! Each island is weighed per target by a log-weight the model gives (the likelihood of the
//! island's estimate, or its evidence): an island that has lost the target explains the frame
//! badly and weighs little. The estimate is the weighted mean of the islands' estimates (angles
//! on the circle), the spread that of the mixture of their posteriors. Every few frames the
//! islands are resampled by those weights (the island filter's island-level selection): an
//! island whose draw names another restarts from a resample of that island's particles.
//! pf-gpu's `engine::Islands` steps the islands and calls these.

use crate::batch::{BatchShape, weighted_means_and_spreads};
use crate::error::PfError;
use crate::random::CounterUniforms;
use crate::resample::{Resampler, Systematic};

/// The fewest samples an island may have.
pub const MIN_ISLAND_SAMPLES: usize = 2;

/// The samples of each of `islands` islands: `particles` split as evenly as possible.
pub fn island_sizes(particles: usize, islands: usize) -> Result<Vec<usize>, PfError> {
    if islands == 0 {
        return Err(PfError::InvalidConfig(
            "splitting samples into islands needs at least one island".into(),
        ));
    }
    if particles < islands * MIN_ISLAND_SAMPLES {
        return Err(PfError::InvalidConfig(format!(
            "{particles} samples cannot be split into {islands} islands: each island needs at \
             least {MIN_ISLAND_SAMPLES}"
        )));
    }
    Ok((0..islands)
        .map(|i| particles / islands + usize::from(i < particles % islands))
        .collect())
}

/// exp(x − max x), normalised; a NaN counts as −∞ (an island whose estimate cannot be weighed
/// weighs nothing), and all −∞ gives equal weights.
pub fn softmax(log_values: &[f64]) -> Vec<f64> {
    let clean: Vec<f64> = log_values
        .iter()
        .map(|&v| if v.is_nan() { f64::NEG_INFINITY } else { v })
        .collect();
    let max = clean.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if max == f64::NEG_INFINITY {
        return vec![1.0 / clean.len() as f64; clean.len()];
    }
    let exp: Vec<f64> = clean.iter().map(|v| (v - max).exp()).collect();
    let total: f64 = exp.iter().sum();
    exp.into_iter().map(|e| e / total).collect()
}

/// The log evidence of a frame over islands that weigh alike: the log of the mean of the islands'
/// evidence, log (1/G)·Σ_g exp(e_g), the estimate of the pooled samples. NaN when an island's is
/// NaN; −∞ when every island's is −∞ (or there is none).
pub fn pooled_log_evidence(islands: &[f64]) -> f64 {
    if islands.iter().any(|e| e.is_nan()) {
        return f64::NAN;
    }
    let max = islands.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if !max.is_finite() {
        return max;
    }
    let mean = islands.iter().map(|e| (e - max).exp()).sum::<f64>() / islands.len() as f64;
    max + mean.ln()
}

/// One island's results for a frame, every target: `[t·D + d]` and `[t]`.
#[derive(Debug, Clone, Copy)]
pub struct IslandEstimate<'a> {
    /// The island's estimates, `[t·D + d]`.
    pub estimates: &'a [f32],
    /// The island posterior's spread about them, `[t·D + d]`.
    pub spreads: &'a [f32],
    /// Each target's effective sample size in the island.
    pub ess: &'a [f64],
}

/// The islands' estimates combined, per target.
#[derive(Debug, Clone, PartialEq)]
pub struct Combined {
    /// The weighted mean of the islands' estimates, `[t·D + d]`.
    pub estimates: Vec<f32>,
    /// The spread of the mixture of the islands' posteriors (within islands and between them),
    /// `[t·D + d]`.
    pub spreads: Vec<f32>,
    /// The effective sample size of all islands' samples under the island weights,
    /// 1 / Σ_g (w_g² / ESS_g), `[t]`.
    pub ess: Vec<f64>,
    /// Each island's weight for each target, `[t·G + g]`, summing to 1 over g.
    pub weights: Vec<f64>,
}

/// Combines the islands' results of one frame: `log_weights[t·G + g]` weighs island g for
/// target t; `angular[d]` says which dimensions are angles.
pub fn combine(
    islands: &[IslandEstimate<'_>],
    log_weights: &[f64],
    dims: usize,
    angular: &[bool],
) -> Result<Combined, PfError> {
    let count = islands.len();
    let targets = islands.first().map_or(0, |i| i.ess.len());
    let consistent = islands.iter().all(|i| {
        i.ess.len() == targets
            && i.estimates.len() == targets * dims
            && i.spreads.len() == targets * dims
    });
    if count == 0 || !consistent || log_weights.len() != targets * count {
        return Err(PfError::InvalidConfig(format!(
            "combining {count} islands of {targets} targets × {dims} dimensions: the islands' \
             results or the {} log-weights do not fit",
            log_weights.len()
        )));
    }
    let shape = BatchShape::new(1, count, dims)?;
    let mut combined = Combined {
        estimates: Vec::with_capacity(targets * dims),
        spreads: Vec::with_capacity(targets * dims),
        ess: Vec::with_capacity(targets),
        weights: Vec::with_capacity(targets * count),
    };
    for t in 0..targets {
        let weights = softmax(&log_weights[t * count..(t + 1) * count]);
        // The islands' estimates of target t as the particles of one target, `[d·G + g]`.
        let mut estimates = vec![0.0f32; count * dims];
        for (g, island) in islands.iter().enumerate() {
            for d in 0..dims {
                estimates[d * count + g] = island.estimates[t * dims + d];
            }
        }
        let (mean, between) = weighted_means_and_spreads(&shape, &estimates, &weights, angular);
        for (d, between) in between.iter().enumerate() {
            let within: f64 = (islands.iter().zip(&weights))
                .map(|(i, w)| w * f64::from(i.spreads[t * dims + d]).powi(2))
                .sum();
            combined
                .spreads
                .push((within + f64::from(*between).powi(2)).sqrt() as f32);
        }
        let inverse: f64 = (islands.iter().zip(&weights))
            .map(|(i, w)| w * w / i.ess[t].max(1e-12))
            .sum();
        combined.estimates.extend(mean);
        combined.ess.push(1.0 / inverse);
        combined.weights.extend(weights);
    }
    Ok(combined)
}

/// Whether the islands exchange after frame `frames` (counted from 1), exchanging every
/// `every` frames (0: never).
pub fn exchange_due(every: u64, frames: u64) -> bool {
    every > 0 && frames.is_multiple_of(every)
}

/// The island-level selection for one target: island g takes island `sources[g]`, drawn by
/// systematic resampling of the island weights (a uniform from `seed`). An island drawn at
/// least once keeps its own particles; each extra copy of one replaces an island no draw names.
pub fn island_sources(weights: &[f64], seed: u64) -> Result<Vec<u32>, PfError> {
    let islands = weights.len();
    let key = [seed as u32, (seed >> 32) as u32];
    let mut draws = vec![0u32; islands];
    Systematic.resample(weights, &CounterUniforms::new(key, 0), &mut draws)?;
    let mut copies = vec![0usize; islands];
    for &d in &draws {
        copies[d as usize] += 1;
    }
    let mut extra: Vec<u32> = (0..islands)
        .flat_map(|g| std::iter::repeat_n(g as u32, copies[g].saturating_sub(1)))
        .collect();
    (copies.iter().enumerate())
        .map(|(g, &c)| match c {
            0 => extra
                .pop()
                .ok_or_else(|| PfError::InvalidConfig("the island draws do not add up".into())),
            _ => Ok(g as u32),
        })
        .collect()
}

/// `count` particles of target `t` drawn systematically by their weights from a batch's
/// `states` and `log_weights`, in one target's layout `[d·count + m]`.
pub fn resampled(
    shape: &BatchShape,
    states: &[f32],
    log_weights: &[f32],
    t: usize,
    count: usize,
    seed: u64,
) -> Result<Vec<f32>, PfError> {
    if t >= shape.targets
        || states.len() != shape.state_len()
        || log_weights.len() != shape.targets * shape.particles
    {
        return Err(PfError::InvalidConfig(format!(
            "resampling target {t} of {} targets: {} states and {} log-weights do not fit",
            shape.targets,
            states.len(),
            log_weights.len()
        )));
    }
    let row = &log_weights[t * shape.particles..(t + 1) * shape.particles];
    let weights = softmax(&row.iter().map(|&w| f64::from(w)).collect::<Vec<_>>());
    let mut ancestors = vec![0u32; count];
    let key = [seed as u32, (seed >> 32) as u32];
    Systematic.resample(&weights, &CounterUniforms::new(key, 1), &mut ancestors)?;
    let mut out = vec![0.0f32; shape.dims * count];
    for d in 0..shape.dims {
        for (m, &a) in ancestors.iter().enumerate() {
            out[d * count + m] = states[shape.state_index(t, d, a as usize)];
        }
    }
    Ok(out)
}

/// The islands' particles as one batch: per target, the islands' particles one after another,
/// each island's log-weights plus the log of its island weight (`island_weights[t·G + g]`;
/// equal weights when it is empty, before the first frame).
pub fn joined_particles(
    islands: &[(BatchShape, Vec<f32>, Vec<f32>)],
    island_weights: &[f64],
) -> Result<(BatchShape, Vec<f32>, Vec<f32>), PfError> {
    let count = islands.len();
    let (targets, dims) = islands
        .first()
        .map_or((0, 0), |(s, _, _)| (s.targets, s.dims));
    let fits = islands.iter().all(|(s, x, lw)| {
        (s.targets, s.dims) == (targets, dims)
            && x.len() == s.state_len()
            && lw.len() == s.targets * s.particles
    });
    if !fits {
        return Err(PfError::InvalidConfig(
            "joining islands of different targets or dimensions, or whose particles do not fit \
             their shapes"
                .into(),
        ));
    }
    let total: usize = islands.iter().map(|(s, _, _)| s.particles).sum();
    let shape = BatchShape::new(targets, total, dims)?;
    let mut states = vec![0.0f32; shape.state_len()];
    let mut log_weights = vec![0.0f32; targets * total];
    for t in 0..targets {
        let mut first = 0;
        for (g, (s, x, lw)) in islands.iter().enumerate() {
            let weight = (island_weights.get(t * count + g).copied()).unwrap_or(1.0 / count as f64);
            for m in 0..s.particles {
                for d in 0..dims {
                    states[shape.state_index(t, d, first + m)] = x[s.state_index(t, d, m)];
                }
                log_weights[t * total + first + m] = lw[t * s.particles + m] + weight.ln() as f32;
            }
            first += s.particles;
        }
    }
    Ok((shape, states, log_weights))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_split_evenly_and_too_few_is_an_error() {
        assert_eq!(island_sizes(7000, 2).unwrap(), vec![3500, 3500]);
        assert_eq!(island_sizes(7, 3).unwrap(), vec![3, 2, 2]);
        assert!(island_sizes(3, 2).is_err());
        assert!(island_sizes(100, 0).is_err());
    }

    #[test]
    fn pooled_evidence_is_the_log_of_the_islands_mean() {
        // Far from 0 too: log-mean-exp must not overflow.
        for e in [-3.0, 0.0, -1e4, 800.0] {
            assert!((pooled_log_evidence(&[e, e, e]) - e).abs() < 1e-9);
            let half = pooled_log_evidence(&[e, f64::NEG_INFINITY]);
            assert!((half - (e + 0.5f64.ln())).abs() < 1e-9);
        }
        let mixed = pooled_log_evidence(&[1.0f64.ln(), 3.0f64.ln()]);
        assert!((mixed - 2.0f64.ln()).abs() < 1e-12);
        assert!(pooled_log_evidence(&[0.0, f64::NAN]).is_nan());
        assert_eq!(pooled_log_evidence(&[]), f64::NEG_INFINITY);
        assert_eq!(
            pooled_log_evidence(&[f64::NEG_INFINITY; 2]),
            f64::NEG_INFINITY
        );
    }

    #[test]
    fn softmax_weighs_a_lost_island_near_zero() {
        let w = softmax(&[-1.0, -1.0]);
        assert_eq!(w, vec![0.5, 0.5]);
        let w = softmax(&[-0.5, -20.0, f64::NAN]);
        assert!(w[0] > 0.999_99 && w[2] == 0.0);
        assert_eq!(softmax(&[f64::NEG_INFINITY; 3]), vec![1.0 / 3.0; 3]);
    }

    #[test]
    fn combine_weighs_each_target_on_its_own() {
        // Two islands, two 1-D targets: island 0 explains target 0, island 1 target 1.
        let a = IslandEstimate {
            estimates: &[1.0, 10.0],
            spreads: &[0.1, 0.1],
            ess: &[50.0, 50.0],
        };
        let b = IslandEstimate {
            estimates: &[3.0, 20.0],
            spreads: &[0.1, 0.1],
            ess: &[50.0, 50.0],
        };
        let c = combine(&[a, b], &[0.0, -40.0, -40.0, 0.0], 1, &[false]).unwrap();
        assert!((c.estimates[0] - 1.0).abs() < 1e-4 && (c.estimates[1] - 20.0).abs() < 1e-4);
        assert!((c.weights[0] + c.weights[1] - 1.0).abs() < 1e-12);
        assert!(c.weights[0] > 0.999 && c.weights[3] > 0.999);
        // Equal weights: the mean of the two, and the spread grows by the gap between them.
        let c = combine(&[a, b], &[0.0; 4], 1, &[false]).unwrap();
        assert!((c.estimates[0] - 2.0).abs() < 1e-6);
        assert!(c.spreads[0] > 1.0 && (c.ess[0] - 100.0).abs() < 1e-9);
        assert!(combine(&[a, b], &[0.0; 3], 1, &[false]).is_err());
        assert!(combine(&[], &[], 1, &[false]).is_err());
    }

    #[test]
    fn sources_keep_drawn_islands_and_replace_the_rest() {
        assert_eq!(island_sources(&[1.0, 0.0], 9).unwrap(), vec![0, 0]);
        assert_eq!(island_sources(&[0.5, 0.5], 9).unwrap(), vec![0, 1]);
        let sources = island_sources(&[0.0, 0.0, 1.0], 4).unwrap();
        assert_eq!(sources, vec![2, 2, 2]);
    }

    #[test]
    fn joined_particles_keep_every_target_and_weigh_by_island() {
        let shape = BatchShape::new(2, 2, 1).unwrap();
        let a = (shape, vec![1.0, 2.0, 3.0, 4.0], vec![0.5f32.ln(); 4]);
        let b = (shape, vec![5.0, 6.0, 7.0, 8.0], vec![0.5f32.ln(); 4]);
        let (joined, states, log_weights) =
            joined_particles(&[a, b], &[0.25, 0.75, 0.5, 0.5]).unwrap();
        assert_eq!((joined.targets, joined.particles), (2, 4));
        assert_eq!(states, vec![1.0, 2.0, 5.0, 6.0, 3.0, 4.0, 7.0, 8.0]);
        let total: f32 = log_weights[..4].iter().map(|w| w.exp()).sum();
        assert!((total - 1.0).abs() < 1e-5);
        assert!((log_weights[2].exp() - 0.375).abs() < 1e-6);
        // Islands that do not fit are an error, not a panic.
        let other = (
            BatchShape::new(1, 2, 1).unwrap(),
            vec![1.0, 2.0],
            vec![0.0; 2],
        );
        let a = (shape, vec![1.0; 4], vec![0.0; 4]);
        assert!(joined_particles(&[a.clone(), other], &[]).is_err());
        assert!(joined_particles(&[(shape, vec![1.0; 3], vec![0.0; 4])], &[]).is_err());
        assert!(resampled(&shape, &a.1, &a.2, 2, 3, 1).is_err());
        assert!(resampled(&shape, &a.1[..3], &a.2, 0, 3, 1).is_err());
        assert_eq!(resampled(&shape, &a.1, &a.2, 1, 3, 1).unwrap().len(), 3);
    }
}
