//! The CPU twin of a model plug-in: a user's observation model and, optionally, dynamics, run by
//! [`crate::batch::BatchFilter::step_model`] with exactly the random numbers the GPU draws.
//!
//! On the GPU the same model is a few WGSL functions (`pf_gpu::model::WgslModel`): the two must
//! agree, and `pf_gpu::model::check_against_cpu` checks that they do on random particles.

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
