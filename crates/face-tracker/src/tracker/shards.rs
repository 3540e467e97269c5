//! The filter engines a face tracker's slots run on: one (the CPU, or one GPU), or one per GPU,
//! each with its own share of the slots.
//!
//! Faces are independent filters, so several GPUs split them with nothing to exchange: each GPU
//! runs the whole step for its slots (frame upload, every annealing layer, the estimates and
//! their check) in its own submission, the shards step at once on threads of their own, and the
//! host only puts their estimates side by side in slot order. Each shard numbers its slots as
//! the whole tracker does (`Filter::number_targets_from`), so a slot draws the random
//! numbers it draws on one engine and the shards track as one GPU would.

use crate::likelihood::gpu::FaceLikelihoodGpu;
use pf_core::batch::{BatchConfig, BatchShape};
use pf_core::resample::ResamplerKind;
use pf_core::smooth::lag_window::LaggedSummaries;
use pf_gpu::engine::{EngineReport, Filter, InFlight};
use pf_gpu::{GpuContext, GpuResampler, GpuTime};
use rayon::prelude::*;

use super::FaceTrackerConfig;
use super::model::{FaceFrame, FaceModel};
use crate::error::FaceError;
use crate::image::GrayImage;
use crate::likelihood::{MIN_ERROR, MIN_VISIBLE_SHARE, residual_error_through};
use crate::projection::DIMS;
use crate::template::Template;

/// A share of the slots on one engine: the face model stepped by the engine's filter.
pub(crate) struct Shard {
    pub filter: Filter<FaceModel>,
    /// The tracker's first slot in this shard.
    pub first_slot: usize,
    pub slots: usize,
}

/// One shard's step: per slot of the shard, the estimate (`[t·7 + d]`), its spread, the ESS and
/// the estimate's ε.
pub(crate) struct ShardStep {
    pub estimates: Vec<f32>,
    pub spreads: Vec<f32>,
    pub ess: Vec<f64>,
    pub log_evidence: Vec<f64>,
    pub errors: Vec<f64>,
    pub gpu_time: Option<GpuTime>,
    /// The shard's slots a lag behind, smoothed on its GPU (`FaceTracker::keep_lag_window`).
    pub lagged: Option<LaggedSummaries>,
}

/// Template points a face is weighed at when the load is modelled (the paper's templates have
/// about 230; a template's real count is known only once its face is found).
pub const NOMINAL_TEMPLATE_POINTS: usize = 230;

/// Template samples a frame must give each GPU for a split over GPUs to pay: 64 faces of 1 000
/// particles × 5 layers × 230 points. Measured on four NVIDIA H100s (`face_step_over_gpus`, with
/// one GPU's step against the faces split over all four): 64 faces ran slower split (1.76
/// against 1.40 ms a step; 1.28 against 0.94 ms with two frames in flight), 256 faster (2.42
/// against 2.70 ms; 1.57 against 2.11 ms), and the synthetic video's four faces at 0.38× one
/// GPU's rate: below about 64 faces a GPU, a step is its fixed chain of dispatches and the
/// shards' round trips, not its work.
pub const SAMPLES_PER_GPU: f64 = 64.0 * 1000.0 * 5.0 * NOMINAL_TEMPLATE_POINTS as f64;

/// How many of `available` GPUs a tracker of `capacity` face slots under `config` pays for:
/// its template samples per frame (slots × particles × annealing layers ×
/// [`NOMINAL_TEMPLATE_POINTS`]) over [`SAMPLES_PER_GPU`], at least one, at most one per slot.
pub fn gpus_for_load(capacity: usize, config: &FaceTrackerConfig, available: usize) -> usize {
    let samples = capacity as f64
        * config.particles as f64
        * config.annealing.layers.max(1) as f64
        * NOMINAL_TEMPLATE_POINTS as f64;
    pf_gpu::load::gpus_for_work(samples, SAMPLES_PER_GPU, available.min(capacity.max(1)))
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
        let mut filter = match ctx {
            None => Filter::on_cpu(
                &batch,
                ResamplerKind::Systematic,
                states,
                FaceModel { lens, gpu: None },
            )?,
            Some(ctx) => {
                let likelihood = FaceLikelihoodGpu::new(
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
                let model = FaceModel {
                    lens,
                    gpu: Some(Box::new(likelihood)),
                };
                Filter::on_gpu(ctx, &batch, GpuResampler::Systematic, &states, model)?
            }
        };
        filter.number_targets_from(first_slot)?;
        Ok(Self {
            filter,
            first_slot,
            slots,
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
        self.filter.reset_target(local, cloud)?;
        if let (Some(likelihood), Some(ctx)) = (&self.filter.model().gpu, self.filter.context()) {
            likelihood.upload_template(ctx, local, &template.gpu_layout())?;
        }
        Ok(())
    }

    /// Sets the shard's slot for the tracker's `slot` moving (`Filter::set_target_motion`).
    pub fn set_motion(
        &mut self,
        slot: usize,
        estimate: &[f32],
        motion: &[f32],
    ) -> Result<(), FaceError> {
        let local = slot - self.first_slot;
        self.filter.set_target_motion(local, estimate, motion)
    }

    /// One frame for the shard's slots; `templates[t]` is the template in the shard's slot t
    /// (`None`: free).
    pub fn step(
        &mut self,
        frame: FrameRef<'_>,
        templates: &[Option<&Template>],
        sharpness: f32,
    ) -> Result<ShardStep, FaceError> {
        // The CPU weighs an image; a GPU only needs the pixels it uploads.
        let image = match self.filter.context() {
            Some(_) => None,
            None => Some(frame.image()?),
        };
        let report = self.filter.step(&FaceFrame {
            pixels: frame.pixels(),
            image: image.as_deref(),
            templates,
            sharpness,
        })?;
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
                    residual_error_through(&state, template, image, &self.filter.model().lens)
                })
            })
            .collect();
        Ok(ShardStep {
            estimates,
            spreads: report.spreads,
            ess: report.ess,
            log_evidence: report.log_evidence,
            errors,
            gpu_time: report.gpu_time,
            lagged: None,
        })
    }

    /// On a GPU: uploads the frame and submits the shard's step without waiting for it; `None`
    /// on the CPU engine, which steps with [`Shard::step`]. [`Shard::finish`] reads it back.
    pub fn submit(&mut self, frame: FrameRef<'_>) -> Result<Option<InFlight>, FaceError> {
        if self.filter.context().is_none() {
            return Ok(None);
        }
        // A GPU reads only the pixels: each slot's template is on the GPU since the slot
        // started, and λ is among its parameters.
        let frame = FaceFrame {
            pixels: frame.pixels(),
            image: None,
            templates: &[],
            sharpness: f32::NAN,
        };
        Ok(Some(self.filter.submit(&frame)?))
    }

    /// The step [`Shard::submit`] submitted, after waiting for it.
    pub fn finish(&mut self, pending: InFlight) -> Result<ShardStep, FaceError> {
        gpu_shard_step(self.filter.finish(pending)?)
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
        log_evidence: report.log_evidence,
        errors,
        gpu_time: report.gpu_time,
        lagged: report.lagged,
    })
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
        return Ok(shard.filter.engine().particles()?);
    }
    let (mut states, mut log_weights, mut slots) = (Vec::new(), Vec::new(), 0);
    let mut particles = 0;
    for shard in shards {
        // Targets are outermost in both layouts: shards' slots follow one another.
        let (shape, s, w) = shard.filter.engine().particles()?;
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

#[cfg(test)]
mod load_tests {
    use super::gpus_for_load;
    use crate::tracker::FaceTrackerConfig;

    #[test]
    fn faces_split_over_gpus_only_where_the_work_pays() {
        let defaults = FaceTrackerConfig::default();
        // The synthetic video's four faces stay on one GPU (split over four, they ran at 0.38× one
        // GPU's rate), and so do 64 (1.25× slower split over four).
        assert_eq!(gpus_for_load(4, &defaults, 4), 1);
        assert_eq!(gpus_for_load(64, &defaults, 4), 1);
        assert_eq!(gpus_for_load(128, &defaults, 4), 2);
        assert_eq!(gpus_for_load(256, &defaults, 4), 4);
        assert_eq!(gpus_for_load(256, &defaults, 1), 1);
        assert_eq!(gpus_for_load(256, &defaults, 0), 0);
        // Never more GPUs than slots.
        let heavy = FaceTrackerConfig {
            particles: 1_000_000,
            ..defaults
        };
        assert_eq!(gpus_for_load(2, &heavy, 8), 2);
    }
}
