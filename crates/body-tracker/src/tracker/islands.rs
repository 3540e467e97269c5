//! Several GPUs for one body: an island particle filter (Vergé, Dubarry, Del Moral & Moulines,
//! "On parallel implementation of sequential Monte Carlo methods: the island particle model",
//! Statistics and Computing 2015).
//!
//! The J samples are split into one island per GPU. Each island is a whole filter of its own on
//! its own GPU (resampling, diffusion, kinematics, likelihood, annealing layers and estimate in
//! one submission) with its own random numbers; the islands step at once, and only their
//! estimates come to the host. There they are combined: each island is weighed by the likelihood
//! of its estimate (an annealed filter gives no evidence estimate to weigh it by, and an island
//! that has lost the body explains the frame badly and so weighs little), and the pose is the
//! weighted mean of the islands' estimates (angles on the circle). Every few frames the islands
//! are resampled by those weights, as in the island filter's island-level selection: an island
//! whose draw names another takes a fresh resample of that island's particles, so that an island
//! that lost the body does not stay lost.
//!
//! Why this design: the earlier split kept one filter on the host and sent every layer's poses
//! to the GPUs and their sums back, a round trip per layer that made two GPUs slower than one.
//! Islands need nothing from each other within a frame.

use pf_core::batch::{BatchShape, weighted_means, weighted_spreads};
use pf_core::random::CounterUniforms;
use pf_core::resample::{Resampler, Systematic};
use pf_gpu::engine::FilterEngine;

use super::filter::FilterStep;
use crate::error::BodyError;
use crate::likelihood::{CapsuleLikelihoodParams, Rays, culled_sum_of_squared_distances_parallel};
use crate::skeleton::{ROOT_DOFS, Skeleton};

/// Frames between the islands' exchanges by default.
pub const DEFAULT_EXCHANGE_EVERY: u64 = 10;

/// The fewest samples an island may have.
pub const MIN_ISLAND_SAMPLES: usize = 2;

/// The samples of each of `islands` islands: `particles` split as evenly as possible.
pub fn island_sizes(particles: usize, islands: usize) -> Result<Vec<usize>, BodyError> {
    if islands == 0 {
        return Err(BodyError::InvalidInput(
            "splitting over GPUs needs at least one GPU".into(),
        ));
    }
    if particles < islands * MIN_ISLAND_SAMPLES {
        return Err(BodyError::InvalidInput(format!(
            "{particles} samples cannot be split over {islands} GPUs: each island needs at least {MIN_ISLAND_SAMPLES}"
        )));
    }
    Ok((0..islands)
        .map(|i| particles / islands + usize::from(i < particles % islands))
        .collect())
}

/// Which of a pose's values are angles (the root's rotations).
fn angular(dims: usize) -> Vec<bool> {
    (0..dims).map(|d| (3..ROOT_DOFS).contains(&d)).collect()
}

/// The islands' estimates combined.
#[derive(Debug, Clone, PartialEq)]
pub struct Combined {
    pub pose: Vec<f32>,
    /// The spread of the mixture of the islands' posteriors: within islands and between them.
    pub spread: Vec<f32>,
    /// The effective sample size of all islands' samples under the island weights,
    /// 1 / Σ_g (w_g² / ESS_g).
    pub ess: f64,
    /// Each island's weight, ∝ the likelihood of its estimate, summing to 1.
    pub weights: Vec<f64>,
}

/// Combines the islands' steps on this frame (see the module's documentation).
pub fn combine(
    skeleton: &Skeleton,
    rays: &Rays,
    params: CapsuleLikelihoodParams,
    steps: &[FilterStep],
) -> Result<Combined, BodyError> {
    let log_likelihoods = steps
        .iter()
        .map(|s| {
            // The GPU's M of the island's estimate, else the host's.
            let sum = if let Some(sum) = s.estimate_sum {
                sum
            } else {
                culled_sum_of_squared_distances_parallel(
                    &skeleton.capsules(&s.pose)?,
                    rays,
                    params.tau,
                )
            };
            Ok(params.log_likelihood(sum))
        })
        .collect::<Result<Vec<f64>, BodyError>>()?;
    let weights = softmax(&log_likelihoods);
    let (islands, dims) = (steps.len(), skeleton.dofs());
    let shape = BatchShape::new(1, islands, dims)?;
    // The islands' estimates as the particles of one target, `[d·G + g]`.
    let mut poses = vec![0.0f32; islands * dims];
    for (g, s) in steps.iter().enumerate() {
        for d in 0..dims {
            poses[d * islands + g] = s.pose[d];
        }
    }
    let angular = angular(dims);
    let pose = weighted_means(&shape, &poses, &weights, &angular);
    let between = weighted_spreads(&shape, &poses, &weights, &angular, &pose);
    let spread = (0..dims)
        .map(|d| {
            let within: f64 = steps
                .iter()
                .zip(&weights)
                .map(|(s, w)| w * f64::from(s.spread[d]).powi(2))
                .sum();
            (within + f64::from(between[d]).powi(2)).sqrt() as f32
        })
        .collect();
    let ess = 1.0
        / steps
            .iter()
            .zip(&weights)
            .map(|(s, w)| w * w / s.ess.max(1e-12))
            .sum::<f64>();
    Ok(Combined {
        pose,
        spread,
        ess,
        weights,
    })
}

/// exp(x − max x), normalised; a NaN counts as −∞ (an island whose estimate cannot be weighed
/// weighs nothing), and all −∞ gives equal weights.
fn softmax(log_values: &[f64]) -> Vec<f64> {
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

/// Whether the islands exchange after frame `frames` (counted from 1).
pub fn exchange_due(every: u64, frames: u64) -> bool {
    every > 0 && frames.is_multiple_of(every)
}

/// The islands' selection: island g takes island a_g, a_g drawn by systematic resampling of the
/// island weights (a uniform from `seed`); an island that draws another is restarted from a
/// resample (systematic, by its particles' weights) of that island's particles, at its own
/// size. Returns the draws.
pub fn exchange(
    engines: &mut [&mut FilterEngine],
    weights: &[f64],
    seed: u64,
) -> Result<Vec<u32>, BodyError> {
    let islands = engines.len();
    let key = [seed as u32, (seed >> 32) as u32];
    let mut draws = vec![0u32; islands];
    Systematic.resample(weights, &CounterUniforms::new(key, 0), &mut draws)?;
    // An island drawn at least once keeps its particles; each extra copy of one replaces an
    // island that no draw names (as many as there are extra copies).
    let mut copies = vec![0usize; islands];
    for &d in &draws {
        copies[d as usize] += 1;
    }
    let mut extra: Vec<u32> = (0..islands)
        .flat_map(|g| std::iter::repeat_n(g as u32, copies[g].saturating_sub(1)))
        .collect();
    let mut sources = Vec::with_capacity(islands);
    for (g, &c) in copies.iter().enumerate() {
        sources.push(match c {
            0 => extra
                .pop()
                .ok_or_else(|| BodyError::InvalidInput("the island draws do not add up".into()))?,
            _ => g as u32,
        });
    }
    for g in 0..islands {
        let source = sources[g] as usize;
        if source == g {
            continue;
        }
        let (shape, states, log_weights) = engines[source].particles()?;
        let target = engines[g].shape().particles;
        let restart = resampled(&shape, &states, &log_weights, target, seed ^ g as u64)?;
        engines[g].reset_target(0, &restart)?;
    }
    Ok(sources)
}

/// `count` particles drawn systematically from one target's particles by their weights, in the
/// batch layout `[d·count + m]`.
fn resampled(
    shape: &BatchShape,
    states: &[f32],
    log_weights: &[f32],
    count: usize,
    seed: u64,
) -> Result<Vec<f32>, BodyError> {
    let weights = softmax(
        &log_weights
            .iter()
            .map(|&w| f64::from(w))
            .collect::<Vec<_>>(),
    );
    let mut ancestors = vec![0u32; count];
    let key = [seed as u32, (seed >> 32) as u32];
    Systematic.resample(&weights, &CounterUniforms::new(key, 1), &mut ancestors)?;
    let mut out = vec![0.0f32; shape.dims * count];
    for d in 0..shape.dims {
        for (m, &a) in ancestors.iter().enumerate() {
            out[d * count + m] = states[shape.state_index(0, d, a as usize)];
        }
    }
    Ok(out)
}

/// The islands' particles as one set: one after another, each island's log-weights plus the log
/// of its island weight (equal weights before the first frame).
pub fn joined_particles(
    islands: &[(BatchShape, Vec<f32>, Vec<f32>)],
    island_weights: &[f64],
) -> Result<(BatchShape, Vec<f32>, Vec<f32>), BodyError> {
    let total: usize = islands.iter().map(|(s, _, _)| s.particles).sum();
    let dims = islands.first().map_or(0, |(s, _, _)| s.dims);
    let shape = BatchShape::new(1, total, dims)?;
    let mut states = vec![0.0f32; dims * total];
    let mut log_weights = Vec::with_capacity(total);
    let mut first = 0;
    for (g, (s, x, lw)) in islands.iter().enumerate() {
        let weight = island_weights
            .get(g)
            .copied()
            .unwrap_or(1.0 / islands.len() as f64);
        for d in 0..dims {
            for m in 0..s.particles {
                states[d * total + first + m] = x[s.state_index(0, d, m)];
            }
        }
        log_weights.extend(lw.iter().map(|&w| w + weight.ln() as f32));
        first += s.particles;
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
        let island_seed = super::super::filter::island_seed;
        assert_eq!(island_seed(5, 0), 5);
        assert_ne!(island_seed(5, 1), island_seed(5, 2));
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
    fn a_lost_island_is_restarted_from_the_good_one() {
        use pf_core::batch::BatchConfig;
        let island = |value: f32| {
            let shape = BatchShape::new(1, 50, 2).unwrap();
            let config = BatchConfig {
                shape,
                seed: 3,
                sigma: vec![0.1, 0.1],
                bounds: None,
                angular: vec![false, false],
                ess_threshold: f64::INFINITY,
                best: 0,
                annealing: Default::default(),
                motion: Default::default(),
            };
            let states: Vec<f32> = (0..100).map(|i| value + i as f32 * 1e-3).collect();
            FilterEngine::cpu(
                &config,
                pf_core::resample::ResamplerKind::Systematic,
                states,
            )
            .unwrap()
        };
        let (mut good, mut lost) = (island(1.0), island(50.0));
        let sources = exchange(&mut [&mut good, &mut lost], &[1.0, 0.0], 9).unwrap();
        assert_eq!(sources, vec![0, 0]);
        let (_, from_good, _) = good.particles().unwrap();
        let (_, restarted, log_weights) = lost.particles().unwrap();
        assert!(restarted.iter().all(|x| from_good.contains(x)));
        assert!(log_weights.windows(2).all(|w| w[0] == w[1]));
        // Equal weights: both islands keep their own particles.
        let before = lost.particles().unwrap().1;
        let sources = exchange(&mut [&mut good, &mut lost], &[0.5, 0.5], 9).unwrap();
        assert_eq!(sources, vec![0, 1]);
        assert_eq!(lost.particles().unwrap().1, before);
        assert!(exchange_due(10, 20) && !exchange_due(10, 21) && !exchange_due(0, 10));
    }
}
