//! A likelihood over one state, `log p(z | x)`, for the closures of `BatchFilter::step` and the
//! tests; `GaussianObservation` is the toy model's (`pf_gpu::toy`).

use nalgebra::SVector;
use rayon::prelude::*;

use crate::particles::ParticleSet;

/// The observation model, in the log domain: `log p(z_t | x)` up to a constant shared by all
/// particles of the step. A tracker builds one per frame (it borrows the frame).
pub trait Likelihood<const D: usize>: Sync {
    /// log p(z | x) of the current observation for one state, up to a constant.
    fn log_likelihood(&self, state: &SVector<f32, D>) -> f32;

    /// The log-likelihood of every particle into `out`; by default in parallel with rayon. A
    /// tracker overrides it to batch work (or to run it on the GPU).
    fn log_likelihoods(&self, particles: &ParticleSet<D>, out: &mut [f32]) {
        out.par_iter_mut()
            .with_min_len(64)
            .enumerate()
            .for_each(|(i, o)| *o = self.log_likelihood(&particles.state(i)));
    }
}

/// A Gaussian likelihood around an observed state with one standard deviation per dimension
/// (angle dimensions compared the short way round): the toy model of the demo and the tests.
#[derive(Debug, Clone, PartialEq)]
pub struct GaussianObservation<const D: usize> {
    /// The observed state z.
    pub observed: SVector<f32, D>,
    /// The observation σ per dimension.
    pub sigma: SVector<f32, D>,
    /// Which dimensions are angles (their differences are taken the short way round).
    pub space: crate::estimate::StateSpace<D>,
}

impl<const D: usize> Likelihood<D> for GaussianObservation<D> {
    fn log_likelihood(&self, state: &SVector<f32, D>) -> f32 {
        let diff = self.space.difference(state, &self.observed);
        let mut sum = 0.0f32;
        for d in 0..D {
            let z = diff[d] / self.sigma[d];
            sum += z * z;
        }
        -0.5 * sum
    }
}
