//! Synthetic stereo sequences with ground truth: a skeleton moving along a known path (walking,
//! arm waving, or both), seen by a depth camera at the origin. Each pixel's ray is cast against
//! the capsule skin, so the body hides its own far side and crossing limbs hide each other
//! (self-occlusion). The measured depth then gets what a stereo rig gives it: noise growing with
//! z² (the disparity error), dropped pixels, and a fraction of outliers anywhere along the ray.

use std::f32::consts::TAU;

use nalgebra::Vector3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::camera::{DepthImage, Intrinsics};
use crate::capsule::{Capsule, ray_capsule};
use crate::error::BodyError;
use crate::human::standing_pose;
use crate::skeleton::Skeleton;
use pf_core::random::{RandomStream, splitmix64};

/// The ground-truth movement.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Motion {
    /// Walking sideways across the view: legs and arms swing, the body sways and turns a little.
    Walk,
    /// Standing, the right arm raised and waving, the left arm and the head following.
    Wave,
    /// Walking while waving the right arm.
    WalkWave,
}

impl Motion {
    /// The name `FromStr` reads (the command line's spelling).
    pub fn name(self) -> &'static str {
        match self {
            Self::Walk => "walk",
            Self::Wave => "wave",
            Self::WalkWave => "walk-wave",
        }
    }
}

impl std::fmt::Display for Motion {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Motion {
    type Err = BodyError;
    fn from_str(s: &str) -> Result<Self, BodyError> {
        match s {
            "walk" => Ok(Self::Walk),
            "wave" => Ok(Self::Wave),
            "walk-wave" => Ok(Self::WalkWave),
            other => Err(BodyError::InvalidInput(format!(
                "unknown motion {other:?}; choose walk, wave or walk-wave"
            ))),
        }
    }
}

/// How a synthetic sequence is made.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SynthConfig {
    pub frames: usize,
    pub motion: Motion,
    /// Frames per second of the motion (the paths are defined in seconds).
    pub fps: f32,
    pub camera: Intrinsics,
    /// Distance of the body from the camera (m).
    pub distance: f32,
    /// Depth noise σ at 1 m (m); at depth z it is this × z².
    pub depth_noise: f32,
    /// Fraction of body pixels lost (0 ≤ dropout < 1).
    pub dropout: f32,
    /// Fraction of the kept points replaced by a depth drawn uniformly between 0.5 m and
    /// twice the true depth.
    pub outliers: f32,
    pub seed: u64,
}

impl SynthConfig {
    /// A short sequence for tests and the default run: 160×120 pixels, 60° wide, body at 3 m.
    pub fn small(frames: usize) -> Result<Self, BodyError> {
        Ok(Self {
            frames,
            motion: Motion::WalkWave,
            fps: 30.0,
            camera: Intrinsics::with_fov(160, 120, 60.0)?,
            distance: 3.0,
            depth_noise: 0.005,
            dropout: 0.1,
            outliers: 0.02,
            seed: 7,
        })
    }

    pub fn validate(&self) -> Result<(), BodyError> {
        self.camera.validate()?;
        let bad = |m: String| Err(BodyError::InvalidInput(m));
        if self.frames == 0 {
            return bad("a sequence needs at least one frame".into());
        }
        if !(self.fps.is_finite() && self.fps > 0.0) {
            return bad(format!("fps must be > 0, got {}", self.fps));
        }
        if !(self.distance.is_finite() && self.distance > 0.5) {
            return bad(format!(
                "the body must stand more than 0.5 m from the camera, got {}",
                self.distance
            ));
        }
        if !(self.depth_noise.is_finite() && self.depth_noise >= 0.0) {
            return bad(format!(
                "depth noise must be >= 0, got {}",
                self.depth_noise
            ));
        }
        if !(0.0..1.0).contains(&self.dropout) {
            return bad(format!("dropout must be in [0, 1), got {}", self.dropout));
        }
        if !(0.0..=1.0).contains(&self.outliers) {
            return bad(format!("outliers must be in [0, 1], got {}", self.outliers));
        }
        Ok(())
    }
}

/// Sets the angle `index` of bone `name`.
fn set(
    skeleton: &Skeleton,
    theta: &mut [f32],
    name: &str,
    index: usize,
    value: f32,
) -> Result<(), BodyError> {
    let range = skeleton.angles_of(name)?;
    if index >= range.len() {
        return Err(BodyError::InvalidSkeleton(format!(
            "the synthetic motion moves angle {index} of {name:?}, which has {}",
            range.len()
        )));
    }
    theta[range.start + index] = value;
    Ok(())
}

/// The ground-truth pose at `frame`. The paths name the default human's joints; another
/// skeleton needs the same joint names (else an error names the missing one).
pub fn pose_at(
    skeleton: &Skeleton,
    config: &SynthConfig,
    frame: usize,
) -> Result<Vec<f32>, BodyError> {
    let t = frame as f32 / config.fps;
    let mut theta = standing_pose(skeleton, config.distance);
    let walking = matches!(config.motion, Motion::Walk | Motion::WalkWave);
    let waving = matches!(config.motion, Motion::Wave | Motion::WalkWave);
    if walking {
        // One stride a second, walking along x at 0.4 m/s, facing the camera slightly turned.
        let phase = TAU * t;
        let swing = phase.sin();
        theta[0] = -0.4 + 0.4 * t;
        theta[1] = -0.05 + 0.02 * (2.0 * phase).cos();
        theta[4] = 0.25 * (0.5 * phase).sin();
        set(skeleton, &mut theta, "left_thigh", 0, -0.5 * swing)?;
        set(skeleton, &mut theta, "right_thigh", 0, 0.5 * swing)?;
        set(
            skeleton,
            &mut theta,
            "left_shin",
            0,
            0.6 * (-swing).max(0.0),
        )?;
        set(skeleton, &mut theta, "right_shin", 0, 0.6 * swing.max(0.0))?;
        set(skeleton, &mut theta, "left_upper_arm", 0, 0.4 * swing)?;
        set(skeleton, &mut theta, "left_forearm", 0, -0.3)?;
        if !waving {
            set(skeleton, &mut theta, "right_upper_arm", 0, -0.4 * swing)?;
            set(skeleton, &mut theta, "right_forearm", 0, -0.3)?;
        }
        set(skeleton, &mut theta, "spine", 1, 0.15 * swing)?;
    }
    if waving {
        // Raise the right arm over 1 s, then wave the forearm at 1.5 Hz.
        let raise = (t / 1.0).min(1.0);
        let wave = (TAU * 1.5 * t).sin();
        set(skeleton, &mut theta, "right_upper_arm", 2, -2.3 * raise)?;
        set(skeleton, &mut theta, "right_upper_arm", 0, -0.3 * raise)?;
        set(
            skeleton,
            &mut theta,
            "right_forearm",
            0,
            -(0.3 + 0.6 * raise * (1.0 + wave)),
        )?;
        set(skeleton, &mut theta, "head", 1, -0.3 * raise * wave)?;
        if !walking {
            set(skeleton, &mut theta, "left_upper_arm", 2, 0.4 * raise)?;
            set(skeleton, &mut theta, "chest", 1, 0.1 * wave)?;
        }
    }
    Ok(theta)
}

/// One rendered frame: the measured points and the same as a depth image.
#[derive(Debug, Clone)]
pub struct RenderedFrame {
    pub points: Vec<Vector3<f32>>,
    pub depth: DepthImage,
}

/// The nearest hit of the ray `dir` (from the origin) on any capsule.
fn first_hit(capsules: &[Capsule], dir: &Vector3<f32>) -> Option<f32> {
    let origin = Vector3::zeros();
    capsules
        .iter()
        .filter_map(|c| ray_capsule(&origin, dir, c))
        .min_by(|a, b| a.total_cmp(b))
}

/// Ray-casts the capsules of `theta` through every pixel and degrades the depth as the config
/// says. Deterministic for a given (seed, frame).
pub fn render(
    skeleton: &Skeleton,
    theta: &[f32],
    config: &SynthConfig,
    frame: usize,
) -> Result<RenderedFrame, BodyError> {
    let capsules = skeleton.capsules(theta)?;
    let camera = &config.camera;
    let rows: Vec<Vec<(u16, Option<Vector3<f32>>)>> = (0..camera.height)
        .into_par_iter()
        .map(|v| {
            let key = splitmix64(config.seed ^ splitmix64((frame as u64) << 32 | u64::from(v)));
            let mut rng = RandomStream::from_key(key);
            (0..camera.width)
                .map(|u| {
                    let ray = camera.pixel_ray(u as f32, v as f32);
                    let dir = ray.normalize();
                    let Some(range) = first_hit(&capsules, &dir) else {
                        return (0, None);
                    };
                    // Draw every number for every hit pixel so that changing one fraction does
                    // not reshuffle the others.
                    let (drop, outlier, noise, far) =
                        (rng.uniform(), rng.uniform(), rng.gaussian(), rng.uniform());
                    let z_true = range * dir.z;
                    if drop < f64::from(config.dropout) {
                        return (0, None);
                    }
                    let z = if outlier < f64::from(config.outliers) {
                        0.5 + (2.0 * z_true - 0.5).max(0.0) * far as f32
                    } else {
                        z_true + config.depth_noise * z_true * z_true * noise as f32
                    };
                    let raw = (z / camera.depth_scale).round();
                    if !(1.0..=f32::from(u16::MAX)).contains(&raw) {
                        return (0, None);
                    }
                    // The point is what the depth image holds, so both inputs agree.
                    let z = raw * camera.depth_scale;
                    (raw as u16, Some(ray * z))
                })
                .collect()
        })
        .collect();
    let mut depth = Vec::with_capacity((camera.width * camera.height) as usize);
    let mut points = Vec::new();
    for row in rows {
        for (raw, point) in row {
            depth.push(raw);
            points.extend(point);
        }
    }
    Ok(RenderedFrame {
        points,
        depth: DepthImage {
            width: camera.width,
            height: camera.height,
            depth,
        },
    })
}
