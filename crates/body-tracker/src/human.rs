//! The default human skeleton: 19 bones (pelvis, two spine segments, neck, head, and per side
//! clavicle, upper arm, forearm, hand, thigh, shin, foot), in metres, y up, facing −z (towards a
//! camera at the origin looking along +z). Longer bones are split into collinear segments, with
//! no joint between them, until the requested number of capsules is reached — the paper used
//! 40–48 capsules for the same body.

use std::f32::consts::PI;

use crate::error::BodyError;
use crate::skeleton::{Axis, Bone, JointAxis, Skeleton, SkeletonSpec};

/// The fewest capsules of the default body (one per bone).
pub const BASE_CAPSULES: usize = 19;
/// The most capsules [`human_skeleton`] builds.
pub const MAX_CAPSULES: usize = 96;

fn axis(axis: Axis, min: f32, max: f32) -> JointAxis {
    JointAxis { axis, min, max }
}

fn bone(
    name: &str,
    parent: Option<&str>,
    offset: [f32; 3],
    direction: [f32; 3],
    length: f32,
    radius: f32,
    joint: Vec<JointAxis>,
) -> Bone {
    Bone {
        name: name.to_string(),
        parent: parent.map(str::to_string),
        offset,
        direction,
        length,
        radius,
        joint,
    }
}

/// Raising an arm sideways turns it about z: positive for the left arm (+x), negative for the right.
fn abduction(side: f32) -> JointAxis {
    if side > 0.0 {
        axis(Axis::Z, -0.3, 2.6)
    } else {
        axis(Axis::Z, -2.6, 0.3)
    }
}

/// The body before any bone is split: the trunk, then each side's arm and leg.
fn base_bones() -> Vec<Bone> {
    let mut bones = trunk_bones();
    for (side, s) in [("left", 1.0f32), ("right", -1.0f32)] {
        bones.extend(limb_bones(side, s));
    }
    bones
}

/// Pelvis (the root), spine, chest, neck and head.
fn trunk_bones() -> Vec<Bone> {
    use Axis::{X, Y, Z};
    vec![
        bone(
            "pelvis",
            None,
            [0.0; 3],
            [0.0, 1.0, 0.0],
            0.10,
            0.14,
            vec![],
        ),
        bone(
            "spine",
            Some("pelvis"),
            [0.0, 0.10, 0.0],
            [0.0, 1.0, 0.0],
            0.22,
            0.13,
            vec![axis(X, -0.5, 0.8), axis(Y, -0.6, 0.6), axis(Z, -0.4, 0.4)],
        ),
        bone(
            "chest",
            Some("spine"),
            [0.0, 0.22, 0.0],
            [0.0, 1.0, 0.0],
            0.22,
            0.15,
            vec![axis(X, -0.3, 0.3), axis(Z, -0.3, 0.3)],
        ),
        bone(
            "neck",
            Some("chest"),
            [0.0, 0.22, 0.0],
            [0.0, 1.0, 0.0],
            0.08,
            0.05,
            vec![axis(X, -0.6, 0.6), axis(Y, -0.8, 0.8)],
        ),
        bone(
            "head",
            Some("neck"),
            [0.0, 0.08, 0.0],
            [0.0, 1.0, 0.0],
            0.14,
            0.10,
            vec![axis(X, -0.6, 0.6), axis(Y, -0.8, 0.8), axis(Z, -0.5, 0.5)],
        ),
    ]
}

/// One side's arm (from the chest) and leg (from the pelvis); `s` is +1 on the left (+x), −1 on
/// the right.
fn limb_bones(side: &str, s: f32) -> [Bone; 7] {
    use Axis::{X, Y, Z};
    let n = |part: &str| format!("{side}_{part}");
    [
        bone(
            &n("clavicle"),
            Some("chest"),
            [0.0, 0.18, 0.0],
            [s, 0.0, 0.0],
            0.16,
            0.05,
            vec![],
        ),
        bone(
            &n("upper_arm"),
            Some(&n("clavicle")),
            [s * 0.16, 0.0, 0.0],
            [0.0, -1.0, 0.0],
            0.28,
            0.05,
            vec![axis(X, -PI, 1.0), axis(Y, -1.5, 1.5), abduction(s)],
        ),
        bone(
            &n("forearm"),
            Some(&n("upper_arm")),
            [0.0, -0.28, 0.0],
            [0.0, -1.0, 0.0],
            0.26,
            0.04,
            vec![axis(X, -2.6, 0.0)],
        ),
        bone(
            &n("hand"),
            Some(&n("forearm")),
            [0.0, -0.26, 0.0],
            [0.0, -1.0, 0.0],
            0.09,
            0.04,
            vec![axis(X, -0.8, 0.8), axis(Z, -0.4, 0.4)],
        ),
        bone(
            &n("thigh"),
            Some("pelvis"),
            [s * 0.10, 0.0, 0.0],
            [0.0, -1.0, 0.0],
            0.42,
            0.08,
            vec![axis(X, -2.0, 0.5), axis(Y, -0.6, 0.6), axis(Z, -0.6, 0.6)],
        ),
        bone(
            &n("shin"),
            Some(&n("thigh")),
            [0.0, -0.42, 0.0],
            [0.0, -1.0, 0.0],
            0.42,
            0.055,
            vec![axis(X, 0.0, 2.6)],
        ),
        bone(
            &n("foot"),
            Some(&n("shin")),
            [0.0, -0.42, 0.0],
            [0.0, 0.0, -1.0],
            0.20,
            0.045,
            vec![axis(X, -0.6, 0.6)],
        ),
    ]
}

/// Splits bone `i` in two collinear halves; the second half is a new child with no joint, and
/// the bone's children move onto it.
fn split(bones: &mut Vec<Bone>, i: usize) {
    let half = bones[i].length / 2.0;
    bones[i].length = half;
    let dir = nalgebra::Vector3::from(bones[i].direction).normalize();
    let step = dir * half;
    let name = format!(
        "{}_{}",
        bones[i].name,
        bones
            .iter()
            .filter(|b| b.name.starts_with(&bones[i].name))
            .count()
            + 1
    );
    let parent = bones[i].name.clone();
    for b in bones.iter_mut() {
        if b.parent.as_deref() == Some(parent.as_str()) {
            b.parent = Some(name.clone());
            b.offset = [
                b.offset[0] - step.x,
                b.offset[1] - step.y,
                b.offset[2] - step.z,
            ];
        }
    }
    let child = Bone {
        name,
        parent: Some(parent),
        offset: [step.x, step.y, step.z],
        direction: bones[i].direction,
        length: half,
        radius: bones[i].radius,
        joint: vec![],
    };
    // Insert right after the bone so that parents stay before children.
    bones.insert(i + 1, child);
}

/// The default human with `capsules` capsules (19 ≤ capsules ≤ 96): the longest segment is split
/// until the count is reached, so limbs get the extra capsules first.
pub fn human_skeleton(capsules: usize) -> Result<Skeleton, BodyError> {
    if !(BASE_CAPSULES..=MAX_CAPSULES).contains(&capsules) {
        return Err(BodyError::InvalidSkeleton(format!(
            "the default human has {BASE_CAPSULES} to {MAX_CAPSULES} capsules, not {capsules}"
        )));
    }
    let mut bones = base_bones();
    while bones.len() < capsules {
        let longest = (0..bones.len())
            .max_by(|&a, &b| bones[a].length.total_cmp(&bones[b].length).then(b.cmp(&a)))
            .unwrap_or(0);
        split(&mut bones, longest);
    }
    Skeleton::new(SkeletonSpec { bones })
}

/// θ for the rest pose standing `depth` metres in front of the camera (feet near y = −1).
pub fn standing_pose(skeleton: &Skeleton, depth: f32) -> Vec<f32> {
    let mut theta = vec![0.0; skeleton.dofs()];
    theta[1] = -0.05;
    theta[2] = depth;
    theta
}
