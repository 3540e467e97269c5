//! A researcher's model on either engine: [`Plugin`] pairs the WGSL model with its CPU twin
//! (`pf_core::plugin::CpuModel`), so one [`Filter`](crate::engine::Filter) type runs it on the
//! host or on a GPU, with the same random numbers.

use bytemuck::Pod;
use pf_core::batch::BatchShape;
use pf_core::plugin::CpuModel;

use super::{ModelSource, WgslModel};
use crate::context::GpuContext;
use crate::engine::Model;
use crate::error::GpuError;
use crate::filter::{GpuLikelihood, LikelihoodInputs};

/// A model plug-in with both sides: its CPU twin `T` and the constants it reads on the host,
/// and on a GPU its WGSL ([`WgslModel`]). Build it with [`Plugin::cpu`] for a filter on the CPU
/// engine or [`Plugin::gpu`] for one on a GPU; a frame is one observation per target.
pub struct Plugin<O: Pod, C: Pod, T: CpuModel<O, C>> {
    twin: T,
    constants: C,
    wgsl: Option<WgslModel<O, C>>,
}

impl<O: Pod, C: Pod + Sync, T: CpuModel<O, C>> Plugin<O, C, T> {
    /// The model for the CPU engine: the twin alone.
    pub fn cpu(twin: T, constants: C) -> Self {
        Self {
            twin,
            constants,
            wgsl: None,
        }
    }

    /// The model for a GPU: the twin and `source` compiled for `shape` on `ctx` (the errors of
    /// [`WgslModel::new`]).
    pub fn gpu(
        ctx: &GpuContext,
        source: ModelSource<'_>,
        shape: &BatchShape,
        twin: T,
        constants: C,
    ) -> Result<Self, GpuError> {
        let wgsl = WgslModel::new(ctx, source, shape, &constants)?;
        if wgsl.propagates() != T::PROPAGATES {
            return Err(GpuError::InvalidConfig(format!(
                "model {}: the WGSL {} propagate but the CPU twin's PROPAGATES is {}",
                source.name,
                if wgsl.propagates() {
                    "defines"
                } else {
                    "does not define"
                },
                T::PROPAGATES
            )));
        }
        Ok(Self {
            twin,
            constants,
            wgsl: Some(wgsl),
        })
    }

    /// The constants, on the host and (for a GPU model) on its device; the next frame reads
    /// them.
    pub fn set_constants(
        &mut self,
        ctx: Option<&GpuContext>,
        constants: C,
    ) -> Result<(), GpuError> {
        if let (Some(wgsl), Some(ctx)) = (&self.wgsl, ctx) {
            wgsl.set_constants(ctx, &constants)?;
        }
        self.constants = constants;
        Ok(())
    }

    /// The CPU twin.
    pub fn twin(&self) -> &T {
        &self.twin
    }
}

impl<O: Pod + Sync, C: Pod + Sync, T: CpuModel<O, C>> Model for Plugin<O, C, T> {
    type Frame<'f> = [O];
    type Error = GpuError;

    fn prepare_gpu(
        &mut self,
        ctx: &GpuContext,
        inputs: &LikelihoodInputs<'_>,
    ) -> Result<(), GpuError> {
        match &mut self.wgsl {
            Some(wgsl) => wgsl.prepare(ctx, inputs),
            None => Ok(()),
        }
    }

    fn upload_frame(
        &mut self,
        ctx: &GpuContext,
        observations: &[O],
    ) -> Result<&dyn GpuLikelihood, GpuError> {
        let wgsl = self.wgsl.as_ref().ok_or_else(|| {
            GpuError::InvalidConfig(
                "a plug-in built with Plugin::cpu was put on a GPU: build it with Plugin::gpu"
                    .into(),
            )
        })?;
        wgsl.set_observations(ctx, observations)?;
        Ok(wgsl)
    }

    fn check_frame(&self, observations: &[O], shape: &BatchShape) -> Result<(), GpuError> {
        if observations.len() != shape.targets {
            return Err(GpuError::LengthMismatch {
                what: "observations (one per target)".into(),
                expected: shape.targets,
                got: observations.len(),
            });
        }
        Ok(())
    }

    fn measure_on_cpu(
        &self,
        observations: &[O],
        shape: &BatchShape,
        states: &[f32],
        out: &mut [f32],
    ) -> Result<(), GpuError> {
        self.check_frame(observations, shape)?;
        let (twin, constants) = (&self.twin, &self.constants);
        pf_core::batch::measure_plugin(twin, observations, constants, shape, states, out);
        Ok(())
    }

    fn propagates_on_cpu(&self) -> bool {
        T::PROPAGATES
    }

    fn propagate_on_cpu(&self, x: &[f32], noise: &[f32], next: &mut [f32]) {
        self.twin.propagate(x, noise, &self.constants, next);
    }
}
