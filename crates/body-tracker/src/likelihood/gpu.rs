//! The launcher of the body paper's ray-cast capsule likelihood (`shaders/body/likelihood.wgsl`,
//! [`SHADER`]) over plain layouts: rays `[dir.x, dir.y, dir.z, depth]` and, per sample, per capsule, two
//! `[f32; 4]`: `[a.x, a.y, a.z, r]`, `[b.x, b.y, b.z, 0]`. It returns M_j = Σ_i (min_k d_ik)² per
//! sample. CPU twin: [`super::listing_1_2`] (and [`super::culled_sum_of_squared_distances`],
//! the fast kernel's culling), in this module's parent.

use bytemuck::{Pod, Zeroable};

use pf_gpu::GpuContext;
use pf_gpu::GpuError;
use pf_gpu::kernels::Kernel;
use pf_gpu::stream::{DeviceStream, Readback};
use pf_gpu::wgpu;

pub use super::SHADER;
pub use super::gpu_rays::{PreparedRays, prepare_rays};
use super::{FAST_TILE, TILE};

/// The most capsules per sample the kernels stage in workgroup memory.
pub const MAX_CAPSULES: usize = 128;

/// Which kernel evaluates the pairs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CapsuleKernel {
    /// The paper's design: every (point, capsule) pair solves the quadratics from a, b, r.
    PaperLayout,
    /// Per-capsule terms once per sample and a bounding-sphere test before any quadratic.
    Fast,
}

#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct CapsuleParams {
    samples: u32,
    points: u32,
    capsules: u32,
    tiles: u32,
    sample_offset: u32,
    _pad: [u32; 3],
    origin: [f32; 3],
    tau: f32,
}

/// One dispatch chunk of samples (the grid's y dimension is limited by the adapter).
struct Chunk {
    samples: u32,
    groups: Vec<wgpu::BindGroup>,
    _params: wgpu::Buffer,
}

/// The GPU likelihood for `samples` samples × `points` points × `capsules` capsules.
pub struct CapsuleLikelihoodGpu {
    kind: CapsuleKernel,
    samples: usize,
    points: usize,
    capsules_per_sample: usize,
    tiles: usize,
    rays: DeviceStream<[f32; 4]>,
    capsules: DeviceStream<[f32; 4]>,
    sums: DeviceStream<f32>,
    /// Per fast tile: (unit axis, half-angle) of the cone holding its rays.
    tile_cones: DeviceStream<[f32; 4]>,
    _partials: DeviceStream<f32>,
    _terms: DeviceStream<[f32; 24]>,
    kernels: Vec<Kernel>,
    chunks: Vec<Chunk>,
    sums_back: Readback<f32>,
}

/// Checks the configuration against the kernels' and the adapter's limits; returns the number
/// of point tiles and the lengths of the capsule and partial-sum buffers.
fn checked_sizes(
    ctx: &GpuContext,
    kind: CapsuleKernel,
    samples: usize,
    points: usize,
    capsules_per_sample: usize,
    origin: [f32; 3],
    tau: f32,
) -> Result<(usize, usize, usize), GpuError> {
    if samples == 0 || points == 0 || capsules_per_sample == 0 {
        return Err(GpuError::InvalidConfig(format!(
            "the capsule likelihood needs samples, points and capsules (got {samples}, {points}, {capsules_per_sample})"
        )));
    }
    if capsules_per_sample > MAX_CAPSULES {
        return Err(GpuError::InvalidConfig(format!(
            "{capsules_per_sample} capsules per sample; the kernels hold at most {MAX_CAPSULES}"
        )));
    }
    if !(tau.is_finite() && tau > 0.0 && origin.iter().all(|x| x.is_finite())) {
        return Err(GpuError::InvalidConfig(format!(
            "invalid tau {tau} or camera origin {origin:?}"
        )));
    }
    let tiles = points.div_ceil(if kind == CapsuleKernel::Fast {
        FAST_TILE
    } else {
        TILE
    });
    let max_groups = ctx.limits().max_compute_workgroups_per_dimension as usize;
    if tiles > max_groups {
        return Err(GpuError::InvalidConfig(format!(
            "{points} points need {tiles} tiles, over the adapter's {max_groups} workgroups per dimension"
        )));
    }
    let too_big = |what: &str| GpuError::InvalidConfig(format!("{what} overflow 32-bit indices"));
    let capsule_values = samples
        .checked_mul(capsules_per_sample * 2)
        .ok_or_else(|| too_big("capsules"))?;
    let partial_values = samples
        .checked_mul(tiles)
        .ok_or_else(|| too_big("partial sums"))?;
    if capsule_values > u32::MAX as usize
        || partial_values > u32::MAX as usize
        || points > u32::MAX as usize
    {
        return Err(too_big("the buffers"));
    }
    Ok((tiles, capsule_values, partial_values))
}

/// The streams a chunk's bind groups use.
struct ChunkStreams<'a> {
    rays: &'a DeviceStream<[f32; 4]>,
    capsules: &'a DeviceStream<[f32; 4]>,
    partials: &'a DeviceStream<f32>,
    terms: &'a DeviceStream<[f32; 24]>,
    sums: &'a DeviceStream<f32>,
    tile_cones: &'a DeviceStream<[f32; 4]>,
}

/// One dispatch chunk of `count` samples (at most the adapter's grid): its parameter buffer and
/// a bind group per kernel, by the `@binding` numbers of `shaders/body/likelihood.wgsl`.
fn chunk(
    ctx: &GpuContext,
    kernels: &[Kernel],
    params: &CapsuleParams,
    count: usize,
    s: &ChunkStreams<'_>,
) -> Result<Chunk, GpuError> {
    let buffer = pf_gpu::stream::uniform_buffer(ctx, "capsule likelihood params", params)?;
    let groups = kernels
        .iter()
        .map(|k| {
            let p = buffer.as_entire_binding();
            let entries: Vec<(u32, wgpu::BindingResource<'_>)> = match k.name() {
                "paper_layout" => vec![
                    (0, p),
                    (1, s.capsules.binding()),
                    (2, s.rays.binding()),
                    (3, s.partials.binding()),
                ],
                "capsule_terms" => vec![(0, p), (1, s.capsules.binding()), (4, s.terms.binding())],
                "fast" => vec![
                    (0, p),
                    (2, s.rays.binding()),
                    (3, s.partials.binding()),
                    (4, s.terms.binding()),
                    (6, s.tile_cones.binding()),
                ],
                _ => vec![(0, p), (3, s.partials.binding()), (5, s.sums.binding())],
            };
            k.bind(ctx, &entries)
        })
        .collect::<Result<Vec<_>, _>>()?;
    Ok(Chunk {
        samples: count as u32,
        groups,
        _params: buffer,
    })
}

impl CapsuleLikelihoodGpu {
    /// A likelihood for `samples` × `points` × `capsules` with the given kernel, camera centre and τ.
    pub fn new(
        ctx: &GpuContext,
        kind: CapsuleKernel,
        samples: usize,
        points: usize,
        capsules_per_sample: usize,
        origin: [f32; 3],
        tau: f32,
    ) -> Result<Self, GpuError> {
        let (tiles, capsule_values, partial_values) =
            checked_sizes(ctx, kind, samples, points, capsules_per_sample, origin, tau)?;
        let max_groups = ctx.limits().max_compute_workgroups_per_dimension as usize;
        let rays = DeviceStream::zeroed(ctx, "rays", points)?;
        let capsules = DeviceStream::zeroed(ctx, "capsules", capsule_values)?;
        let partials = DeviceStream::zeroed(ctx, "likelihood partial sums", partial_values)?;
        let terms = DeviceStream::zeroed(
            ctx,
            "capsule terms",
            if kind == CapsuleKernel::Fast {
                samples * capsules_per_sample
            } else {
                1
            },
        )?;
        let sums = DeviceStream::zeroed(ctx, "likelihood sums", samples)?;
        let tile_cones = DeviceStream::zeroed(ctx, "tile cones", tiles)?;
        let entries: &[&str] = match kind {
            CapsuleKernel::PaperLayout => &["paper_layout", "reduce_partials"],
            CapsuleKernel::Fast => &["capsule_terms", "fast", "reduce_partials"],
        };
        let kernels = entries
            .iter()
            .map(|e| Kernel::new(ctx, e, SHADER, e))
            .collect::<Result<Vec<_>, _>>()?;
        let streams = ChunkStreams {
            rays: &rays,
            capsules: &capsules,
            partials: &partials,
            terms: &terms,
            sums: &sums,
            tile_cones: &tile_cones,
        };
        let mut chunks = Vec::new();
        let mut offset = 0;
        while offset < samples {
            let count = (samples - offset).min(max_groups);
            let params = CapsuleParams {
                samples: samples as u32,
                points: points as u32,
                capsules: capsules_per_sample as u32,
                tiles: tiles as u32,
                sample_offset: offset as u32,
                _pad: [0; 3],
                origin,
                tau,
            };
            chunks.push(chunk(ctx, &kernels, &params, count, &streams)?);
            offset += count;
        }
        Ok(Self {
            kind,
            samples,
            points,
            capsules_per_sample,
            tiles,
            sums_back: Readback::new(ctx, "likelihood sums readback", samples)?,
            rays,
            capsules,
            sums,
            tile_cones,
            _partials: partials,
            _terms: terms,
            kernels,
            chunks,
        })
    }

    /// The kernel it runs.
    pub fn kind(&self) -> CapsuleKernel {
        self.kind
    }

    /// This frame's rays, `[dir, depth]` per point (exactly `points` of them).
    ///
    /// For the fast kernel the rays are first put in Morton (Z-curve) order of their direction, so
    /// that each tile of 1 024 rays covers a compact patch of the view and its cone is narrow;
    /// M_j is a sum over points, so their order does not change it.
    pub fn upload_rays(&self, ctx: &GpuContext, rays: &[[f32; 4]]) -> Result<(), GpuError> {
        if self.kind != CapsuleKernel::Fast {
            return self.rays.upload(ctx, rays);
        }
        self.upload_prepared_rays(ctx, &prepare_rays(rays))
    }

    /// Rays already put in order with their cones by [`prepare_rays`] (one preparation for
    /// several likelihoods over the same frame); for the fast kernel.
    pub fn upload_prepared_rays(
        &self,
        ctx: &GpuContext,
        prepared: &PreparedRays,
    ) -> Result<(), GpuError> {
        self.rays.upload(ctx, &prepared.ordered)?;
        self.tile_cones.upload(ctx, &prepared.tile_cones)
    }

    /// Every sample's capsules, `samples × capsules × 2` values.
    pub fn upload_capsules(&self, ctx: &GpuContext, capsules: &[[f32; 4]]) -> Result<(), GpuError> {
        self.capsules.upload(ctx, capsules)
    }

    /// Records the evaluation in its own compute pass: per chunk, (terms,) pairs, reduction.
    pub fn record(&self, encoder: &mut wgpu::CommandEncoder) {
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("capsule likelihood"),
            timestamp_writes: None,
        });
        self.record_in(&mut pass);
    }

    /// Records the evaluation into an open compute pass.
    pub fn record_in(&self, pass: &mut wgpu::ComputePass<'_>) {
        for chunk in &self.chunks {
            for (kernel, group) in self.kernels.iter().zip(&chunk.groups) {
                let groups = match kernel.name() {
                    "capsule_terms" => [
                        self.capsules_per_sample.div_ceil(64) as u32,
                        chunk.samples,
                        1,
                    ],
                    "reduce_partials" => [1, chunk.samples, 1],
                    _ => [self.tiles as u32, chunk.samples, 1],
                };
                kernel.record(pass, group, groups);
            }
        }
    }

    /// Evaluates M_j for every sample: one submission, the sums read back.
    pub fn evaluate(&self, ctx: &GpuContext) -> Result<Vec<f32>, GpuError> {
        let mut encoder = ctx.device.create_command_encoder(&Default::default());
        let submission = ctx.scoped("evaluating the capsule likelihood", || {
            self.record(&mut encoder);
            self.sums_back.record_copy(&mut encoder, &self.sums);
            ctx.queue.submit([encoder.finish()])
        })?;
        self.sums_back.read(ctx, Some(submission))
    }

    /// The capsules the kernels read, for a producer on the GPU (forward kinematics).
    pub(crate) fn capsule_stream(&self) -> &DeviceStream<[f32; 4]> {
        &self.capsules
    }

    /// M_j per sample, as the last recorded evaluation left them.
    pub(crate) fn sum_stream(&self) -> &DeviceStream<f32> {
        &self.sums
    }

    /// (samples, points, capsules).
    pub fn shape(&self) -> (usize, usize, usize) {
        (self.samples, self.points, self.capsules_per_sample)
    }
}

#[cfg(test)]
mod tests {
    use super::CapsuleParams;

    #[test]
    fn capsule_params_mirror_their_wgsl_layout() {
        use std::mem::{offset_of, size_of};
        let fields = [
            ("samples", offset_of!(CapsuleParams, samples)),
            ("points", offset_of!(CapsuleParams, points)),
            ("capsules", offset_of!(CapsuleParams, capsules)),
            ("tiles", offset_of!(CapsuleParams, tiles)),
            ("sample_offset", offset_of!(CapsuleParams, sample_offset)),
            ("origin", offset_of!(CapsuleParams, origin)),
            ("tau", offset_of!(CapsuleParams, tau)),
        ];
        pf_gpu::kernels::assert_mirrors_wgsl(
            super::SHADER,
            "CapsuleParams",
            size_of::<CapsuleParams>(),
            &fields,
        );
    }
}
