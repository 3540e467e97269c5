//! The seam between the filter and an observation model on the GPU: the streams a likelihood
//! binds, the trait it implements (one `record` per phase of the step, plus the buffers it wants
//! read back with the step), and the likelihood that does nothing (stage tests).

use bytemuck::Pod;

use crate::context::GpuContext;
use crate::error::GpuError;
use crate::stream::DeviceStream;
use pf_core::batch::BatchShape;

/// The streams a likelihood reads and writes, handed to [`GpuLikelihood::prepare`].
pub struct LikelihoodInputs<'a> {
    /// Targets × particles × dimensions.
    pub shape: BatchShape,
    /// The frame parameters (uniform buffer, `Params` of `shaders/engine/common.wgsl`). A
    /// likelihood reads the shape from it, and in `Propagate` the step its draws are keyed by:
    /// the fused step holds the frame's first layer's block there for the whole frame, the
    /// staged one each layer's in turn.
    pub params: &'a wgpu::Buffer,
    /// States, `[(t·D + d)·M + m]`, already diffused when the likelihood runs.
    pub states: &'a DeviceStream<f32>,
    /// Where the likelihood writes `log p(z | x)`, `[t·M + m]`.
    pub log_likelihood: &'a DeviceStream<f32>,
    /// The step's estimate per target, `[t·D + d]`: the best-M′ weighted mean where the filter
    /// computes one, else the weighted mean (written by the Estimate stage).
    pub estimates: &'a DeviceStream<f32>,
    /// The per-target Philox keys of the diffusion stream (`counter_gaussian(key_t, m, d,
    /// step)`), for a likelihood that brings its own dynamics ([`GpuLikelihood::propagates`]).
    pub diffusion_keys: &'a DeviceStream<[u32; 2]>,
}

/// Where in the step a likelihood's dispatches are recorded (all in the step's one pass).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LikelihoodPhase {
    /// The Diffuse stage, in place of the filter's Gaussian random walk; recorded only for a
    /// likelihood that [`GpuLikelihood::propagates`].
    Propagate,
    /// The Likelihood stage of annealing layer `layer` (0 without annealing): write
    /// `log p(z | x)` of every particle. A likelihood may weigh early layers coarser (the body
    /// tracker's point subsets); most ignore the layer.
    Measure {
        /// The annealing layer, from 0.
        layer: usize,
    },
    /// After the Estimate stage, on the step's estimates (a tracker's check of its estimate,
    /// say); its results come back through [`GpuLikelihood::readbacks`].
    AfterEstimate,
}

/// A device buffer a likelihood wants read back with every step: the filter copies its first
/// `bytes` into a section of the step's one staging buffer, and the step's report returns them
/// under `name` ([`LikelihoodReadbacks::get`]).
#[derive(Debug, Clone, Copy)]
pub struct ReadbackSource<'a> {
    /// The name the report files the bytes under.
    pub name: &'static str,
    /// The buffer copied from its start.
    pub buffer: &'a wgpu::Buffer,
    /// How many bytes (a multiple of 4).
    pub bytes: u64,
}

impl<'a> ReadbackSource<'a> {
    /// The whole of `stream`.
    pub fn of<T: Pod>(name: &'static str, stream: &'a DeviceStream<T>) -> Self {
        Self {
            name,
            buffer: stream.buffer(),
            bytes: (stream.len() * std::mem::size_of::<T>()) as u64,
        }
    }
}

/// The likelihood's readbacks of one step, by name (empty on the CPU engine and for a
/// likelihood that asks for none).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct LikelihoodReadbacks {
    sections: Vec<(&'static str, Vec<u8>)>,
}

impl LikelihoodReadbacks {
    pub(crate) fn new(sections: Vec<(&'static str, Vec<u8>)>) -> Self {
        Self { sections }
    }

    /// The values read back under `name`, as `T`s; an error names a section the likelihood did
    /// not ask for, or bytes that are not a whole number of `T`s.
    pub fn get<T: Pod>(&self, name: &str) -> Result<Vec<T>, GpuError> {
        let (_, bytes) = self
            .sections
            .iter()
            .find(|(n, _)| *n == name)
            .ok_or_else(|| {
                let known: Vec<&str> = self.sections.iter().map(|(n, _)| *n).collect();
                GpuError::InvalidConfig(format!(
                    "the step read back no section named {name:?} (it has {known:?})"
                ))
            })?;
        if !bytes.len().is_multiple_of(std::mem::size_of::<T>().max(1)) {
            return Err(GpuError::InvalidConfig(format!(
                "readback {name:?}: {} bytes are not a whole number of {}-byte values",
                bytes.len(),
                std::mem::size_of::<T>()
            )));
        }
        Ok(bytemuck::pod_collect_to_vec(bytes))
    }

    /// Whether there is none.
    pub fn is_empty(&self) -> bool {
        self.sections.is_empty()
    }
}

/// An observation model on the GPU. A tracker builds its pipelines and bind groups once in
/// `prepare`, uploads each frame's observation before the step, and records its dispatches for
/// each phase of the step; what it wants back comes in the step's report.
pub trait GpuLikelihood {
    /// Binds the filter's streams (once, after construction); builds its bind groups.
    fn prepare(&mut self, ctx: &GpuContext, inputs: &LikelihoodInputs<'_>) -> Result<(), GpuError>;

    /// Records the dispatches of `phase` into the step's compute pass (nothing for a phase it
    /// has no work in).
    fn record(&self, phase: LikelihoodPhase, pass: &mut wgpu::ComputePass<'_>);

    /// Whether `prepare` has bound it; a step with an unprepared likelihood is an error rather
    /// than a step that weighs stale values.
    fn is_prepared(&self) -> bool {
        true
    }

    /// Whether it brings its own dynamics, recorded in [`LikelihoodPhase::Propagate`] in place
    /// of the filter's Gaussian random walk.
    fn propagates(&self) -> bool {
        false
    }

    /// The buffers read back with every step, each into its own section of the filter's one
    /// staging buffer (copied after the last stage that ran, mapped behind the step's one wait).
    fn readbacks(&self) -> Vec<ReadbackSource<'_>> {
        Vec::new()
    }

    /// What lets the filter record the next step's commands while the GPU runs this one
    /// (`GpuFilter`'s prerecording): an id that names everything `record` and `readbacks`
    /// depend on (bind groups, pipelines, dispatch sizes, buffers), taken fresh
    /// ([`RecordingId::fresh`]) whenever any of it changes, as `prepare` does. `None` (the
    /// default): what it records may change from step to step, so every step is recorded anew.
    /// A frame's data (observations written with `queue.write_buffer` before the step) is not
    /// part of it.
    fn recording_id(&self) -> Option<RecordingId> {
        None
    }
}

/// Names one state of a likelihood's recording ([`GpuLikelihood::recording_id`]): unique in the
/// process, so that two likelihoods, or one before and after a `prepare`, never share one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RecordingId(u64);

impl RecordingId {
    /// An id no other call has returned.
    pub fn fresh() -> Self {
        use std::sync::atomic::{AtomicU64, Ordering};
        static NEXT: AtomicU64 = AtomicU64::new(1);
        Self(NEXT.fetch_add(1, Ordering::Relaxed))
    }
}

/// A likelihood that records nothing (the log-likelihood stream keeps its contents).
pub struct NoLikelihood;

impl GpuLikelihood for NoLikelihood {
    fn prepare(&mut self, _: &GpuContext, _: &LikelihoodInputs<'_>) -> Result<(), GpuError> {
        Ok(())
    }
    fn record(&self, _: LikelihoodPhase, _: &mut wgpu::ComputePass<'_>) {}
}
