//! A toy GPU likelihood: a Gaussian around each target's observed state (`toy_likelihood.wgsl`).
//! It drives the driver tests and benchmarks; its CPU twin is `pf_core::GaussianObservation`.

use crate::context::GpuContext;
use crate::error::GpuError;
use crate::filter::{GpuLikelihood, LikelihoodInputs, LikelihoodPhase, RecordingId};
use crate::kernels::{Kernel, sources, stage_source};
use crate::stream::DeviceStream;

/// A Gaussian around each target's observed state, written by hand (the plug-in twin is [`TOY_MODEL`]).
pub struct ToyGaussianLikelihood {
    observed: DeviceStream<f32>,
    inv_sigma: DeviceStream<f32>,
    kernel: Kernel,
    bind_group: Option<wgpu::BindGroup>,
    groups: [u32; 3],
    /// Names the bind group and grid `record` records, until the next `prepare`.
    recording: Option<RecordingId>,
}

impl ToyGaussianLikelihood {
    /// `sigma` per dimension; observations are `[t·D + d]` for `targets` targets.
    pub fn new(ctx: &GpuContext, targets: usize, sigma: &[f32]) -> Result<Self, GpuError> {
        if sigma.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
            return Err(GpuError::InvalidConfig(
                "toy likelihood sigma must be finite and > 0".into(),
            ));
        }
        let inv: Vec<f32> = sigma.iter().map(|s| 1.0 / s).collect();
        Ok(Self {
            observed: DeviceStream::zeroed(ctx, "toy observations", targets * sigma.len())?,
            inv_sigma: DeviceStream::from_slice(ctx, "toy inverse sigma", &inv)?,
            kernel: Kernel::trusted(
                ctx,
                "toy likelihood",
                &stage_source(sources::TOY_LIKELIHOOD),
                "gaussian_log_likelihood",
            )?,
            bind_group: None,
            groups: [0; 3],
            recording: None,
        })
    }

    /// This frame's observations, `[t·D + d]`.
    pub fn upload_observations(&self, ctx: &GpuContext, observed: &[f32]) -> Result<(), GpuError> {
        self.observed.upload(ctx, observed)
    }
}

impl GpuLikelihood for ToyGaussianLikelihood {
    fn prepare(&mut self, ctx: &GpuContext, inputs: &LikelihoodInputs<'_>) -> Result<(), GpuError> {
        if self.observed.len() != inputs.shape.targets * inputs.shape.dims {
            return Err(GpuError::LengthMismatch {
                what: "toy observations".into(),
                expected: inputs.shape.targets * inputs.shape.dims,
                got: self.observed.len(),
            });
        }
        self.bind_group = Some(self.kernel.bind(
            ctx,
            &[
                (0, inputs.params.as_entire_binding()),
                (1, inputs.states.binding()),
                (2, inputs.log_likelihood.binding()),
                (3, self.observed.binding()),
                (4, self.inv_sigma.binding()),
            ],
        )?);
        self.groups = [
            inputs.shape.particles.div_ceil(64) as u32,
            inputs.shape.targets as u32,
            1,
        ];
        self.recording = Some(RecordingId::fresh());
        Ok(())
    }

    fn is_prepared(&self) -> bool {
        self.bind_group.is_some()
    }

    fn record(&self, phase: LikelihoodPhase, pass: &mut wgpu::ComputePass<'_>) {
        if !matches!(phase, LikelihoodPhase::Measure { .. }) {
            return;
        }
        if let Some(group) = &self.bind_group {
            self.kernel.record(pass, group, self.groups);
        }
    }

    fn recording_id(&self) -> Option<RecordingId> {
        self.recording
    }
}

/// The same toy model through the plug-in API ([`crate::model`]): seven dimensions, the
/// observation and σ⁻¹ per dimension. [`ToyTwin`] is its CPU twin. The benchmark
/// `whole_step_7d_1000` runs it beside [`ToyGaussianLikelihood`].
pub const TOY_MODEL: crate::model::ModelSource<'static> = crate::model::ModelSource {
    name: "toy Gaussian",
    wgsl: "
struct Observation { z: array<f32, 7> }
struct Constants { inv_sigma: array<f32, 7> }

fn log_likelihood(x: State, observation: Observation, c: Constants) -> f32 {
    var state = x;
    var z = observation.z;
    var inv_sigma = c.inv_sigma;
    var sum = 0.0;
    for (var d = 0u; d < DIMS; d = d + 1u) {
        var diff = state[d] - z[d];
        if (is_angle(d)) {
            diff = wrap_angle(diff);
        }
        let e = diff * inv_sigma[d];
        sum = sum + e * e;
    }
    return -0.5 * sum;
}
",
};

/// One target's observed 7-D state.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct ToyObservation {
    /// The observed state.
    pub z: [f32; 7],
}

/// σ⁻¹ per dimension.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct ToyConstants {
    /// 1/σ per dimension.
    pub inv_sigma: [f32; 7],
}

impl ToyConstants {
    /// From σ per dimension (finite and > 0).
    pub fn from_sigma(sigma: &[f32; 7]) -> Result<Self, GpuError> {
        if sigma.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
            return Err(GpuError::InvalidConfig(
                "toy likelihood sigma must be finite and > 0".into(),
            ));
        }
        Ok(Self {
            inv_sigma: sigma.map(|s| 1.0 / s),
        })
    }
}

/// The CPU twin of [`TOY_MODEL`]; `angular` says which dimensions are angles.
pub struct ToyTwin {
    /// Which dimensions are angles.
    pub angular: [bool; 7],
}

impl pf_core::plugin::CpuModel<ToyObservation, ToyConstants> for ToyTwin {
    fn log_likelihood(&self, x: &[f32], z: &ToyObservation, c: &ToyConstants) -> f32 {
        let sum: f32 = (0..7)
            .map(|d| {
                let mut diff = x[d] - z.z[d];
                if self.angular[d] {
                    diff = pf_core::batch::wrap_angle_floor(diff);
                }
                (diff * c.inv_sigma[d]).powi(2)
            })
            .sum();
        -0.5 * sum
    }
}
