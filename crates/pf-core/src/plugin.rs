//! The CPU twin of a model plug-in: a user's observation model and, optionally, dynamics, run by
//! [`crate::batch::BatchFilter::step_model`] with exactly the random numbers the GPU draws.
//!
//! On the GPU the same model is a few WGSL functions (`pf_gpu::model::WgslModel`): the two must
//! agree, and `pf_gpu::model::check_against_cpu` checks that they do on random particles.

use rayon::prelude::*;

use crate::batch::BatchShape;

/// A model over the batch layout: `x` is one particle's state (its `D` values), `z` the target's
/// observation this frame, `c` the model's constants.
pub trait CpuModel<O, C>: Sync {
    /// Whether [`CpuModel::propagate`] replaces the engine's Gaussian random walk. When `false`
    /// the filter diffuses with `BatchConfig::sigma`, as it does without a model.
    const PROPAGATES: bool = false;

    /// log p(z | x), up to a constant. Must not panic on any finite `x`; a NaN or +∞ result is
    /// reported by the filter as a typed error naming the particle.
    fn log_likelihood(&self, x: &[f32], z: &O, c: &C) -> f32;

    /// The dynamics: the next state from the previous one and `D` standard Gaussian draws
    /// (`noise[d]` is the draw the GPU's `propagate` receives for dimension `d`). Angle
    /// dimensions are wrapped by the engine afterwards.
    fn propagate(&self, x: &[f32], noise: &[f32], c: &C, next: &mut [f32]) {
        let _ = (noise, c);
        next.copy_from_slice(x);
    }
}

/// The twin's log-likelihood of every particle of `states` (`[(t·D + d)·M + m]`) against each
/// target's observation, into `out[t·M + m]`, targets on all cores: the CPU measure of a plug-in
/// (`BatchFilter::step_model`, and `pf_gpu::model::Plugin` on the CPU engine). `observations`
/// holds one observation per target (checked by the callers).
pub fn measure_all<O: Sync, C: Sync, M: CpuModel<O, C>>(
    model: &M,
    observations: &[O],
    constants: &C,
    shape: &BatchShape,
    states: &[f32],
    out: &mut [f32],
) {
    out.par_chunks_mut(shape.particles)
        .enumerate()
        .for_each(|(t, row)| {
            let mut x = vec![0.0f32; shape.dims];
            for (m, value) in row.iter_mut().enumerate() {
                for (d, v) in x.iter_mut().enumerate() {
                    *v = states[shape.state_index(t, d, m)];
                }
                *value = model.log_likelihood(&x, &observations[t], constants);
            }
        });
}
