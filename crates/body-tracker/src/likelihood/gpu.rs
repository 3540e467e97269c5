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
pub use super::gpu_rays::{END_MARKER, PreparedRays, RayLevel, prepare_ray_levels, prepare_rays};
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
    first_tile: u32,
    _pad: [u32; 2],
    origin: [f32; 3],
    tau: f32,
}

/// One dispatch chunk of samples (the grid's y dimension is limited by the adapter).
struct Chunk {
    samples: u32,
    groups: Vec<wgpu::BindGroup>,
    _params: wgpu::Buffer,
}

/// The GPU likelihood for `samples` samples × `points` points × `capsules` capsules. The fast
/// kernel's rays may come in several levels ([`PreparedRays`]: level 0 every point, later ones
/// subsets), each evaluated on its own ([`Self::record_level_in`]).
pub struct CapsuleLikelihoodGpu {
    kind: CapsuleKernel,
    samples: usize,
    /// Level 0's points (the configured number).
    points: usize,
    capsules_per_sample: usize,
    /// Per level, its point tiles (one level for the paper's kernel).
    level_tiles: Vec<usize>,
    rays: DeviceStream<[f32; 4]>,
    capsules: DeviceStream<[f32; 4]>,
    sums: DeviceStream<f32>,
    /// Per fast tile: (unit axis, half-angle) of the cone holding its rays.
    tile_cones: DeviceStream<[f32; 4]>,
    _partials: DeviceStream<f32>,
    _terms: DeviceStream<[f32; 24]>,
    kernels: Vec<Kernel>,
    /// Per level, its dispatch chunks.
    chunks: Vec<Vec<Chunk>>,
    sums_back: Readback<f32>,
}

/// The sizes of a likelihood's buffers, checked against the kernels' and the adapter's limits.
struct Sizes {
    /// Point tiles per level.
    level_tiles: Vec<usize>,
    /// Rays in the buffer: every level's, padded to whole tiles (the fast kernel), or the
    /// points (the paper's).
    rays: usize,
    capsule_values: usize,
    partial_values: usize,
}

/// Checks the configuration against the kernels' and the adapter's limits; returns the sizes
/// of the buffers.
fn checked_sizes(
    ctx: &GpuContext,
    kind: CapsuleKernel,
    samples: usize,
    level_points: &[usize],
    capsules_per_sample: usize,
    origin: [f32; 3],
    tau: f32,
) -> Result<Sizes, GpuError> {
    let bad = |m: String| Err(GpuError::InvalidConfig(m));
    if samples == 0
        || capsules_per_sample == 0
        || level_points.is_empty()
        || level_points.contains(&0)
    {
        return bad(format!(
            "the capsule likelihood needs samples, points and capsules (got {samples}, {level_points:?}, {capsules_per_sample})"
        ));
    }
    if kind == CapsuleKernel::PaperLayout && level_points.len() > 1 {
        return bad("the paper's kernel weighs one level of points".into());
    }
    if capsules_per_sample > MAX_CAPSULES {
        return bad(format!(
            "{capsules_per_sample} capsules per sample; the kernels hold at most {MAX_CAPSULES}"
        ));
    }
    if !(tau.is_finite() && tau > 0.0 && origin.iter().all(|x| x.is_finite())) {
        return bad(format!("invalid tau {tau} or camera origin {origin:?}"));
    }
    let tile = if kind == CapsuleKernel::Fast {
        FAST_TILE
    } else {
        TILE
    };
    let level_tiles: Vec<usize> = level_points.iter().map(|p| p.div_ceil(tile)).collect();
    let max_tiles = level_tiles.iter().copied().max().unwrap_or(0);
    let max_groups = ctx.limits().max_compute_workgroups_per_dimension as usize;
    if max_tiles > max_groups {
        return bad(format!(
            "{} points need {max_tiles} tiles, over the adapter's {max_groups} workgroups per dimension",
            level_points[0]
        ));
    }
    let rays = match kind {
        CapsuleKernel::Fast => level_tiles.iter().sum::<usize>() * FAST_TILE,
        CapsuleKernel::PaperLayout => level_points[0],
    };
    let too_big = |what: &str| GpuError::InvalidConfig(format!("{what} overflow 32-bit indices"));
    let capsule_values = samples
        .checked_mul(capsules_per_sample * 2)
        .ok_or_else(|| too_big("capsules"))?;
    let partial_values = samples
        .checked_mul(max_tiles)
        .ok_or_else(|| too_big("partial sums"))?;
    if capsule_values > u32::MAX as usize
        || partial_values > u32::MAX as usize
        || rays > u32::MAX as usize
    {
        return Err(too_big("the buffers"));
    }
    Ok(Sizes {
        level_tiles,
        rays,
        capsule_values,
        partial_values,
    })
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

/// The kernels of `kind`, in the order a level records them.
fn kernels_of(ctx: &GpuContext, kind: CapsuleKernel) -> Result<Vec<Kernel>, GpuError> {
    let entries: &[&str] = match kind {
        CapsuleKernel::PaperLayout => &["paper_layout", "reduce_partials"],
        CapsuleKernel::Fast => &["capsule_terms", "fast", "reduce_partials"],
    };
    entries
        .iter()
        .map(|e| Kernel::trusted(ctx, e, SHADER, e))
        .collect()
}

/// One level's dispatch chunks: the samples split so that each chunk's grid fits the
/// adapter's limit.
fn sample_chunks(
    ctx: &GpuContext,
    kernels: &[Kernel],
    params: CapsuleParams,
    streams: &ChunkStreams<'_>,
) -> Result<Vec<Chunk>, GpuError> {
    let samples = params.samples as usize;
    let max_groups = ctx.limits().max_compute_workgroups_per_dimension as usize;
    let mut chunks = Vec::new();
    let mut offset = 0;
    while offset < samples {
        let count = (samples - offset).min(max_groups);
        let params = CapsuleParams {
            sample_offset: offset as u32,
            ..params
        };
        chunks.push(chunk(ctx, kernels, &params, count, streams)?);
        offset += count;
    }
    Ok(chunks)
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
        Self::with_levels(
            ctx,
            kind,
            samples,
            &[points],
            capsules_per_sample,
            origin,
            tau,
        )
    }

    /// A fast-kernel likelihood over rays in levels of at most `level_points[l]` points each
    /// (level 0 every point, later levels the subsets that coarse layers weigh).
    pub fn with_levels(
        ctx: &GpuContext,
        kind: CapsuleKernel,
        samples: usize,
        level_points: &[usize],
        capsules_per_sample: usize,
        origin: [f32; 3],
        tau: f32,
    ) -> Result<Self, GpuError> {
        let sizes = checked_sizes(
            ctx,
            kind,
            samples,
            level_points,
            capsules_per_sample,
            origin,
            tau,
        )?;
        let rays = DeviceStream::zeroed(ctx, "rays", sizes.rays)?;
        let capsules = DeviceStream::zeroed(ctx, "capsules", sizes.capsule_values)?;
        let partials = DeviceStream::zeroed(ctx, "likelihood partial sums", sizes.partial_values)?;
        let terms_len = match kind {
            CapsuleKernel::Fast => samples * capsules_per_sample,
            CapsuleKernel::PaperLayout => 1,
        };
        let terms = DeviceStream::zeroed(ctx, "capsule terms", terms_len)?;
        let sums = DeviceStream::zeroed(ctx, "likelihood sums", samples)?;
        let all_tiles = sizes.level_tiles.iter().sum::<usize>();
        let tile_cones = DeviceStream::zeroed(ctx, "tile cones", all_tiles)?;
        let kernels = kernels_of(ctx, kind)?;
        let streams = ChunkStreams {
            rays: &rays,
            capsules: &capsules,
            partials: &partials,
            terms: &terms,
            sums: &sums,
            tile_cones: &tile_cones,
        };
        let mut chunks = Vec::with_capacity(sizes.level_tiles.len());
        let mut first_tile = 0;
        for &tiles in &sizes.level_tiles {
            let params = CapsuleParams {
                samples: samples as u32,
                points: sizes.rays as u32,
                capsules: capsules_per_sample as u32,
                tiles: tiles as u32,
                sample_offset: 0,
                first_tile: first_tile as u32,
                _pad: [0; 2],
                origin,
                tau,
            };
            chunks.push(sample_chunks(ctx, &kernels, params, &streams)?);
            first_tile += tiles;
        }
        Ok(Self {
            kind,
            samples,
            points: level_points[0],
            capsules_per_sample,
            level_tiles: sizes.level_tiles,
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
        let tiles: Vec<usize> = prepared.levels.iter().map(|l| l.tiles).collect();
        if self.kind != CapsuleKernel::Fast || tiles != self.level_tiles {
            return Err(GpuError::InvalidConfig(format!(
                "rays prepared in levels of {tiles:?} tiles; this {:?} likelihood takes {:?}",
                self.kind, self.level_tiles
            )));
        }
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

    /// Records the evaluation (of level 0, every point) into an open compute pass.
    pub fn record_in(&self, pass: &mut wgpu::ComputePass<'_>) {
        self.record_level_in(0, pass);
    }

    /// The number of levels of points it weighs.
    pub fn levels(&self) -> usize {
        self.level_tiles.len()
    }

    /// Records the evaluation of level `level`'s points (level 0 when there is no such level)
    /// into an open compute pass: the sums are M over that level's points only.
    pub fn record_level_in(&self, level: usize, pass: &mut wgpu::ComputePass<'_>) {
        let level = if level < self.level_tiles.len() {
            level
        } else {
            0
        };
        let tiles = self.level_tiles[level] as u32;
        for chunk in &self.chunks[level] {
            for (kernel, group) in self.kernels.iter().zip(&chunk.groups) {
                let groups = match kernel.name() {
                    "capsule_terms" => [
                        self.capsules_per_sample.div_ceil(64) as u32,
                        chunk.samples,
                        1,
                    ],
                    "reduce_partials" => [1, chunk.samples, 1],
                    _ => [tiles, chunk.samples, 1],
                };
                kernel.record(pass, group, groups);
            }
        }
    }

    /// Evaluates M_j for every sample: one submission, the sums read back.
    pub fn evaluate(&self, ctx: &GpuContext) -> Result<Vec<f32>, GpuError> {
        self.evaluate_level(ctx, 0)
    }

    /// Evaluates M_j over level `level`'s points only (a coarse subset): one submission, the
    /// sums read back.
    pub fn evaluate_level(&self, ctx: &GpuContext, level: usize) -> Result<Vec<f32>, GpuError> {
        if level >= self.levels() {
            return Err(GpuError::InvalidConfig(format!(
                "level {level} of points; this likelihood has {}",
                self.levels()
            )));
        }
        let mut encoder = ctx.device.create_command_encoder(&Default::default());
        let submission = ctx.scoped("evaluating the capsule likelihood", || {
            {
                let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("capsule likelihood"),
                    timestamp_writes: None,
                });
                self.record_level_in(level, &mut pass);
            }
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
            ("first_tile", offset_of!(CapsuleParams, first_tile)),
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
