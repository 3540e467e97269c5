//! The seam every model plugs into: [`Model`], a model's CPU twin and its GPU side behind one
//! trait, so that one [`Filter`](super::Filter) steps it on either engine.

use pf_core::batch::BatchShape;

use crate::context::GpuContext;
use crate::error::GpuError;
use crate::filter::{GpuLikelihood, LikelihoodInputs};

/// An observation model the engine steps: how one frame weighs the particles, on the host (the
/// CPU engine) and on the GPU (the GPU engine). The engine owns everything else (resampling,
/// diffusion or the model's own dynamics, annealing layers, drift, normalising, estimates,
/// random numbers), so a model gets every engine feature by implementing this.
///
/// The two sides must agree: the GPU side's log-likelihoods equal the CPU twin's within the
/// tolerance policy (`crate::model::tolerance`), which each model's GPU-vs-CPU test checks.
pub trait Model: Sync {
    /// What one step weighs: a frame and whatever the model reads beside it (a plug-in's is one
    /// observation per target, `[O]`; the face tracker's the image and each slot's template).
    type Frame<'f>: ?Sized;

    /// The model's own error. The engine's errors convert into it; the model's reach the caller
    /// as they are.
    type Error: From<GpuError>;

    /// Binds the GPU side to the streams of the filter it is built into (once, when a GPU
    /// filter is built with it). Models without a GPU side do nothing.
    fn prepare_gpu(
        &mut self,
        ctx: &GpuContext,
        inputs: &LikelihoodInputs<'_>,
    ) -> Result<(), Self::Error>;

    /// On the GPU engine: uploads what the step needs of `frame` and returns the likelihood the
    /// step records. The queue writes the upload after any step already submitted, so a frame
    /// may be uploaded while the one before is in flight.
    fn upload_frame(
        &mut self,
        ctx: &GpuContext,
        frame: &Self::Frame<'_>,
    ) -> Result<&dyn GpuLikelihood, Self::Error>;

    /// On the CPU engine: fills `out[t·M + m]` with the log-likelihood of each particle of
    /// `states` (`[(t·D + d)·M + m]`) against `frame`. Called once per annealing layer.
    fn measure_on_cpu(
        &self,
        frame: &Self::Frame<'_>,
        shape: &BatchShape,
        states: &[f32],
        out: &mut [f32],
    ) -> Result<(), Self::Error>;

    /// [`Model::measure_on_cpu`] for annealing layer `layer` (0 without annealing), for a model
    /// that weighs early layers coarser, as its GPU side does for `LikelihoodPhase::Measure {
    /// layer }`. The default ignores the layer.
    fn measure_layer_on_cpu(
        &self,
        frame: &Self::Frame<'_>,
        shape: &BatchShape,
        layer: usize,
        states: &[f32],
        out: &mut [f32],
    ) -> Result<(), Self::Error> {
        let _ = layer;
        self.measure_on_cpu(frame, shape, states, out)
    }

    /// Checks `frame` before either engine moves a particle (its length, for example), so that
    /// a bad frame changes nothing. The default accepts every frame.
    fn check_frame(&self, frame: &Self::Frame<'_>, shape: &BatchShape) -> Result<(), Self::Error> {
        let _ = (frame, shape);
        Ok(())
    }

    /// Whether the model brings its own dynamics on the CPU engine
    /// ([`Model::propagate_on_cpu`]; its GPU side says so through
    /// [`GpuLikelihood::propagates`]). `false`: the engine's Gaussian random walk.
    fn propagates_on_cpu(&self) -> bool {
        false
    }

    /// The model's dynamics on the CPU engine: one particle's next state from `x` and `D`
    /// standard Gaussian draws (those the GPU side's propagate gets, so the two agree). Called
    /// only when [`Model::propagates_on_cpu`]; angle dimensions are wrapped by the engine.
    fn propagate_on_cpu(&self, x: &[f32], noise: &[f32], next: &mut [f32]) {
        let _ = noise;
        next.copy_from_slice(x);
    }
}
