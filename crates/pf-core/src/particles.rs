//! Struct-of-arrays particle storage.
//!
//! One target's M particles of dimension D live in one `Vec<f32>` laid out dimension-major:
//! component `d` of particle `m` is at `d * M + m`. That is exactly the layout of the GPU state
//! buffer of one target (pf-gpu stacks targets: target `t` starts at `t * D * M`), so a set can be
//! uploaded or downloaded with one copy and a kernel reads each dimension coalesced.

use nalgebra::SVector;

use crate::error::PfError;

/// The particles of one target: states (dimension-major) and log-weights.
#[derive(Debug, Clone, PartialEq)]
pub struct ParticleSet<const D: usize> {
    len: usize,
    states: Vec<f32>,
    log_weights: Vec<f32>,
    /// Double buffer for resampling, kept so that a step allocates nothing.
    scratch: Vec<f32>,
}

impl<const D: usize> ParticleSet<D> {
    /// `len` particles at the origin with equal weights.
    pub fn zeros(len: usize) -> Result<Self, PfError> {
        if len == 0 {
            return Err(PfError::EmptyParticleSet);
        }
        if len > u32::MAX as usize {
            return Err(PfError::InvalidConfig(format!(
                "{len} particles do not fit 32-bit ancestor indices"
            )));
        }
        let uniform = -(len as f32).ln();
        Ok(Self {
            len,
            states: vec![0.0; D * len],
            log_weights: vec![uniform; len],
            scratch: vec![0.0; D * len],
        })
    }

    /// `len` particles with states from `init(index)` and equal weights.
    pub fn from_fn(
        len: usize,
        mut init: impl FnMut(usize) -> SVector<f32, D>,
    ) -> Result<Self, PfError> {
        let mut set = Self::zeros(len)?;
        for i in 0..len {
            set.set_state(i, &init(i));
        }
        Ok(set)
    }

    /// Particles N.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Always false: a set holds at least one particle.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// The state of particle `i` (panics if `i >= len`, like slice indexing).
    pub fn state(&self, i: usize) -> SVector<f32, D> {
        SVector::from_fn(|d, _| self.states[d * self.len + i])
    }

    /// Overwrites particle `i`'s state.
    pub fn set_state(&mut self, i: usize, x: &SVector<f32, D>) {
        for d in 0..D {
            self.states[d * self.len + i] = x[d];
        }
    }

    /// Component `d` of every particle.
    pub fn dim(&self, d: usize) -> &[f32] {
        &self.states[d * self.len..(d + 1) * self.len]
    }

    /// Component `d` of every particle, mutable (dimension-major storage).
    pub fn dim_mut(&mut self, d: usize) -> &mut [f32] {
        &mut self.states[d * self.len..(d + 1) * self.len]
    }

    /// The whole dimension-major state buffer (`D * len` values).
    pub fn states_raw(&self) -> &[f32] {
        &self.states
    }

    /// The whole state buffer, `[d·N + i]`, mutable.
    pub fn states_raw_mut(&mut self) -> &mut [f32] {
        &mut self.states
    }

    /// The log-weights.
    pub fn log_weights(&self) -> &[f32] {
        &self.log_weights
    }

    /// The log-weights, mutable.
    pub fn log_weights_mut(&mut self) -> &mut [f32] {
        &mut self.log_weights
    }

    /// Gives every particle the weight 1/len.
    pub fn reset_weights(&mut self) {
        let uniform = -(self.len as f32).ln();
        self.log_weights.fill(uniform);
    }

    /// Replaces the set by the ancestors' states (`ancestors.len() == len`) with equal weights.
    pub fn select(&mut self, ancestors: &[u32]) -> Result<(), PfError> {
        if ancestors.len() != self.len {
            return Err(PfError::LengthMismatch {
                what: "ancestor indices",
                expected: self.len,
                got: ancestors.len(),
            });
        }
        if let Some(&bad) = ancestors.iter().find(|&&a| a as usize >= self.len) {
            return Err(PfError::InvalidConfig(format!(
                "ancestor index {bad} is out of range for {} particles",
                self.len
            )));
        }
        let n = self.len;
        for d in 0..D {
            let src = &self.states[d * n..(d + 1) * n];
            let dst = &mut self.scratch[d * n..(d + 1) * n];
            for (out, &a) in dst.iter_mut().zip(ancestors) {
                *out = src[a as usize];
            }
        }
        std::mem::swap(&mut self.states, &mut self.scratch);
        self.reset_weights();
        Ok(())
    }
}
