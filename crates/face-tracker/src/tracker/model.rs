//! The face tracker as a [`Model`] of the engine's one [`Filter`](pf_gpu::engine::Filter): a
//! frame weighs each slot's particles against its template, on the host
//! ([`FaceModel::measure_on_cpu`]) or on the GPU ([`FaceLikelihoodGpu`]), eq. 1 on both.

use pf_core::batch::BatchShape;
use pf_gpu::engine::Model;
use pf_gpu::{GpuContext, GpuError, GpuLikelihood, LikelihoodInputs};
use rayon::prelude::*;

use crate::error::FaceError;
use crate::image::GrayImage;
use crate::likelihood::gpu::FaceLikelihoodGpu;
use crate::likelihood::{Lens, log_weight, residual_errors_of_through};
use crate::projection::DIMS;
use crate::template::Template;

/// The face likelihood over a shard's slots: the camera, and on a GPU engine the GPU side.
pub(crate) struct FaceModel {
    /// The camera the faces are seen through (the CPU side's; the GPU side has its own copy).
    pub lens: Lens,
    /// The GPU side (GPU engines only).
    pub gpu: Option<Box<FaceLikelihoodGpu>>,
}

/// What one step of a shard weighs.
pub(crate) struct FaceFrame<'a> {
    /// The frame's 8-bit pixels, row-major (what a GPU uploads).
    pub pixels: &'a [u8],
    /// The frame as an image (what the host weighs; `None` on a GPU engine).
    pub image: Option<&'a GrayImage>,
    /// The template in each of the shard's slots (`None`: a free slot, weighed 0).
    pub templates: &'a [Option<&'a Template>],
    /// The likelihood's sharpness λ (eq. 1).
    pub sharpness: f32,
}

impl Model for FaceModel {
    type Frame<'f> = FaceFrame<'f>;
    type Error = FaceError;

    fn prepare_gpu(
        &mut self,
        ctx: &GpuContext,
        inputs: &LikelihoodInputs<'_>,
    ) -> Result<(), FaceError> {
        if let Some(gpu) = &mut self.gpu {
            gpu.prepare(ctx, inputs)?;
        }
        Ok(())
    }

    fn upload_frame(
        &mut self,
        ctx: &GpuContext,
        frame: &FaceFrame<'_>,
    ) -> Result<&dyn GpuLikelihood, FaceError> {
        let gpu = self.gpu.as_deref().ok_or_else(|| {
            GpuError::InvalidConfig("a face model built for the CPU was put on a GPU".into())
        })?;
        gpu.upload_frame(ctx, frame.pixels)?;
        Ok(gpu)
    }

    fn measure_on_cpu(
        &self,
        frame: &FaceFrame<'_>,
        shape: &BatchShape,
        states: &[f32],
        out: &mut [f32],
    ) -> Result<(), FaceError> {
        let image = frame.image.ok_or_else(|| {
            FaceError::InvalidInput("a face step on the CPU needs the frame as an image".into())
        })?;
        host_log_weights(
            shape,
            states,
            frame.templates,
            image,
            &self.lens,
            frame.sharpness,
            out,
        );
        Ok(())
    }
}

/// The CPU engine's measure: each slot's particles in tasks of `TASK` (a particle is about a
/// microsecond of work), weighed `LANES` at a time; free slots weigh 0.
fn host_log_weights(
    shape: &BatchShape,
    states: &[f32],
    templates: &[Option<&Template>],
    frame: &GrayImage,
    lens: &Lens,
    sharpness: f32,
    out: &mut [f32],
) {
    const TASK: usize = 64;
    out.par_chunks_mut(shape.particles)
        .enumerate()
        .for_each(|(t, out)| {
            let Some(template) = templates[t] else {
                out.fill(0.0);
                return;
            };
            out.par_chunks_mut(TASK)
                .enumerate()
                .for_each(|(task, out)| {
                    let first = task * TASK;
                    let mut particles = [[0.0f32; DIMS]; TASK];
                    for (k, s) in particles[..out.len()].iter_mut().enumerate() {
                        *s = std::array::from_fn(|d| states[shape.state_index(t, d, first + k)]);
                    }
                    let mut errors = [0.0f64; TASK];
                    residual_errors_of_through(
                        &particles[..out.len()],
                        template,
                        frame,
                        lens,
                        &mut errors[..out.len()],
                    );
                    for (out, error) in out.iter_mut().zip(errors) {
                        *out = log_weight(error, sharpness);
                    }
                });
        });
}
