//! The whole body likelihood on the GPU: forward kinematics from pose samples
//! (`shaders/body/skeleton.wgsl`, [`super::SHADER`]), then the fast capsule likelihood
//! (`shaders/body/likelihood.wgsl`, [`crate::likelihood::gpu`]), then log-likelihoods (eq. 3). Inside the GPU filter the
//! poses are the filter's own state buffer, so a frame uploads only its rays; [`super::gpu_split::SplitBodyLikelihood`]
//! spreads the samples of a host-held filter over several GPUs.
//!
//! The skeleton arrives as plain [`GpuBone`]s ([`super::Skeleton::gpu_bones`] builds them); CPU
//! twins: [`super::Skeleton::capsules`] and [`crate::likelihood::listing_1_2`].

use bytemuck::{Pod, Zeroable};

use crate::likelihood::CoarseLayers;
use crate::likelihood::gpu::{
    CapsuleKernel, CapsuleLikelihoodGpu, END_MARKER, MAX_CAPSULES, PreparedRays, prepare_ray_levels,
};
use pf_gpu::GpuContext;
use pf_gpu::GpuError;
use pf_gpu::filter::{GpuLikelihood, LikelihoodInputs, LikelihoodPhase, ReadbackSource};
use pf_gpu::kernels::Kernel;
use pf_gpu::stream::{DeviceStream, Readback};
use pf_gpu::wgpu;

use super::SHADER;

/// Marks the root in [`GpuBone::parent`].
pub const NO_PARENT: u32 = u32::MAX;

/// One bone as the kinematics kernel reads it (`Bone` in the shader).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct GpuBone {
    /// Where the bone starts in its parent's frame.
    pub offset: [f32; 3],
    /// The capsule's radius (m).
    pub radius: f32,
    /// direction · length in the bone's own frame.
    pub extent: [f32; 3],
    /// The parent's index (smaller than this bone's), or [`NO_PARENT`] for bone 0.
    pub parent: u32,
    /// (number of joint axes ≤ 3, index in θ of the first angle, axes 2 bits each — 0 x, 1 y,
    /// 2 z —, 0).
    pub joint: [u32; 4],
}

#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct KinematicsParams {
    samples: u32,
    particles: u32,
    dims: u32,
    bones: u32,
    log_scale: f32,
    _pad: [u32; 3],
}

/// The likelihood's settings that do not change between frames.
#[derive(Debug, Clone, PartialEq)]
pub struct BodyLikelihoodConfig {
    /// The skeleton's bones in order, parents first (`Skeleton::gpu_bones`).
    pub bones: Vec<GpuBone>,
    /// Pose values per sample (the skeleton's degrees of freedom).
    pub dims: usize,
    /// Points per frame at most; a frame may have fewer.
    pub points: usize,
    /// The camera centre the rays start from.
    pub origin: [f32; 3],
    /// τ of eq. 6 and σ of eq. 3 (σ can change per frame: [`BodyLikelihoodGpu::set_sigma`]).
    pub tau: f32,
    /// σ of eq. 3 (m).
    pub sigma: f32,
    /// Coarse annealing layers weighing a subset of the points (a second level of the prepared
    /// rays); `None`: every layer weighs every point.
    pub coarse: Option<CoarseLayers>,
}

impl BodyLikelihoodConfig {
    fn validate(&self) -> Result<(), GpuError> {
        let bad = |m: String| Err(GpuError::InvalidConfig(m));
        if self.bones.is_empty() || self.bones.len() > MAX_CAPSULES {
            return bad(format!(
                "a skeleton of {} bones; the GPU kernels take 1 to {MAX_CAPSULES}",
                self.bones.len()
            ));
        }
        if !(self.sigma.is_finite() && self.sigma > 0.0) {
            return bad(format!("sigma must be finite and > 0, got {}", self.sigma));
        }
        if let Some(coarse) = &self.coarse
            && coarse.points == 0
        {
            return bad("coarse annealing layers need at least one point".into());
        }
        if self.dims < 6 {
            return bad(format!(
                "a pose needs the 6 root values, got {} dims",
                self.dims
            ));
        }
        for (k, bone) in self.bones.iter().enumerate() {
            let parent_ok = if k == 0 {
                bone.parent == NO_PARENT
            } else {
                (bone.parent as usize) < k
            };
            let [count, first, axes, _] = bone.joint;
            let angles_ok = count <= 3
                && (first as usize) + (count as usize) <= self.dims
                && (0..count).all(|i| (axes >> (2 * i)) & 3 < 3);
            if !parent_ok || !angles_ok {
                return bad(format!(
                    "bone {k} is inconsistent (parent {}, joint {:?}, {} dims)",
                    bone.parent, bone.joint, self.dims
                ));
            }
        }
        Ok(())
    }

    /// The most points of each level of the prepared rays: every point, then the coarse
    /// layers' subset.
    fn level_points(&self) -> Vec<usize> {
        let mut levels = vec![self.points];
        if let Some(coarse) = &self.coarse {
            levels.push(coarse.capacity(self.points));
        }
        levels
    }
}

/// A uniform buffer holding `value`.
fn kinematics_params(
    ctx: &GpuContext,
    label: &str,
    value: &KinematicsParams,
) -> Result<wgpu::Buffer, GpuError> {
    pf_gpu::stream::uniform_buffer(ctx, label, value)
}

/// A frame's rays, `[dir, depth]` per point (at most `points` of them), as a
/// [`BodyLikelihoodGpu`] configured for `points` (and `coarse`) uploads them: level 0 every
/// ray, padded to `points` with end markers (depth −1, which add nothing to any sum), then the
/// coarse layers' subset padded to its capacity; each in Morton order with its tile cones. Pure
/// host work, so that it can run beside the GPU's work on the previous frame.
pub fn prepare_body_rays(
    rays: &[[f32; 4]],
    points: usize,
    coarse: Option<&CoarseLayers>,
) -> Result<PreparedRays, GpuError> {
    if rays.len() > points {
        return Err(GpuError::LengthMismatch {
            what: "frame points (at most)".into(),
            expected: points,
            got: rays.len(),
        });
    }
    if let Some(i) = rays.iter().position(|r| r[3].is_nan() || r[3] < 0.0) {
        return Err(GpuError::InvalidConfig(format!(
            "ray {i} has depth {}; depths must be >= 0",
            rays[i][3]
        )));
    }
    let padded = |mut level: Vec<[f32; 4]>, capacity: usize| {
        level.resize(capacity, END_MARKER);
        level
    };
    let mut levels = vec![padded(rays.to_vec(), points)];
    if let Some(coarse) = coarse {
        levels.push(padded(coarse.subset(rays), coarse.capacity(points)));
    }
    let levels: Vec<&[[f32; 4]]> = levels.iter().map(Vec::as_slice).collect();
    Ok(prepare_ray_levels(&levels))
}

/// Forward kinematics plus the fast capsule likelihood for `samples` pose samples on one GPU.
pub struct BodyLikelihoodGpu {
    config: BodyLikelihoodConfig,
    samples: usize,
    capsules: CapsuleLikelihoodGpu,
    params: wgpu::Buffer,
    params_value: KinematicsParams,
    /// Per level of points past the first, the parameters its log-likelihoods read (σ scaled
    /// to the level's points); level 0 reads `params`.
    level_params: Vec<(wgpu::Buffer, KinematicsParams)>,
    bones: DeviceStream<GpuBone>,
    frames: DeviceStream<[f32; 4]>,
    kinematics: Kernel,
    to_log_likelihood: Kernel,
    /// Poses uploaded from the host ([`Self::submit_poses`]); unused inside the GPU filter.
    host_poses: DeviceStream<f32>,
    host_group: wgpu::BindGroup,
    /// Bound by [`GpuLikelihood::prepare`] to the filter's states and log-likelihoods: the
    /// kinematics, and per level of points the log-likelihoods from its sums.
    filter_groups: Option<(wgpu::BindGroup, Vec<wgpu::BindGroup>)>,
    /// M of the filter's estimate, in the step's submission (bound by `prepare`).
    estimate_fit: Option<EstimateFit>,
    sums_back: Readback<f32>,
}

/// The tracker's check of its estimate on the GPU: forward kinematics of the step's estimate
/// (one pose) and the capsule likelihood's sum M over the frame's rays, read back with the step
/// ([`BodyLikelihoodGpu::ESTIMATE_SUM`]), so that the host does not weigh it.
struct EstimateFit {
    /// A one-sample likelihood over the same rays (uploaded with the frame's).
    capsules: CapsuleLikelihoodGpu,
    _params: wgpu::Buffer,
    _frames: DeviceStream<[f32; 4]>,
    kinematics: wgpu::BindGroup,
}

impl BodyLikelihoodGpu {
    /// The readback section holding M of the step's estimate (one f32), once prepared for a
    /// filter.
    pub const ESTIMATE_SUM: &'static str = "body estimate sum";

    /// Builds the kinematics and likelihood kernels and every buffer for `config`.
    pub fn new(
        ctx: &GpuContext,
        config: BodyLikelihoodConfig,
        samples: usize,
    ) -> Result<Self, GpuError> {
        config.validate()?;
        let bones_count = config.bones.len();
        let capsules = CapsuleLikelihoodGpu::with_levels(
            ctx,
            CapsuleKernel::Fast,
            samples,
            &config.level_points(),
            bones_count,
            config.origin,
            config.tau,
        )?;
        let frames_len = samples
            .checked_mul(bones_count * 4)
            .filter(|&n| n <= u32::MAX as usize)
            .ok_or_else(|| {
                GpuError::InvalidConfig(format!(
                    "{samples} samples x {bones_count} bones overflow 32-bit indices"
                ))
            })?;
        let params_value = KinematicsParams {
            samples: samples as u32,
            particles: samples as u32,
            dims: config.dims as u32,
            bones: bones_count as u32,
            log_scale: -1.0 / (2.0 * config.sigma * config.sigma),
            _pad: [0; 3],
        };
        let params = kinematics_params(ctx, "kinematics params", &params_value)?;
        let level_params = (1..capsules.levels())
            .map(|_| {
                Ok((
                    kinematics_params(ctx, "coarse level params", &params_value)?,
                    params_value,
                ))
            })
            .collect::<Result<Vec<_>, GpuError>>()?;
        let bones = DeviceStream::from_slice(ctx, "bones", &config.bones)?;
        let frames = DeviceStream::zeroed(ctx, "bone frames", frames_len)?;
        let kinematics = Kernel::trusted(ctx, "forward kinematics", SHADER, "forward_kinematics")?;
        let to_log_likelihood = Kernel::trusted(
            ctx,
            "log-likelihood from sums",
            SHADER,
            "log_likelihood_from_sums",
        )?;
        let host_poses = DeviceStream::zeroed(ctx, "pose samples", samples * config.dims)?;
        let host_group = kinematics.bind(
            ctx,
            &[
                (0, params.as_entire_binding()),
                (1, bones.binding()),
                (2, host_poses.binding()),
                (3, frames.binding()),
                (4, capsules.capsule_stream().binding()),
            ],
        )?;
        Ok(Self {
            config,
            samples,
            sums_back: Readback::new(ctx, "body likelihood sums", samples)?,
            capsules,
            params,
            params_value,
            level_params,
            bones,
            frames,
            kinematics,
            to_log_likelihood,
            host_poses,
            host_group,
            filter_groups: None,
            estimate_fit: None,
        })
    }

    /// Samples evaluated per frame (targets × particles).
    pub fn samples(&self) -> usize {
        self.samples
    }

    /// This frame's rays, `[dir, depth]` per point: at most the configured number. The rest of
    /// the buffer is filled with the fast kernel's end marker (depth −1), which adds nothing to
    /// any sum. The same as [`prepare_body_rays`] then [`Self::upload_prepared_rays`].
    pub fn upload_rays(&mut self, ctx: &GpuContext, rays: &[[f32; 4]]) -> Result<(), GpuError> {
        let prepared = prepare_body_rays(rays, self.config.points, self.config.coarse.as_ref())?;
        self.upload_prepared_rays(ctx, &prepared)
    }

    /// A frame's rays already prepared by [`prepare_body_rays`] for this likelihood's number of
    /// points and coarse layers (on any thread, for example while the GPU works on the previous
    /// frame): the upload alone. Rays prepared for another configuration are refused.
    pub fn upload_prepared_rays(
        &mut self,
        ctx: &GpuContext,
        prepared: &PreparedRays,
    ) -> Result<(), GpuError> {
        self.capsules.upload_prepared_rays(ctx, prepared)?;
        if let Some(fit) = &self.estimate_fit {
            fit.capsules.upload_prepared_rays(ctx, prepared)?;
        }
        Ok(())
    }

    /// σ of eq. 3 from the next evaluation on (every level's).
    pub fn set_sigma(&mut self, ctx: &GpuContext, sigma: f32) -> Result<(), GpuError> {
        self.set_level_sigmas(ctx, &vec![sigma; self.capsules.levels()])
    }

    /// σ of eq. 3 per level of points from the next evaluation on: level 0's for every point,
    /// then the coarse subset's (σ scaled to each level's points).
    pub fn set_level_sigmas(&mut self, ctx: &GpuContext, sigmas: &[f32]) -> Result<(), GpuError> {
        if sigmas.len() != self.capsules.levels() {
            return Err(GpuError::LengthMismatch {
                what: "sigma per level of points".into(),
                expected: self.capsules.levels(),
                got: sigmas.len(),
            });
        }
        if let Some(sigma) = sigmas.iter().find(|s| !(s.is_finite() && **s > 0.0)) {
            return Err(GpuError::InvalidConfig(format!(
                "sigma must be finite and > 0, got {sigma}"
            )));
        }
        let log_scale = |sigma: f32| -1.0 / (2.0 * sigma * sigma);
        self.config.sigma = sigmas[0];
        self.params_value.log_scale = log_scale(sigmas[0]);
        ctx.queue
            .write_buffer(&self.params, 0, bytemuck::bytes_of(&self.params_value));
        for ((buffer, value), &sigma) in self.level_params.iter_mut().zip(&sigmas[1..]) {
            value.log_scale = log_scale(sigma);
            ctx.queue.write_buffer(buffer, 0, bytemuck::bytes_of(value));
        }
        Ok(())
    }

    fn kinematics_groups(&self) -> [u32; 3] {
        [self.samples.div_ceil(64) as u32, 1, 1]
    }

    /// Uploads poses (`[d·J + j]`, J = samples) and submits kinematics and likelihood; read the
    /// sums with [`Self::read_sums`]. Two steps so that several GPUs can work at once. Not for a
    /// likelihood prepared for a filter (whose layout it then follows).
    pub fn submit_poses(
        &self,
        ctx: &GpuContext,
        poses: &[f32],
    ) -> Result<wgpu::SubmissionIndex, GpuError> {
        if self.filter_groups.is_some() {
            return Err(GpuError::InvalidConfig(
                "this body likelihood is bound to a filter's states; build another for host poses"
                    .into(),
            ));
        }
        self.host_poses.upload(ctx, poses)?;
        let mut encoder = ctx.device.create_command_encoder(&Default::default());
        ctx.scoped("evaluating the body likelihood", || {
            {
                let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("body likelihood"),
                    timestamp_writes: None,
                });
                self.kinematics
                    .record(&mut pass, &self.host_group, self.kinematics_groups());
                self.capsules.record_in(&mut pass);
            }
            self.sums_back
                .record_copy(&mut encoder, self.capsules.sum_stream());
            ctx.queue.submit([encoder.finish()])
        })
    }

    /// M_j of the submitted poses.
    pub fn read_sums(
        &self,
        ctx: &GpuContext,
        submission: wgpu::SubmissionIndex,
    ) -> Result<Vec<f64>, GpuError> {
        Ok(self
            .sums_back
            .read(ctx, Some(submission))?
            .into_iter()
            .map(f64::from)
            .collect())
    }

    /// The capsules of every uploaded pose (`[(j·K + k)·2]`, as `capsules_gpu_layout`), for
    /// checking the kinematics against the CPU.
    pub fn pose_capsules(
        &self,
        ctx: &GpuContext,
        poses: &[f32],
    ) -> Result<Vec<[f32; 4]>, GpuError> {
        let submission = self.submit_poses(ctx, poses)?;
        ctx.wait(Some(submission), "forward kinematics")?;
        self.capsules.capsule_stream().download(ctx)
    }
}

impl GpuLikelihood for BodyLikelihoodGpu {
    fn prepare(&mut self, ctx: &GpuContext, inputs: &LikelihoodInputs<'_>) -> Result<(), GpuError> {
        let shape = inputs.shape;
        if shape.particle_len() != self.samples || shape.dims != self.config.dims {
            return Err(GpuError::InvalidConfig(format!(
                "the body likelihood was built for {} samples of {} values; the filter has {} x {} of {}",
                self.samples, self.config.dims, shape.targets, shape.particles, shape.dims
            )));
        }
        // The filter's layout has a stride of M particles per target.
        self.params_value.particles = shape.particles as u32;
        ctx.queue
            .write_buffer(&self.params, 0, bytemuck::bytes_of(&self.params_value));
        for (buffer, value) in &mut self.level_params {
            value.particles = shape.particles as u32;
            ctx.queue.write_buffer(buffer, 0, bytemuck::bytes_of(value));
        }
        let kinematics = self.kinematics.bind(
            ctx,
            &[
                (0, self.params.as_entire_binding()),
                (1, self.bones.binding()),
                (2, inputs.states.binding()),
                (3, self.frames.binding()),
                (4, self.capsules.capsule_stream().binding()),
            ],
        )?;
        let to_log_likelihood = std::iter::once(&self.params)
            .chain(self.level_params.iter().map(|(buffer, _)| buffer))
            .map(|params| {
                self.to_log_likelihood.bind(
                    ctx,
                    &[
                        (0, params.as_entire_binding()),
                        (5, self.capsules.sum_stream().binding()),
                        (6, inputs.log_likelihood.binding()),
                    ],
                )
            })
            .collect::<Result<Vec<_>, _>>()?;
        self.filter_groups = Some((kinematics, to_log_likelihood));
        self.estimate_fit = Some(self.estimate_fit(ctx, inputs)?);
        Ok(())
    }

    fn is_prepared(&self) -> bool {
        self.filter_groups.is_some()
    }

    fn record(&self, phase: LikelihoodPhase, pass: &mut wgpu::ComputePass<'_>) {
        if phase == LikelihoodPhase::AfterEstimate
            && let Some(fit) = &self.estimate_fit
        {
            self.kinematics.record(pass, &fit.kinematics, [1, 1, 1]);
            fit.capsules.record_in(pass);
        }
        let LikelihoodPhase::Measure { layer } = phase else {
            return;
        };
        if let Some((kinematics, to_log_likelihood)) = &self.filter_groups {
            let level = match &self.config.coarse {
                Some(coarse) if coarse.is_coarse(layer) => 1,
                _ => 0,
            };
            let groups = self.kinematics_groups();
            self.kinematics.record(pass, kinematics, groups);
            self.capsules.record_level_in(level, pass);
            self.to_log_likelihood
                .record(pass, &to_log_likelihood[level], groups);
        }
    }

    fn readbacks(&self) -> Vec<ReadbackSource<'_>> {
        self.estimate_fit
            .iter()
            .map(|fit| ReadbackSource::of(Self::ESTIMATE_SUM, fit.capsules.sum_stream()))
            .collect()
    }
}

impl BodyLikelihoodGpu {
    /// The one-pose likelihood over the filter's estimate (target 0's, `[d]` of the estimates:
    /// the kinematics read it as one sample of one particle).
    fn estimate_fit(
        &self,
        ctx: &GpuContext,
        inputs: &LikelihoodInputs<'_>,
    ) -> Result<EstimateFit, GpuError> {
        let bones = self.config.bones.len();
        // The same levels as the filter's likelihood, so that one upload of prepared rays
        // fits both; the check weighs level 0, every point.
        let capsules = CapsuleLikelihoodGpu::with_levels(
            ctx,
            CapsuleKernel::Fast,
            1,
            &self.config.level_points(),
            bones,
            self.config.origin,
            self.config.tau,
        )?;
        let params_value = KinematicsParams {
            samples: 1,
            particles: 1,
            ..self.params_value
        };
        let params = kinematics_params(ctx, "estimate kinematics params", &params_value)?;
        let frames = DeviceStream::zeroed(ctx, "estimate bone frames", bones * 4)?;
        let kinematics = self.kinematics.bind(
            ctx,
            &[
                (0, params.as_entire_binding()),
                (1, self.bones.binding()),
                (2, inputs.estimates.binding()),
                (3, frames.binding()),
                (4, capsules.capsule_stream().binding()),
            ],
        )?;
        Ok(EstimateFit {
            capsules,
            _params: params,
            _frames: frames,
            kinematics,
        })
    }
}

#[cfg(test)]
mod layout_tests {
    use std::mem::{offset_of, size_of};

    use super::{GpuBone, KinematicsParams, SHADER};
    use pf_gpu::kernels::assert_mirrors_wgsl;

    #[test]
    fn kinematics_params_and_bones_mirror_their_wgsl_layouts() {
        macro_rules! fields {
            ($t:ty: $($f:ident),*) => { [$((stringify!($f), offset_of!($t, $f))),*] };
        }
        assert_mirrors_wgsl(
            SHADER,
            "KinematicsParams",
            size_of::<KinematicsParams>(),
            &fields!(KinematicsParams: samples, particles, dims, bones, log_scale),
        );
        assert_mirrors_wgsl(
            SHADER,
            "Bone",
            size_of::<GpuBone>(),
            &fields!(GpuBone: offset, radius, extent, parent, joint),
        );
    }
}
