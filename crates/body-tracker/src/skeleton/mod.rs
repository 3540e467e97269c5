//! Kinematic skeletons: a tree of rigid bones with 0–3 joint angles each, forward kinematics to
//! capsules, and a readable JSON form.
//!
//! Conventions. Every bone has a frame (origin o, rotation R). The root's frame is the root pose:
//! o = (θ0, θ1, θ2), R = Rz(θ5)·Ry(θ4)·Rx(θ3). A child's origin is o_parent + R_parent·offset and
//! its rotation R_parent·R_joint, where R_joint is the product of rotations about its joint axes
//! (in the listed order) by its joint angles. The bone's capsule runs from o to
//! o + R·(length·direction) with the bone's radius. The pose vector θ is the 6 root values
//! followed by every bone's joint angles in bone order.

use std::path::Path;

use nalgebra::{Rotation3, Vector3};
use serde::{Deserialize, Serialize};

use crate::capsule::Capsule;
use crate::error::BodyError;

pub mod gpu;
pub mod gpu_split;

/// The WGSL of the forward kinematics and the body's log-likelihood, launched by
/// [`gpu::BodyLikelihoodGpu`]; [`Skeleton::capsules`] is the kinematics' CPU twin.
pub const SHADER: &str = include_str!("../../../../shaders/body/skeleton.wgsl");

/// A rotation axis of a joint.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Axis {
    X,
    Y,
    Z,
}

impl Axis {
    fn unit(self) -> Vector3<f32> {
        match self {
            Axis::X => Vector3::x(),
            Axis::Y => Vector3::y(),
            Axis::Z => Vector3::z(),
        }
    }
}

/// One joint angle: its axis and limits (radians).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct JointAxis {
    pub axis: Axis,
    pub min: f32,
    pub max: f32,
}

/// One bone as written in a skeleton file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Bone {
    pub name: String,
    /// The parent's name; exactly one bone (the root) has none.
    #[serde(default)]
    pub parent: Option<String>,
    /// Where the bone starts, in the parent's frame, from the parent's origin (ignored for the root).
    #[serde(default)]
    pub offset: [f32; 3],
    /// The bone's direction in its own frame (normalised on load).
    pub direction: [f32; 3],
    pub length: f32,
    pub radius: f32,
    /// 0 to 3 joint angles.
    #[serde(default)]
    pub joint: Vec<JointAxis>,
}

/// A skeleton file: the bones, parents before children.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SkeletonSpec {
    pub bones: Vec<Bone>,
}

/// A validated skeleton, ready for forward kinematics.
#[derive(Debug, Clone, PartialEq)]
pub struct Skeleton {
    bones: Vec<Bone>,
    parents: Vec<Option<usize>>,
    directions: Vec<Vector3<f32>>,
    /// Index in θ of each bone's first joint angle.
    first_angle: Vec<usize>,
    dofs: usize,
}

/// A bone's frame: origin and rotation.
type Frame = (Vector3<f32>, Rotation3<f32>);

/// The number of root pose values at the start of θ (translation, then Rx, Ry, Rz).
pub const ROOT_DOFS: usize = 6;

/// Checks one bone's own values (finite non-negative length, positive radius, finite non-zero
/// direction, finite offset, 0–3 joint axes with min ≤ max); its unit direction.
fn checked_direction(bone: &Bone) -> Result<Vector3<f32>, BodyError> {
    let bad = |m: String| Err(BodyError::InvalidSkeleton(m));
    if !(bone.length.is_finite() && bone.length >= 0.0) {
        return bad(format!("bone {:?} has length {}", bone.name, bone.length));
    }
    if !(bone.radius.is_finite() && bone.radius > 0.0) {
        return bad(format!("bone {:?} has radius {}", bone.name, bone.radius));
    }
    let dir = Vector3::from(bone.direction);
    let norm = dir.norm();
    if !(norm.is_finite() && norm > 0.0) {
        let [x, y, z] = bone.direction;
        return bad(format!(
            "bone {:?} has direction ({x}, {y}, {z}): it must be finite and not zero",
            bone.name
        ));
    }
    if !bone.offset.iter().all(|x| x.is_finite()) {
        return bad(format!("bone {:?} has offset {:?}", bone.name, bone.offset));
    }
    if bone.joint.len() > 3 {
        return bad(format!(
            "bone {:?} has {} joint axes; at most 3",
            bone.name,
            bone.joint.len()
        ));
    }
    for j in &bone.joint {
        if !(j.min.is_finite() && j.max.is_finite() && j.min <= j.max) {
            return bad(format!(
                "bone {:?} has joint limits [{}, {}]",
                bone.name, j.min, j.max
            ));
        }
    }
    Ok(dir / norm)
}

impl Skeleton {
    /// Checks the bones: unique names, parents listed before children, one root, 0–3 joint axes
    /// with min ≤ max, finite non-negative lengths and positive radii, non-zero directions.
    pub fn new(spec: SkeletonSpec) -> Result<Self, BodyError> {
        let bad = |m: String| Err(BodyError::InvalidSkeleton(m));
        if spec.bones.is_empty() {
            return bad("a skeleton needs at least one bone".into());
        }
        let mut parents = Vec::with_capacity(spec.bones.len());
        let mut directions = Vec::with_capacity(spec.bones.len());
        let mut first_angle = Vec::with_capacity(spec.bones.len());
        let mut dofs = ROOT_DOFS;
        for (i, bone) in spec.bones.iter().enumerate() {
            if spec.bones[..i].iter().any(|b| b.name == bone.name) {
                return bad(format!("bone name {:?} is used twice", bone.name));
            }
            let parent = match &bone.parent {
                None if i == 0 => None,
                None => {
                    return bad(format!(
                        "bone {:?} has no parent, but only the first bone may be the root",
                        bone.name
                    ));
                }
                Some(p) => match spec.bones[..i].iter().position(|b| &b.name == p) {
                    Some(j) => Some(j),
                    None => {
                        return bad(format!(
                            "bone {:?} names parent {p:?}, which is not among the bones listed before it",
                            bone.name
                        ));
                    }
                },
            };
            if i == 0 && bone.parent.is_some() {
                return bad(format!(
                    "the first bone {:?} must be the root (no parent)",
                    bone.name
                ));
            }
            let dir = checked_direction(bone)?;
            parents.push(parent);
            directions.push(dir);
            first_angle.push(dofs);
            dofs += bone.joint.len();
        }
        Ok(Self {
            bones: spec.bones,
            parents,
            directions,
            first_angle,
            dofs,
        })
    }

    /// Reads a skeleton from a JSON file.
    pub fn load(path: &Path) -> Result<Self, BodyError> {
        let err = |message: String| BodyError::SkeletonFile {
            path: path.display().to_string(),
            message,
        };
        let text = std::fs::read_to_string(path).map_err(|e| err(e.to_string()))?;
        let spec: SkeletonSpec = serde_json::from_str(&text).map_err(|e| err(e.to_string()))?;
        Self::new(spec)
    }

    /// Writes the skeleton as pretty JSON.
    pub fn save(&self, path: &Path) -> Result<(), BodyError> {
        let err = |message: String| BodyError::SkeletonFile {
            path: path.display().to_string(),
            message,
        };
        let text = serde_json::to_string_pretty(&self.spec()).map_err(|e| err(e.to_string()))?;
        std::fs::write(path, text).map_err(|e| err(e.to_string()))
    }

    pub fn spec(&self) -> SkeletonSpec {
        SkeletonSpec {
            bones: self.bones.clone(),
        }
    }

    pub fn bones(&self) -> &[Bone] {
        &self.bones
    }

    /// The length of θ.
    pub fn dofs(&self) -> usize {
        self.dofs
    }

    /// One capsule per bone.
    pub fn capsule_count(&self) -> usize {
        self.bones.len()
    }

    /// The index of the bone called `name`.
    pub fn bone_index(&self, name: &str) -> Result<usize, BodyError> {
        self.bones
            .iter()
            .position(|b| b.name == name)
            .ok_or_else(|| BodyError::UnknownJoint {
                name: name.to_string(),
                known: self
                    .bones
                    .iter()
                    .map(|b| b.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", "),
            })
    }

    /// A name for every value of θ: `root_tx … root_rz`, then `{bone}_{axis}` (the CSV header).
    pub fn pose_names(&self) -> Vec<String> {
        let mut names: Vec<String> = ["tx", "ty", "tz", "rx", "ry", "rz"]
            .iter()
            .map(|n| format!("root_{n}"))
            .collect();
        for bone in &self.bones {
            for j in &bone.joint {
                let axis = match j.axis {
                    Axis::X => "x",
                    Axis::Y => "y",
                    Axis::Z => "z",
                };
                names.push(format!("{}_{axis}", bone.name));
            }
        }
        names
    }

    /// The range of θ holding the joint angles of bone `name`.
    pub fn angles_of(&self, name: &str) -> Result<std::ops::Range<usize>, BodyError> {
        let i = self.bone_index(name)?;
        Ok(self.first_angle[i]..self.first_angle[i] + self.bones[i].joint.len())
    }

    /// Partitioned sampling's two parts of θ: the trunk (the root's six values and the angles of
    /// every bone above a branch of the tree, whose subtree ends in more than one leaf) and the
    /// limbs (every other bone's angles). For the default human the trunk is the pelvis, the
    /// spine and the chest; the limbs are the neck and head, the arms and the legs.
    pub fn trunk_and_limbs(&self) -> (Vec<usize>, Vec<usize>) {
        let n = self.bones.len();
        let mut has_child = vec![false; n];
        for &p in self.parents.iter().flatten() {
            has_child[p] = true;
        }
        // Parents come before children, so one backward pass counts each subtree's leaves.
        let mut leaves = vec![0usize; n];
        for i in (0..n).rev() {
            if !has_child[i] {
                leaves[i] += 1;
            }
            if let Some(p) = self.parents[i] {
                leaves[p] += leaves[i];
            }
        }
        let mut trunk: Vec<usize> = (0..ROOT_DOFS).collect();
        let mut limbs = Vec::new();
        for (i, bone) in self.bones.iter().enumerate() {
            let angles = self.first_angle[i]..self.first_angle[i] + bone.joint.len();
            if leaves[i] > 1 {
                trunk.extend(angles);
            } else {
                limbs.extend(angles);
            }
        }
        (trunk, limbs)
    }

    /// Lower and upper limits of θ (root translation and rotation unbounded).
    pub fn limits(&self) -> (Vec<f32>, Vec<f32>) {
        let mut lo = vec![f32::NEG_INFINITY; self.dofs];
        let mut hi = vec![f32::INFINITY; self.dofs];
        for (i, bone) in self.bones.iter().enumerate() {
            for (k, j) in bone.joint.iter().enumerate() {
                lo[self.first_angle[i] + k] = j.min;
                hi[self.first_angle[i] + k] = j.max;
            }
        }
        (lo, hi)
    }

    /// The pose of every bone frame (origin, rotation) for θ.
    fn frames(&self, theta: &[f32]) -> Result<Vec<Frame>, BodyError> {
        if theta.len() != self.dofs {
            return Err(BodyError::InvalidPose(format!(
                "the pose has {} values; this skeleton needs {}",
                theta.len(),
                self.dofs
            )));
        }
        if let Some(i) = theta.iter().position(|x| !x.is_finite()) {
            return Err(BodyError::InvalidPose(format!(
                "pose value {i} is {}",
                theta[i]
            )));
        }
        let mut frames: Vec<Frame> = Vec::with_capacity(self.bones.len());
        for (i, bone) in self.bones.iter().enumerate() {
            let mut joint = Rotation3::identity();
            for (k, j) in bone.joint.iter().enumerate() {
                joint *= Rotation3::from_axis_angle(
                    &nalgebra::Unit::new_unchecked(j.axis.unit()),
                    theta[self.first_angle[i] + k],
                );
            }
            let frame = match self.parents[i] {
                None => {
                    let root = Rotation3::from_euler_angles(theta[3], theta[4], theta[5]);
                    (Vector3::new(theta[0], theta[1], theta[2]), root * joint)
                }
                Some(p) => {
                    let (origin, rotation) = frames[p];
                    (
                        origin + rotation * Vector3::from(bone.offset),
                        rotation * joint,
                    )
                }
            };
            frames.push(frame);
        }
        Ok(frames)
    }

    /// Forward kinematics: the capsule of every bone for pose θ, into `out`.
    pub fn capsules_into(&self, theta: &[f32], out: &mut Vec<Capsule>) -> Result<(), BodyError> {
        let frames = self.frames(theta)?;
        out.clear();
        out.extend(self.bones.iter().zip(&frames).zip(&self.directions).map(
            |((bone, (o, r)), dir)| Capsule {
                a: *o,
                b: o + r * (dir * bone.length),
                radius: bone.radius,
            },
        ));
        Ok(())
    }

    pub fn capsules(&self, theta: &[f32]) -> Result<Vec<Capsule>, BodyError> {
        let mut out = Vec::with_capacity(self.bones.len());
        self.capsules_into(theta, &mut out)?;
        Ok(out)
    }

    /// The bones in the layout of the kinematics kernel (`shaders/body/skeleton.wgsl`).
    pub fn gpu_bones(&self) -> Vec<gpu::GpuBone> {
        self.bones
            .iter()
            .enumerate()
            .map(|(i, bone)| {
                let extent = self.directions[i] * bone.length;
                let axes = bone.joint.iter().enumerate().fold(0u32, |packed, (k, j)| {
                    let code = match j.axis {
                        Axis::X => 0,
                        Axis::Y => 1,
                        Axis::Z => 2,
                    };
                    packed | (code << (2 * k))
                });
                gpu::GpuBone {
                    offset: bone.offset,
                    radius: bone.radius,
                    extent: [extent.x, extent.y, extent.z],
                    parent: self.parents[i].map_or(gpu::NO_PARENT, |p| p as u32),
                    joint: [bone.joint.len() as u32, self.first_angle[i] as u32, axes, 0],
                }
            })
            .collect()
    }

    /// The bones whose start is a tracked joint: the root and every bone with a joint angle.
    /// Collinear segments added to reach a capsule count have none, so the set (and the joint
    /// error) does not depend on the number of capsules.
    pub fn joint_bones(&self) -> Vec<usize> {
        (0..self.bones.len())
            .filter(|&i| self.parents[i].is_none() || !self.bones[i].joint.is_empty())
            .collect()
    }

    /// The positions of the tracked joints ([`Self::joint_bones`]) for θ.
    pub fn tracked_joint_positions(&self, theta: &[f32]) -> Result<Vec<Vector3<f32>>, BodyError> {
        let all = self.joint_positions(theta)?;
        Ok(self.joint_bones().into_iter().map(|i| all[i]).collect())
    }

    /// The start point of every bone (the joint positions) for θ.
    pub fn joint_positions(&self, theta: &[f32]) -> Result<Vec<Vector3<f32>>, BodyError> {
        Ok(self.frames(theta)?.into_iter().map(|(o, _)| o).collect())
    }
}
