//! What a tracker plugs into the filter: its dynamics (diffusion) and its likelihood.

use nalgebra::{SMatrix, SVector};
use rayon::prelude::*;

use crate::error::PfError;
use crate::particles::ParticleSet;
use crate::random::RandomStream;

/// The motion model: moves one particle one step forward, drawing its noise from `noise`.
///
/// The filter calls it for the particles in index order with the target's diffusion stream, so
/// a run is reproducible from its seed.
pub trait Dynamics<const D: usize>: Send + Sync {
    /// Moves one particle's state one step, drawing from `noise`.
    fn propagate(&self, state: &mut SVector<f32, D>, noise: &mut RandomStream);
}

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

/// Random-walk diffusion with one standard deviation per dimension and optional bounds:
/// `x_d ← clamp(x_d + σ_d·n_d, lo_d, hi_d)`, the diffusion of both papers.
#[derive(Debug, Clone, PartialEq)]
pub struct GaussianDiffusion<const D: usize> {
    sigma: SVector<f32, D>,
    bounds: Option<(SVector<f32, D>, SVector<f32, D>)>,
}

impl<const D: usize> GaussianDiffusion<D> {
    /// Errors when a σ is negative or not finite.
    pub fn new(sigma: SVector<f32, D>) -> Result<Self, PfError> {
        if let Some(d) = (0..D).find(|&d| !(sigma[d].is_finite() && sigma[d] >= 0.0)) {
            return Err(PfError::InvalidConfig(format!(
                "diffusion sigma of dimension {d} is {}, expected a finite value >= 0",
                sigma[d]
            )));
        }
        Ok(Self {
            sigma,
            bounds: None,
        })
    }

    /// Clamps every propagated state into [lower, upper]; errors when lower > upper anywhere.
    pub fn with_bounds(
        mut self,
        lower: SVector<f32, D>,
        upper: SVector<f32, D>,
    ) -> Result<Self, PfError> {
        if let Some(d) =
            (0..D).find(|&d| lower[d].is_nan() || upper[d].is_nan() || lower[d] > upper[d])
        {
            return Err(PfError::InvalidConfig(format!(
                "diffusion bounds of dimension {d} are [{}, {}]",
                lower[d], upper[d]
            )));
        }
        self.bounds = Some((lower, upper));
        Ok(self)
    }

    /// The diffusion σ per dimension.
    pub fn sigma(&self) -> &SVector<f32, D> {
        &self.sigma
    }

    /// The clamping bounds, when set.
    pub fn bounds(&self) -> Option<&(SVector<f32, D>, SVector<f32, D>)> {
        self.bounds.as_ref()
    }
}

impl<const D: usize> Dynamics<D> for GaussianDiffusion<D> {
    fn propagate(&self, state: &mut SVector<f32, D>, noise: &mut RandomStream) {
        for d in 0..D {
            state[d] += self.sigma[d] * noise.gaussian_f32();
        }
        if let Some((lo, hi)) = &self.bounds {
            for d in 0..D {
                state[d] = state[d].clamp(lo[d], hi[d]);
            }
        }
    }
}

/// Linear-Gaussian dynamics `x ← A·x + σ ⊙ n`: a constant-velocity model, or the model of the
/// Kalman-filter check.
#[derive(Debug, Clone, PartialEq)]
pub struct LinearGaussian<const D: usize> {
    /// The transition matrix A of x' = A·x + σ ⊙ n.
    pub transition: SMatrix<f32, D, D>,
    /// The noise σ per dimension.
    pub sigma: SVector<f32, D>,
}

impl<const D: usize> Dynamics<D> for LinearGaussian<D> {
    fn propagate(&self, state: &mut SVector<f32, D>, noise: &mut RandomStream) {
        let mut next = self.transition * *state;
        for d in 0..D {
            next[d] += self.sigma[d] * noise.gaussian_f32();
        }
        *state = next;
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
