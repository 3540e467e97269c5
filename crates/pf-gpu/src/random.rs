//! Counter-based random numbers on the GPU (`shaders/engine/random.wgsl`): raw Philox4x32-10 blocks and
//! Gaussian draws. The filter stages compute the same numbers inline; this launcher exists so that
//! the generator can be checked against its CPU twin bit for bit.

use bytemuck::{Pod, Zeroable};

use crate::context::GpuContext;
use crate::error::GpuError;
use crate::kernels::{Kernel, sources};
use crate::stream::DeviceStream;

#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct RandomParams {
    key: [u32; 2],
    count: u32,
    dims: u32,
    step_lo: u32,
    step_hi: u32,
    _pad: [u32; 2],
}

fn source() -> String {
    [sources::PHILOX, sources::RANDOM].join("\n")
}

fn run(
    ctx: &GpuContext,
    entry: &str,
    params: RandomParams,
    counters: &[[u32; 4]],
    normals_len: usize,
) -> Result<(Vec<[u32; 4]>, Vec<f32>), GpuError> {
    let kernel = Kernel::trusted(ctx, entry, &source(), entry)?;
    let counters_stream = DeviceStream::from_slice(ctx, "counters", counters)?;
    let words = DeviceStream::<[u32; 4]>::zeroed(ctx, "philox words", counters.len())?;
    let normals = DeviceStream::<f32>::zeroed(ctx, "normals", normals_len)?;
    let uniform = crate::stream::uniform_buffer(ctx, "random params (uniform)", &params)?;
    let entries: Vec<(u32, wgpu::BindingResource<'_>)> = if entry == "philox_blocks" {
        vec![
            (0, uniform.as_entire_binding()),
            (1, counters_stream.binding()),
            (2, words.binding()),
        ]
    } else {
        vec![(0, uniform.as_entire_binding()), (3, normals.binding())]
    };
    let group = kernel.bind(ctx, &entries)?;
    let mut encoder = ctx.device.create_command_encoder(&Default::default());
    {
        let mut pass = encoder.begin_compute_pass(&Default::default());
        kernel.record(&mut pass, &group, [params.count.div_ceil(64).max(1), 1, 1]);
    }
    ctx.queue.submit([encoder.finish()]);
    let words_out = if entry == "philox_blocks" {
        words.download(ctx)?
    } else {
        Vec::new()
    };
    let normals_out = if entry == "gaussians" {
        normals.download(ctx)?
    } else {
        Vec::new()
    };
    Ok((words_out, normals_out))
}

/// Philox4x32-10 of every counter under `key`, computed on the GPU.
pub fn philox_blocks(
    ctx: &GpuContext,
    key: [u32; 2],
    counters: &[[u32; 4]],
) -> Result<Vec<[u32; 4]>, GpuError> {
    let count = u32::try_from(counters.len())
        .map_err(|_| GpuError::InvalidConfig("too many counters".into()))?;
    let params = RandomParams {
        key,
        count,
        dims: 0,
        step_lo: 0,
        step_hi: 0,
        _pad: [0; 2],
    };
    Ok(run(ctx, "philox_blocks", params, counters, 0)?.0)
}

/// `counter_gaussian(key, m, d, step)` for m < particles, d < dims, as `[m·dims + d]`.
pub fn gaussians(
    ctx: &GpuContext,
    key: [u32; 2],
    particles: u32,
    dims: u32,
    step: u64,
) -> Result<Vec<f32>, GpuError> {
    let params = RandomParams {
        key,
        count: particles,
        dims,
        step_lo: step as u32,
        step_hi: (step >> 32) as u32,
        _pad: [0; 2],
    };
    let len = particles
        .checked_mul(dims)
        .ok_or_else(|| GpuError::InvalidConfig(format!("{particles} x {dims} draws overflow")))?;
    Ok(run(ctx, "gaussians", params, &[[0; 4]], len as usize)?.1)
}
