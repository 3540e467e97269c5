//! The launcher of the face paper's sparse-template likelihood (`shaders/face/likelihood.wgsl`, [`super::SHADER`])
//! over plain layouts: the frame as a texture of 8-bit gray levels, read through the texture unit's
//! bilinear filter ([`pf_gpu::GrayTexture`]), and per face up to `max_points` feature
//! points as two `[f32; 4]` each, (P, J) and (N, 0). It is a [`GpuLikelihood`]: inside the GPU
//! filter it reads the particles where they are and writes log π = −sharpness·ln ε, and it keeps
//! ε per particle for failure detection. CPU twin: [`super::residual_error`], in this module's parent.

use bytemuck::{Pod, Zeroable};

use pf_gpu::GpuContext;
use pf_gpu::GpuError;
use pf_gpu::GrayTexture;
use pf_gpu::filter::{
    GpuLikelihood, LikelihoodInputs, LikelihoodPhase, ReadbackSource, RecordingId,
};
use pf_gpu::kernels::{Kernel, KernelOptions, ShaderChecks, stage_source};
use pf_gpu::stream::DeviceStream;
use pf_gpu::wgpu;

use crate::lens::Lens;

/// How the faces of a frame are dispatched.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FaceDispatch {
    /// The paper's layout (a workgroup per particle, an invocation per point), one dispatch per
    /// face, as the paper launches one kernel per face.
    PerFace,
    /// The paper's layout, every face of the frame in one dispatch (grid: particles × faces).
    Batched,
    /// `lanes` invocations a particle looping over the points (a power of two up to 256: 256 /
    /// `lanes` particles a workgroup), every face in one dispatch; up to [`STAGED_MAX_LANES`]
    /// the workgroup reads its face's template into workgroup memory first.
    Packed { lanes: u32 },
    /// The packed kernel with the lanes a particle chosen from the frame's particles
    /// ([`packed_lanes_for`]): the tracker's choice.
    PackedByLoad,
}

/// Invocations a packed dispatch aims at: about as many as an NVIDIA H100 keeps resident (132
/// SMs × 2 048). Measured there (docs/BENCHMARKS.md, "Lanes a particle"): with fewer the
/// weighing waits on each point's texture read, with more each particle's pose set-up and
/// reduction are repeated for nothing.
pub const PACKED_TARGET_INVOCATIONS: usize = 1 << 18;

/// The lanes a particle [`FaceDispatch::PackedByLoad`] weighs `particles` (every face's, one
/// frame) with: the largest power of two that keeps particles × lanes within
/// [`PACKED_TARGET_INVOCATIONS`], between 4 and 64. On the H100 one face of 1 000 particles
/// weighed fastest with 64–128 lanes, 16 faces with 8–16, 64 faces with 4.
pub fn packed_lanes_for(particles: usize) -> u32 {
    let fits = PACKED_TARGET_INVOCATIONS / particles.max(1);
    let lanes = if fits == 0 { 1 } else { 1 << fits.ilog2() };
    lanes.clamp(4, 64) as u32
}

/// Invocations in a workgroup of the face kernels (`WG` in the shader).
const WORKGROUP: u32 = 256;

/// The most lanes a particle for which the packed weighing stages each face's template in
/// workgroup memory (`weigh_faces_packed_staged`: sixteen or more particles a workgroup share
/// one read of it). Measured on an NVIDIA H200 (docs/BENCHMARKS.md, "Template points in
/// workgroup memory"): 64 faces with 4 lanes weighed in 32.9–33.3 µs a layer instead of
/// 37.3–37.8, 16 faces with 16 in 16.2–16.5 µs instead of 16.8–17.2; with 64 lanes (four
/// particles a workgroup) staging was slower, 12.1–12.5 µs against 10.0–10.4 for 4 faces.
pub const STAGED_MAX_LANES: u32 = 16;

#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct FaceParams {
    width: u32,
    height: u32,
    max_points: u32,
    face_offset: u32,
    sharpness: f32,
    min_error: f32,
    min_visible_share: f32,
    /// The camera ([`Lens`]): 1/f (0: weak perspective) and the principal point.
    inverse_focal: f32,
    principal_x: f32,
    principal_y: f32,
    /// 1/width and 1/height: where the texture's pixel centres lie.
    texel_x: f32,
    texel_y: f32,
}

/// The check of each face's estimate: ε per face, read back with the step
/// ([`FaceLikelihoodGpu::ESTIMATE_ERRORS`]).
struct EstimateCheck {
    group: wgpu::BindGroup,
    errors: DeviceStream<f32>,
}

/// The face likelihood for `faces` faces of up to `max_points` points on `width × height` frames.
pub struct FaceLikelihoodGpu {
    dispatch: FaceDispatch,
    faces: usize,
    max_points: usize,
    width: u32,
    height: u32,
    /// The frame's 8-bit gray levels.
    frame: GrayTexture,
    points: DeviceStream<[f32; 4]>,
    counts: DeviceStream<u32>,
    errors: Option<DeviceStream<f32>>,
    /// ε of each face's pose estimate, computed after the filter's Estimate stage.
    estimate_check: Option<EstimateCheck>,
    estimate_kernel: Kernel,
    /// One parameter buffer per dispatch (face offsets 0.. for PerFace, one for Batched and
    /// the packed layouts).
    params: Vec<wgpu::Buffer>,
    /// The weighing kernel, built by `prepare` (its lanes a particle may depend on the
    /// filter's particles).
    kernel: Option<Kernel>,
    groups: Vec<wgpu::BindGroup>,
    particles: u32,
    /// The packed kernel's lanes a particle, chosen by `prepare` (`None`: a workgroup a
    /// particle).
    lanes: Option<u32>,
    /// Names what `prepare` built (the kernels, groups and grids `record` records, the
    /// readbacks' buffers); the rest of this likelihood's state is data written before a step.
    recording: Option<RecordingId>,
}

impl FaceLikelihoodGpu {
    /// The name of the step report's readback of ε at each face's pose estimate (`[t]`, `f32`):
    /// the same ε as the particles' (the CPU twin is `residual_error` at the estimate), computed
    /// after the Estimate stage in the step's submission.
    pub const ESTIMATE_ERRORS: &'static str = "face estimate errors";

    /// `sharpness` γ in π ∝ ε^−γ (the paper's π ∝ 1/ε is γ = 1; γ = 0 weighs every particle the
    /// same, the diffusion-only baseline); ε is floored at `min_error`, and is 1 for a pose that shows less than `min_visible_share` of its face's points.
    /// Points are seen through `lens` ([`Lens::WEAK`]: the paper's weak perspective).
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        ctx: &GpuContext,
        dispatch: FaceDispatch,
        faces: usize,
        max_points: usize,
        width: u32,
        height: u32,
        sharpness: f32,
        min_error: f32,
        min_visible_share: f32,
        lens: Lens,
    ) -> Result<Self, GpuError> {
        if faces == 0 || max_points == 0 || width < 2 || height < 2 {
            return Err(GpuError::InvalidConfig(format!(
                "the face likelihood needs faces, points and a frame of at least 2x2 (got {faces} faces, {max_points} points, {width}x{height})"
            )));
        }
        check_weighing(&lens, sharpness, min_error, min_visible_share)?;
        let point_values = faces
            .checked_mul(max_points * 2)
            .filter(|&n| n <= u32::MAX as usize)
            .ok_or_else(|| GpuError::InvalidConfig("too many feature points".into()))?;
        let frame = GrayTexture::new(ctx, "face frame", width, height)?;
        let points = DeviceStream::zeroed(ctx, "feature points", point_values)?;
        let counts = DeviceStream::zeroed(ctx, "feature point counts", faces)?;
        if let FaceDispatch::Packed { lanes } = dispatch {
            check_lanes(lanes)?;
        }
        let estimate_kernel = Kernel::trusted(
            ctx,
            "face estimate check",
            &stage_source(super::SHADER),
            "weigh_estimates",
        )?;
        let every_face = FaceParams {
            width,
            height,
            max_points: max_points as u32,
            face_offset: 0,
            sharpness,
            min_error,
            min_visible_share,
            inverse_focal: lens.inverse_focal,
            principal_x: lens.principal[0],
            principal_y: lens.principal[1],
            texel_x: 1.0 / width as f32,
            texel_y: 1.0 / height as f32,
        };
        let params = params_per_dispatch(ctx, dispatch, faces, every_face)?;
        Ok(Self {
            dispatch,
            faces,
            max_points,
            width,
            height,
            frame,
            points,
            counts,
            errors: None,
            estimate_check: None,
            estimate_kernel,
            params,
            kernel: None,
            groups: Vec::new(),
            particles: 0,
            lanes: None,
            recording: None,
        })
    }

    /// The dispatch layout it runs.
    pub fn dispatch(&self) -> FaceDispatch {
        self.dispatch
    }

    /// This frame's 8-bit gray levels, `[y·width + x]`: the one upload of a frame.
    pub fn upload_frame(&self, ctx: &GpuContext, gray: &[u8]) -> Result<(), GpuError> {
        self.frame.upload(ctx, gray)
    }

    /// Face `face`'s template: `[(P, J), (N, 0)]` per point, at most `max_points` points.
    pub fn upload_template(
        &self,
        ctx: &GpuContext,
        face: usize,
        points: &[[f32; 4]],
    ) -> Result<(), GpuError> {
        if face >= self.faces
            || !points.len().is_multiple_of(2)
            || points.len() / 2 > self.max_points
        {
            return Err(GpuError::InvalidConfig(format!(
                "template for face {face} of {}: {} values (two per point, at most {} points)",
                self.faces,
                points.len(),
                self.max_points
            )));
        }
        self.points
            .upload_at(ctx, face * self.max_points * 2, points)?;
        self.counts
            .upload_at(ctx, face, &[(points.len() / 2) as u32])
    }

    /// ε of every particle of every face (`[t·M + m]`) as the last step left them.
    pub fn download_errors(&self, ctx: &GpuContext) -> Result<Vec<f32>, GpuError> {
        match &self.errors {
            Some(errors) => errors.download(ctx),
            None => Err(GpuError::InvalidConfig(
                "the face likelihood has not been prepared for a filter".into(),
            )),
        }
    }

    /// The per-particle ε stream, for a readback in the frame's submission.
    pub fn error_stream(&self) -> Option<&DeviceStream<f32>> {
        self.errors.as_ref()
    }

    /// The frame size it was built for (width, height).
    pub fn frame_size(&self) -> (u32, u32) {
        (self.width, self.height)
    }
}

impl GpuLikelihood for FaceLikelihoodGpu {
    fn prepare(&mut self, ctx: &GpuContext, inputs: &LikelihoodInputs<'_>) -> Result<(), GpuError> {
        let shape = inputs.shape;
        if shape.targets != self.faces || shape.dims != 7 {
            return Err(GpuError::InvalidConfig(format!(
                "the face likelihood was built for {} faces of 7 values; the filter has {} targets of {}",
                self.faces, shape.targets, shape.dims
            )));
        }
        let errors = DeviceStream::zeroed(ctx, "face errors", shape.particle_len())?;
        let lanes = match self.dispatch {
            FaceDispatch::PerFace | FaceDispatch::Batched => None,
            FaceDispatch::Packed { lanes } => Some(lanes),
            FaceDispatch::PackedByLoad => Some(packed_lanes_for(shape.particle_len())),
        };
        let kernel = weighing_kernel(ctx, lanes)?;
        self.groups = self
            .params
            .iter()
            .map(|p| {
                kernel.bind(
                    ctx,
                    &[
                        (0, inputs.params.as_entire_binding()),
                        (1, inputs.states.binding()),
                        (2, inputs.log_likelihood.binding()),
                        (3, p.as_entire_binding()),
                        (4, self.frame.binding()),
                        (10, self.frame.sampler_binding()),
                        (5, self.points.binding()),
                        (6, self.counts.binding()),
                        (7, errors.binding()),
                    ],
                )
            })
            .collect::<Result<_, _>>()?;
        self.errors = Some(errors);
        self.kernel = Some(kernel);
        self.particles = shape.particles as u32;
        self.lanes = lanes;
        let estimate_errors = DeviceStream::zeroed(ctx, "face estimate errors", self.faces)?;
        let group = self.estimate_kernel.bind(
            ctx,
            &[
                (0, inputs.params.as_entire_binding()),
                (3, self.params[0].as_entire_binding()),
                (4, self.frame.binding()),
                (10, self.frame.sampler_binding()),
                (5, self.points.binding()),
                (6, self.counts.binding()),
                (8, inputs.estimates.binding()),
                (9, estimate_errors.binding()),
            ],
        )?;
        self.estimate_check = Some(EstimateCheck {
            group,
            errors: estimate_errors,
        });
        self.recording = Some(RecordingId::fresh());
        Ok(())
    }

    fn is_prepared(&self) -> bool {
        self.errors.is_some()
    }

    fn record(&self, phase: LikelihoodPhase, pass: &mut wgpu::ComputePass<'_>) {
        match phase {
            LikelihoodPhase::Measure { .. } => {
                let Some(kernel) = &self.kernel else {
                    return;
                };
                let faces = self.faces as u32;
                let (x, y) = match (self.dispatch, self.lanes) {
                    (FaceDispatch::PerFace, _) => (self.particles, 1),
                    (_, Some(lanes)) => (self.particles.div_ceil(WORKGROUP / lanes), faces),
                    (_, None) => (self.particles, faces),
                };
                for group in &self.groups {
                    kernel.record(pass, group, [x, y, 1]);
                }
            }
            LikelihoodPhase::AfterEstimate => {
                if let Some(check) = &self.estimate_check {
                    self.estimate_kernel
                        .record(pass, &check.group, [1, self.faces as u32, 1]);
                }
            }
            LikelihoodPhase::Propagate => {}
        }
    }

    fn readbacks(&self) -> Vec<ReadbackSource<'_>> {
        self.estimate_check
            .iter()
            .map(|check| ReadbackSource::of(Self::ESTIMATE_ERRORS, &check.errors))
            .collect()
    }

    fn recording_id(&self) -> Option<RecordingId> {
        self.recording
    }
}

/// Refuses lanes a particle that do not divide a workgroup.
fn check_lanes(lanes: u32) -> Result<(), GpuError> {
    if lanes.is_power_of_two() && lanes <= WORKGROUP {
        return Ok(());
    }
    Err(GpuError::InvalidConfig(format!(
        "the packed face kernel needs a power of two up to {WORKGROUP} lanes a particle, got {lanes}"
    )))
}

/// The weighing kernel: the packed one with `lanes` a particle (its template staged in workgroup
/// memory up to [`STAGED_MAX_LANES`]), else a workgroup a particle.
/// Its workgroup memory is not zeroed first: every invocation writes its own sums before the
/// reduction reads any (`reduce_groups`).
fn weighing_kernel(ctx: &GpuContext, lanes: Option<u32>) -> Result<Kernel, GpuError> {
    let constants = lanes.map(|l| [("LANES", f64::from(l))]);
    let options = KernelOptions {
        constants: constants.as_ref().map_or(&[], |c| c.as_slice()),
        zero_workgroup_memory: false,
        checks: ShaderChecks::Trusted,
    };
    let entry = match lanes {
        Some(l) if l <= STAGED_MAX_LANES => "weigh_faces_packed_staged",
        Some(_) => "weigh_faces_packed",
        None => "weigh_faces",
    };
    let source = stage_source(super::SHADER);
    Kernel::with_options(ctx, "face likelihood", &source, entry, options)
}

/// Checks the lens and the weighing's settings (`FaceLikelihoodGpu::new`'s).
fn check_weighing(
    lens: &Lens,
    sharpness: f32,
    min_error: f32,
    min_visible_share: f32,
) -> Result<(), GpuError> {
    if !(lens.inverse_focal.is_finite()
        && lens.inverse_focal >= 0.0
        && lens.principal.iter().all(|c| c.is_finite()))
    {
        return Err(GpuError::InvalidConfig(format!(
            "the lens needs a finite, non-negative 1/f and a finite principal point, got {lens:?}"
        )));
    }
    if !(sharpness.is_finite() && sharpness >= 0.0 && min_error.is_finite() && min_error > 0.0) {
        return Err(GpuError::InvalidConfig(format!(
            "sharpness must be finite and >= 0 and the error floor finite and > 0, the visible share in [0, 1] (got {sharpness}, {min_error}, {min_visible_share})"
        )));
    }
    Ok(())
}

/// The uniform parameters of each dispatch: one per face for `PerFace` (each its face's
/// offset), else one for every face.
fn params_per_dispatch(
    ctx: &GpuContext,
    dispatch: FaceDispatch,
    faces: usize,
    every_face: FaceParams,
) -> Result<Vec<wgpu::Buffer>, GpuError> {
    let offsets: Vec<u32> = match dispatch {
        FaceDispatch::PerFace => (0..faces as u32).collect(),
        FaceDispatch::Batched | FaceDispatch::Packed { .. } | FaceDispatch::PackedByLoad => {
            vec![0]
        }
    };
    offsets
        .into_iter()
        .map(|face_offset| {
            let value = FaceParams {
                face_offset,
                ..every_face
            };
            pf_gpu::stream::uniform_buffer(ctx, "face likelihood params", &value)
        })
        .collect()
}

#[cfg(test)]
mod lanes_tests {
    use super::packed_lanes_for;

    #[test]
    fn the_lanes_follow_the_frames_particles() {
        // On the H100 (docs/BENCHMARKS.md): one face 64 (128 within 0.1 µs), 16 faces 16, 64
        // faces 4.
        assert_eq!(packed_lanes_for(1_000), 64);
        assert_eq!(packed_lanes_for(4_000), 64);
        assert_eq!(packed_lanes_for(16_000), 16);
        assert_eq!(packed_lanes_for(64_000), 4);
        // The ends: no particles, and more than the target invocations.
        assert_eq!(packed_lanes_for(0), 64);
        assert_eq!(packed_lanes_for(1 << 20), 4);
        for particles in [1, 7, 999, 12_345, 300_000] {
            let lanes = packed_lanes_for(particles);
            assert!(
                lanes.is_power_of_two() && (4..=64).contains(&lanes),
                "{particles}: {lanes}"
            );
        }
    }
}

#[cfg(test)]
mod layout_tests {
    use std::mem::{offset_of, size_of};

    use super::FaceParams;
    use pf_gpu::kernels::{assert_mirrors_wgsl, stage_source};

    #[test]
    fn face_params_mirror_their_wgsl_layout() {
        macro_rules! fields {
            ($t:ty: $($f:ident),*) => { [$((stringify!($f), offset_of!($t, $f))),*] };
        }
        assert_mirrors_wgsl(
            &stage_source(crate::likelihood::SHADER),
            "FaceParams",
            size_of::<FaceParams>(),
            &fields!(FaceParams: width, height, max_points, face_offset, sharpness, min_error,
                min_visible_share, inverse_focal, principal_x, principal_y, texel_x, texel_y),
        );
    }
}
