//! The filter engines a face tracker's slots run on: one (the CPU, or one GPU), or one per GPU,
//! each with its own share of the slots.
//!
//! Faces are independent filters, so several GPUs split them with nothing to exchange: each GPU
//! runs the whole step for its slots (frame upload, every annealing layer, the estimates and
//! their check) in its own submission, the shards step at once on threads of their own, and the
//! host only puts their estimates side by side in slot order. Each shard numbers its slots as
//! the whole tracker does (`FilterEngine::number_targets_from`), so a slot draws the random
//! numbers it draws on one engine and the shards track as one GPU would.

use crate::likelihood::gpu::FaceLikelihoodGpu;
use pf_core::batch::{BatchConfig, BatchShape};
use pf_gpu::engine::{EngineReport, FilterEngine};
use pf_gpu::{GpuContext, GpuLikelihood, GpuTime, NoLikelihood, PendingStep};
use rayon::prelude::*;

use super::FaceTrackerConfig;
use crate::error::FaceError;
use crate::image::GrayImage;
use crate::likelihood::{
    Lens, MIN_ERROR, MIN_VISIBLE_SHARE, log_weight, residual_error_through,
    residual_errors_of_through,
};
use crate::projection::DIMS;
use crate::template::Template;

/// A share of the slots on one engine.
pub(crate) struct Shard {
    pub engine: FilterEngine,
    /// The GPU likelihood (GPU engines only; the CPU engine weighs on the host).
    pub gpu_likelihood: Option<Box<FaceLikelihoodGpu>>,
    /// The tracker's first slot in this shard.
    pub first_slot: usize,
    pub slots: usize,
    /// The camera the faces are seen through (the CPU engine's; a GPU's likelihood has its own
    /// copy).
    pub lens: Lens,
}

/// One shard's step: per slot of the shard, the estimate (`[t·7 + d]`), its spread, the ESS and
/// the estimate's ε.
pub(crate) struct ShardStep {
    pub estimates: Vec<f32>,
    pub spreads: Vec<f32>,
    pub ess: Vec<f64>,
    pub errors: Vec<f64>,
    pub gpu_time: Option<GpuTime>,
}

/// The slots of each of `shards` shards: `capacity` split as evenly as possible, each at least 1.
pub(crate) fn shard_sizes(capacity: usize, shards: usize) -> Result<Vec<usize>, FaceError> {
    if shards == 0 || capacity < shards {
        return Err(FaceError::InvalidInput(format!(
            "{capacity} face slots cannot be split over {shards} GPUs: each GPU needs at least one"
        )));
    }
    Ok((0..shards)
        .map(|s| capacity / shards + usize::from(s < capacity % shards))
        .collect())
}

/// A frame as a step takes it: an image, or borrowed 8-bit pixels (row-major, a binding's
/// array) that a GPU uploads as they are; the CPU's weighing copies them into an image first.
#[derive(Debug, Clone, Copy)]
pub enum FrameRef<'a> {
    Image(&'a GrayImage),
    Pixels {
        width: u32,
        height: u32,
        data: &'a [u8],
    },
}

impl<'a> FrameRef<'a> {
    /// (width, height).
    pub fn size(&self) -> (u32, u32) {
        match self {
            FrameRef::Image(image) => (image.width, image.height),
            FrameRef::Pixels { width, height, .. } => (*width, *height),
        }
    }

    /// The pixels, row-major.
    pub fn pixels(&self) -> &'a [u8] {
        match self {
            FrameRef::Image(image) => &image.data,
            FrameRef::Pixels { data, .. } => data,
        }
    }

    /// The frame as an image (borrowed, or copied from the pixels; checks their count).
    pub fn image(&self) -> Result<std::borrow::Cow<'a, GrayImage>, FaceError> {
        Ok(match self {
            FrameRef::Image(image) => std::borrow::Cow::Borrowed(*image),
            FrameRef::Pixels {
                width,
                height,
                data,
            } => std::borrow::Cow::Owned(GrayImage::new(*width, *height, data.to_vec())?),
        })
    }
}

impl Shard {
    /// `slots` slots from `first_slot` on, on the CPU (`ctx` `None`) or a GPU, for frames of
    /// `frame_size`.
    pub fn new(
        config: &FaceTrackerConfig,
        batch: &BatchConfig,
        first_slot: usize,
        slots: usize,
        frame_size: (u32, u32),
        ctx: Option<GpuContext>,
    ) -> Result<Self, FaceError> {
        let shape = BatchShape::new(slots, config.particles, DIMS)?;
        let batch = BatchConfig {
            shape,
            ..batch.clone()
        };
        batch.validate()?;
        let lens = config.lens(frame_size)?;
        // Free slots hold a cloud at the origin until a face arrives; they are never reported.
        let states = vec![0.0; shape.state_len()];
        let (engine, gpu_likelihood) = match ctx {
            None => (FilterEngine::cpu(&batch, states)?, None),
            Some(ctx) => {
                let mut likelihood = FaceLikelihoodGpu::new(
                    &ctx,
                    config.gpu_dispatch,
                    slots,
                    config.extraction.max_points.max(1),
                    frame_size.0,
                    frame_size.1,
                    config.sharpness,
                    MIN_ERROR,
                    MIN_VISIBLE_SHARE,
                    lens,
                )?;
                let engine = FilterEngine::gpu(ctx, &batch, &states)?;
                if let Some((ctx, inputs)) = engine.likelihood_inputs() {
                    likelihood.prepare(ctx, &inputs)?;
                }
                (engine, Some(Box::new(likelihood)))
            }
        };
        let mut engine = engine;
        engine.number_targets_from(first_slot)?;
        Ok(Self {
            engine,
            gpu_likelihood,
            first_slot,
            slots,
            lens,
        })
    }

    /// Whether the tracker's slot `slot` is in this shard.
    pub fn holds(&self, slot: usize) -> bool {
        (self.first_slot..self.first_slot + self.slots).contains(&slot)
    }

    /// Restarts the shard's slot for the tracker's `slot` from `cloud` with `template`.
    pub fn start(
        &mut self,
        slot: usize,
        cloud: &[f32],
        template: &Template,
    ) -> Result<(), FaceError> {
        let local = slot - self.first_slot;
        self.engine.reset_target(local, cloud)?;
        if let (Some(likelihood), Some(ctx)) = (&self.gpu_likelihood, self.engine.context()) {
            likelihood.upload_template(ctx, local, &template.gpu_layout())?;
        }
        Ok(())
    }

    /// One frame for the shard's slots; `templates[t]` is the template in the shard's slot t
    /// (`None`: free).
    pub fn step(
        &mut self,
        frame: FrameRef<'_>,
        templates: &[Option<&Template>],
        sharpness: f32,
    ) -> Result<ShardStep, FaceError> {
        if let (Some(likelihood), Some(ctx)) = (&self.gpu_likelihood, self.engine.context()) {
            likelihood.upload_frame(ctx, frame.pixels())?;
        }
        // The CPU weighs an image; a GPU only needs the pixels it uploaded.
        let image = match &self.gpu_likelihood {
            Some(_) => None,
            None => Some(frame.image()?),
        };
        let on_gpu: &dyn GpuLikelihood = match &self.gpu_likelihood {
            Some(likelihood) => &**likelihood,
            None => &NoLikelihood,
        };
        let lens = self.lens;
        let report = self.engine.step(
            |shape, states, out| -> Result<(), FaceError> {
                if let Some(image) = &image {
                    host_log_weights(shape, states, templates, image, &lens, sharpness, out);
                }
                Ok(())
            },
            on_gpu,
        )?;
        let Some(image) = &image else {
            return gpu_shard_step(report);
        };
        // Faces in parallel (at 64 faces this is 15 000 points); a free slot's ε is 1.
        let estimates = report.point_estimates().to_vec();
        let errors = templates
            .par_iter()
            .enumerate()
            .map(|(t, template)| {
                let state: [f32; DIMS] = std::array::from_fn(|d| estimates[t * DIMS + d]);
                template.map_or(1.0, |template| {
                    residual_error_through(&state, template, image, &lens)
                })
            })
            .collect();
        Ok(ShardStep {
            estimates,
            spreads: report.spreads,
            ess: report.ess,
            errors,
            gpu_time: report.gpu_time,
        })
    }

    /// On a GPU: uploads the frame and submits the shard's step without waiting for it; `None`
    /// on the CPU engine, which steps with [`Shard::step`]. [`Shard::finish`] reads it back.
    pub fn submit(&mut self, frame: FrameRef<'_>) -> Result<Option<PendingStep>, FaceError> {
        let (Some(likelihood), Some(ctx)) = (&self.gpu_likelihood, self.engine.context()) else {
            return Ok(None);
        };
        likelihood.upload_frame(ctx, frame.pixels())?;
        Ok(self.engine.submit(&**likelihood)?)
    }

    /// The step [`Shard::submit`] submitted, after waiting for it.
    pub fn finish(&mut self, pending: PendingStep) -> Result<ShardStep, FaceError> {
        gpu_shard_step(self.engine.finish(pending)?)
    }
}

/// A GPU shard's step from its engine's report: the GPU weighed the estimates in the step's
/// submission.
fn gpu_shard_step(report: EngineReport) -> Result<ShardStep, FaceError> {
    let errors = report
        .likelihood
        .get::<f32>(FaceLikelihoodGpu::ESTIMATE_ERRORS)?
        .into_iter()
        .map(f64::from)
        .collect();
    Ok(ShardStep {
        estimates: report.point_estimates().to_vec(),
        spreads: report.spreads,
        ess: report.ess,
        errors,
        gpu_time: report.gpu_time,
    })
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

/// Every shard's step at once (each on its own thread when there are several), in shard order.
pub(crate) fn step_all(
    shards: &mut [Shard],
    frame: FrameRef<'_>,
    templates: &[Option<&Template>],
    sharpness: f32,
) -> Result<Vec<ShardStep>, FaceError> {
    let mine = |shard: &Shard| &templates[shard.first_slot..shard.first_slot + shard.slots];
    if let [shard] = shards {
        let templates = mine(shard);
        return Ok(vec![shard.step(frame, templates, sharpness)?]);
    }
    std::thread::scope(|scope| {
        let running: Vec<_> = shards
            .iter_mut()
            .map(|shard| {
                let templates = mine(shard);
                scope.spawn(move || shard.step(frame, templates, sharpness))
            })
            .collect();
        running
            .into_iter()
            .map(|r| {
                r.join()
                    .map_err(|_| FaceError::InvalidInput("a GPU's thread panicked".into()))?
            })
            .collect()
    })
}

/// The shards' particles as one batch, slots in order: (shape, states, log-weights).
pub(crate) fn joined_particles(
    shards: &[Shard],
) -> Result<(BatchShape, Vec<f32>, Vec<f32>), FaceError> {
    if let [shard] = shards {
        return Ok(shard.engine.particles()?);
    }
    let (mut states, mut log_weights, mut slots) = (Vec::new(), Vec::new(), 0);
    let mut particles = 0;
    for shard in shards {
        // Targets are outermost in both layouts: shards' slots follow one another.
        let (shape, s, w) = shard.engine.particles()?;
        states.extend(s);
        log_weights.extend(w);
        slots += shape.targets;
        particles = shape.particles;
    }
    Ok((
        BatchShape::new(slots, particles, DIMS)?,
        states,
        log_weights,
    ))
}
