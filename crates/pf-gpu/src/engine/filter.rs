//! [`Filter`]: one model stepped on the engine chosen at construction, a frame at a time
//! ([`Filter::step`]) or two frames in flight ([`Filter::submit`], [`Filter::finish`]).

use pf_core::batch::{BatchConfig, BatchShape, Propagate};
use pf_core::resample::ResamplerKind;

use super::{EngineReport, FilterEngine, GpuEngine, Model};
use crate::context::GpuContext;
use crate::error::GpuError;
use crate::filter::{GpuFilter, GpuResampler, GpuStage, PendingStep};

/// T targets × M particles of one model on one engine (the host, or one GPU). Built with its
/// model, which is prepared against the engine's streams at construction, so it can neither be
/// forgotten nor bound to another filter. Configure the engine's features (annealing layers and
/// their survival rule, constant-velocity drift, best-M′ estimates) in the [`BatchConfig`];
/// split targets over several GPUs by building one filter per GPU and numbering each part with
/// [`Filter::number_targets_from`] (as [`crate::model::ShardedModelFilter`] does).
pub struct Filter<M: Model> {
    engine: FilterEngine,
    model: M,
}

/// A frame submitted by [`Filter::submit`] and not yet read back. On the CPU engine the frame
/// was stepped at submission and this holds its report.
#[must_use = "a submitted frame must be finished (Filter::finish)"]
pub enum InFlight {
    /// A step on the GPU.
    Gpu(PendingStep),
    /// A step the CPU engine made at once.
    Stepped(Box<EngineReport>),
}

impl<M: Model> Filter<M> {
    /// The model on the CPU engine over `initial_states` (`[(t·D + d)·M + m]`).
    pub fn on_cpu(
        config: &BatchConfig,
        resampler: ResamplerKind,
        initial_states: Vec<f32>,
        model: M,
    ) -> Result<Self, M::Error> {
        let engine = FilterEngine::cpu(config, resampler, initial_states)?;
        Ok(Self { engine, model })
    }

    /// The model on the GPU of `ctx` over `initial_states` (`[(t·D + d)·M + m]`).
    pub fn on_gpu(
        ctx: GpuContext,
        config: &BatchConfig,
        resampler: GpuResampler,
        initial_states: &[f32],
        mut model: M,
    ) -> Result<Self, M::Error> {
        let filter = GpuFilter::new(&ctx, config, resampler, initial_states)?;
        model.prepare_gpu(&ctx, &filter.likelihood_inputs())?;
        let engine = FilterEngine::Gpu(Box::new(GpuEngine { ctx, filter }));
        Ok(Self { engine, model })
    }

    /// One frame: resample, diffuse (or the model's dynamics), weigh against `frame`, normalise,
    /// estimate; every annealing layer of the configuration.
    pub fn step(&mut self, frame: &M::Frame<'_>) -> Result<EngineReport, M::Error> {
        self.model.check_frame(frame, &self.engine.shape())?;
        let Self { engine, model } = self;
        match engine {
            FilterEngine::Cpu(filter) => {
                let model: &M = model;
                let dynamics = |x: &[f32], noise: &[f32], next: &mut [f32]| {
                    model.propagate_on_cpu(x, noise, next)
                };
                let propagate = model
                    .propagates_on_cpu()
                    .then_some(&dynamics as &Propagate<'_>);
                // The batch filter measures once per annealing layer, in order.
                let mut layer = 0;
                FilterEngine::step_on_cpu(filter, propagate, |shape, states, out| {
                    let measured = model.measure_layer_on_cpu(frame, shape, layer, states, out);
                    layer += 1;
                    measured
                })
            }
            FilterEngine::Gpu(gpu) => {
                let likelihood = model.upload_frame(&gpu.ctx, frame)?;
                let report = gpu.filter.step(&gpu.ctx, likelihood)?;
                Ok(gpu.report(report))
            }
        }
    }

    /// Submits a frame without waiting for it: the GPU steps it while the host prepares the
    /// next frame or reads the one before. At most two frames are in flight; [`Self::finish`]
    /// them in the order submitted (the results equal stepping one at a time, bit for bit). On
    /// the CPU engine the frame is stepped at once.
    pub fn submit(&mut self, frame: &M::Frame<'_>) -> Result<InFlight, M::Error> {
        if matches!(self.engine, FilterEngine::Cpu(_)) {
            return Ok(InFlight::Stepped(Box::new(self.step(frame)?)));
        }
        self.model.check_frame(frame, &self.engine.shape())?;
        let Self { engine, model } = self;
        match engine {
            FilterEngine::Cpu(_) => unreachable!("the CPU engine stepped above"),
            FilterEngine::Gpu(gpu) => {
                let likelihood = model.upload_frame(&gpu.ctx, frame)?;
                let pending = gpu
                    .filter
                    .submit_stages(&gpu.ctx, &GpuStage::ALL, likelihood)?;
                Ok(InFlight::Gpu(pending))
            }
        }
    }

    /// The report of the oldest frame in flight, after waiting for it.
    pub fn finish(&mut self, frame: InFlight) -> Result<EngineReport, M::Error> {
        match (frame, &mut self.engine) {
            (InFlight::Stepped(report), _) => Ok(*report),
            (InFlight::Gpu(pending), FilterEngine::Gpu(gpu)) => {
                let report = gpu.filter.finish_step(&gpu.ctx, pending)?;
                Ok(gpu.report(report))
            }
            (InFlight::Gpu(_), FilterEngine::Cpu(_)) => Err(GpuError::InvalidConfig(
                "a GPU step was handed to a filter on the CPU engine".into(),
            )
            .into()),
        }
    }

    /// Targets × particles × dimensions.
    pub fn shape(&self) -> BatchShape {
        self.engine.shape()
    }

    /// The GPU context, on the GPU engine.
    pub fn context(&self) -> Option<&GpuContext> {
        self.engine.context()
    }

    /// The model.
    pub fn model(&self) -> &M {
        &self.model
    }

    /// The model, to change what it holds between frames (templates, constants).
    pub fn model_mut(&mut self) -> &mut M {
        &mut self.model
    }

    /// The engine and the model at once (a model's upload that needs the engine's context).
    pub fn parts_mut(&mut self) -> (&mut FilterEngine, &mut M) {
        (&mut self.engine, &mut self.model)
    }

    /// On the GPU engine: its context, its driver and the model, to run single stages
    /// ([`GpuFilter::run_stages`]) or read a stream back.
    pub fn gpu_parts(&mut self) -> Option<(&GpuContext, &mut GpuFilter, &M)> {
        match &mut self.engine {
            FilterEngine::Cpu(_) => None,
            FilterEngine::Gpu(gpu) => Some((&gpu.ctx, &mut gpu.filter, &self.model)),
        }
    }

    /// The engine (particles, resets, the GPU driver's single stages).
    pub fn engine(&self) -> &FilterEngine {
        &self.engine
    }

    /// The engine, to move particles between filters (islands over several GPUs).
    pub fn engine_mut(&mut self) -> &mut FilterEngine {
        &mut self.engine
    }

    /// Makes this filter's targets targets `first ..` of a larger batch split over several
    /// filters (one per GPU), so that each draws the random numbers it draws in the whole batch
    /// and the parts step as the whole would.
    pub fn number_targets_from(&mut self, first: usize) -> Result<(), M::Error> {
        Ok(self.engine.number_targets_from(first)?)
    }

    /// Restarts target `t` from `states` (its `D·M` values, `[d·M + m]`) with equal weights.
    pub fn reset_target(&mut self, t: usize, states: &[f32]) -> Result<(), M::Error> {
        Ok(self.engine.reset_target(t, states)?)
    }

    /// Sets target `t` moving, as if its last two estimates had been `estimate − motion` and
    /// `estimate` (`pf_core::batch::BatchFilter::set_target_motion`).
    pub fn set_target_motion(
        &mut self,
        t: usize,
        estimate: &[f32],
        motion: &[f32],
    ) -> Result<(), M::Error> {
        Ok(self.engine.set_target_motion(t, estimate, motion)?)
    }

    /// The particles after the last step: the states (`[(t·D + d)·M + m]`) and the normalised
    /// log-weights (`[t·M + m]`). The GPU engine reads them back (a wait).
    pub fn particles(&self) -> Result<(Vec<f32>, Vec<f32>), M::Error> {
        let (_, states, log_weights) = self.engine.particles()?;
        Ok((states, log_weights))
    }
}
