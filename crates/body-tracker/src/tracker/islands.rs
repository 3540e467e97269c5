//! Several GPUs for one body: an island particle filter (Vergé, Dubarry, Del Moral & Moulines,
//! "On parallel implementation of sequential Monte Carlo methods: the island particle model",
//! Statistics and Computing 2015), on the engine's islands (`pf_gpu::engine::islands`, the host
//! math in `pf_core::islands`).
//!
//! The J samples are split into one island per GPU. Each island is a whole filter of its own on
//! its own GPU (resampling, diffusion, kinematics, likelihood, annealing layers and estimate in
//! one submission) with its own random numbers; the islands step at once, and only their
//! estimates come to the host. What is the body's own here is how an island is weighed: by the
//! likelihood of its estimate (an annealed filter gives no evidence estimate to weigh it by, and
//! an island that has lost the body explains the frame badly and so weighs little).
//!
//! Why this design: the earlier split kept one filter on the host and sent every layer's poses
//! to the GPUs and their sums back, a round trip per layer that made two GPUs slower than one.
//! Islands need nothing from each other within a frame.

use pf_core::islands::IslandEstimate;
pub use pf_core::islands::{exchange_due, island_sizes, joined_particles};
pub use pf_gpu::engine::islands::exchange;

use super::filter::FilterStep;
use crate::error::BodyError;
use crate::likelihood::{CapsuleLikelihoodParams, Rays, culled_sum_of_squared_distances_parallel};
use crate::skeleton::{ROOT_DOFS, Skeleton};

/// Ray-capsule tests a frame must give each GPU for an island to pay for its GPU. Unlike a face
/// step, a body step's time grows with its samples (the kinematics and the likelihood run per
/// sample and layer), and every split measured paid: on four NVIDIA H100s, `body track
/// --synthetic` at the defaults (1 500 samples × 8 layers × 1 040 points × 48 capsules, 0.6 G
/// tests a frame) ran at 231, 333 and 428 frames/s on one, two and four GPUs (0.15 G tests a
/// GPU at four); 7 000 samples at 1024×768 (40 G) at 31.4, 59.8 and 110.6. Below the smallest
/// share measured to pay, one GPU.
pub const TESTS_PER_GPU: f64 = 1.0e8;

/// How many of `available` GPUs a frame of `points` points pays for under `config`: its
/// ray-capsule tests (samples × annealing layers × points × capsules) over [`TESTS_PER_GPU`], at
/// least one, at most one per sample.
pub fn gpus_for_load(
    skeleton: &Skeleton,
    config: &super::TrackerConfig,
    points: usize,
    available: usize,
) -> usize {
    let tests = config.particles as f64
        * config.annealing.layers.max(1) as f64
        * points.min(config.max_points) as f64
        * skeleton.capsule_count() as f64;
    pf_gpu::load::gpus_for_work(tests, TESTS_PER_GPU, available.min(config.particles.max(1)))
}

/// Frames between the islands' exchanges by default.
pub const DEFAULT_EXCHANGE_EVERY: u64 = 10;

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

/// Combines the islands' steps on this frame, each weighed by the likelihood of its estimate
/// (the GPU's M of it where the step computed it, else the host's).
pub fn combine(
    skeleton: &Skeleton,
    rays: &Rays,
    params: CapsuleLikelihoodParams,
    steps: &[FilterStep],
) -> Result<Combined, BodyError> {
    let log_likelihoods = steps
        .iter()
        .map(|s| {
            let sum = match s.estimate_sum {
                Some(sum) => sum,
                None => culled_sum_of_squared_distances_parallel(
                    &skeleton.capsules(&s.pose)?,
                    rays,
                    params.tau,
                ),
            };
            Ok(params.log_likelihood(sum))
        })
        .collect::<Result<Vec<f64>, BodyError>>()?;
    let estimates: Vec<IslandEstimate<'_>> = steps
        .iter()
        .map(|s| IslandEstimate {
            estimates: &s.pose,
            spreads: &s.spread,
            ess: std::slice::from_ref(&s.ess),
        })
        .collect();
    let dims = skeleton.dofs();
    let combined = pf_core::islands::combine(&estimates, &log_likelihoods, dims, &angular(dims))?;
    Ok(Combined {
        pose: combined.estimates,
        spread: combined.spreads,
        ess: combined.ess[0],
        weights: combined.weights,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use pf_core::batch::BatchShape;
    use pf_gpu::engine::FilterEngine;

    #[test]
    fn islands_only_where_the_tests_pay_for_them() {
        let skeleton = crate::human::human_skeleton(48).unwrap();
        let defaults = super::super::TrackerConfig::default();
        // The synthetic default (about 1 040 points, 0.6 G tests) takes four; 100 samples of
        // it (40 M) one; the paper's frame of 43 000 points at 7 000 samples four.
        assert_eq!(gpus_for_load(&skeleton, &defaults, 1040, 4), 4);
        let light = super::super::TrackerConfig {
            particles: 100,
            ..defaults.clone()
        };
        assert_eq!(gpus_for_load(&skeleton, &light, 1040, 4), 1);
        let paper = super::super::TrackerConfig {
            particles: 7000,
            max_points: 50_000,
            ..defaults.clone()
        };
        assert_eq!(gpus_for_load(&skeleton, &paper, 43_000, 4), 4);
        assert_eq!(gpus_for_load(&skeleton, &paper, 43_000, 1), 1);
        // Points beyond max_points are not weighed, so they do not count.
        assert_eq!(
            gpus_for_load(&skeleton, &defaults, 10_000_000, 4),
            gpus_for_load(&skeleton, &defaults, defaults.max_points, 4)
        );
        let few = super::super::TrackerConfig {
            particles: 2,
            ..paper
        };
        assert!(gpus_for_load(&skeleton, &few, 43_000, 4) <= 2);
    }

    #[test]
    fn island_seeds_keep_the_first_and_differ_between_islands() {
        let island_seed = super::super::filter::island_seed;
        assert_eq!(island_seed(5, 0), 5);
        assert_ne!(island_seed(5, 1), island_seed(5, 2));
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
        assert_eq!(sources, vec![vec![0, 0]]);
        let (_, from_good, _) = good.particles().unwrap();
        let (_, restarted, log_weights) = lost.particles().unwrap();
        assert!(restarted.iter().all(|x| from_good.contains(x)));
        assert!(log_weights.windows(2).all(|w| w[0] == w[1]));
        // Equal weights: both islands keep their own particles.
        let before = lost.particles().unwrap().1;
        let sources = exchange(&mut [&mut good, &mut lost], &[0.5, 0.5], 9).unwrap();
        assert_eq!(sources, vec![vec![0, 1]]);
        assert_eq!(lost.particles().unwrap().1, before);
        assert!(exchange_due(10, 20) && !exchange_due(10, 21) && !exchange_due(0, 10));
    }
}
