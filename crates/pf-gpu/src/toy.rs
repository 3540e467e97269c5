//! A toy GPU likelihood: a Gaussian around each target's observed state (`toy_likelihood.wgsl`).
//! It drives the driver tests and benchmarks; its CPU twin is `pf_core::GaussianObservation`.

use crate::context::GpuContext;
use crate::error::GpuError;
use crate::filter::{GpuLikelihood, LikelihoodInputs};
use crate::kernels::{Kernel, sources, stage_source};
use crate::stream::DeviceStream;

pub struct ToyGaussianLikelihood {
    observed: DeviceStream<f32>,
    inv_sigma: DeviceStream<f32>,
    kernel: Kernel,
    bind_group: Option<wgpu::BindGroup>,
    groups: [u32; 3],
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
            kernel: Kernel::new(
                ctx,
                "toy likelihood",
                &stage_source(sources::TOY_LIKELIHOOD),
                "gaussian_log_likelihood",
            )?,
            bind_group: None,
            groups: [0; 3],
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
        Ok(())
    }

    fn record(&self, pass: &mut wgpu::ComputePass<'_>) {
        if let Some(group) = &self.bind_group {
            self.kernel.record(pass, group, self.groups);
        }
    }
}
