//! The 7-D face state and its weak-perspective projection (eq. 5–9 of the face paper).
//!
//! State x = (Tx, Ty, S, Rx, Ry, Rz, α): image translation (pixels), scale, rotation angles
//! (radians) and illumination gain. A model point P projects to p = S·R₂ₓ₃·P + (Tx, Ty), with
//! R = Rx·Ry·Rz and R₂ₓ₃ its first two rows; its normal rotates to R·N, and the point is
//! self-occluded when (R·N)_z < 0 (it faces away from the camera).

use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector2, Vector3};

/// Indices into the state.
pub const TX: usize = 0;
pub const TY: usize = 1;
pub const SCALE: usize = 2;
pub const RX: usize = 3;
pub const RY: usize = 4;
pub const RZ: usize = 5;
pub const ALPHA: usize = 6;
/// The state's dimension.
pub const DIMS: usize = 7;

/// The names of the state's values (CSV headers).
pub const STATE_NAMES: [&str; DIMS] = ["tx", "ty", "scale", "rx", "ry", "rz", "alpha"];

/// R = Rx(a)·Ry(b)·Rz(c), right-handed rotations about the model axes.
pub fn rotation(rx: f32, ry: f32, rz: f32) -> Matrix3<f32> {
    let (sx, cx) = rx.sin_cos();
    let (sy, cy) = ry.sin_cos();
    let (sz, cz) = rz.sin_cos();
    let x = Matrix3::new(1.0, 0.0, 0.0, 0.0, cx, -sx, 0.0, sx, cx);
    let y = Matrix3::new(cy, 0.0, sy, 0.0, 1.0, 0.0, -sy, 0.0, cy);
    let z = Matrix3::new(cz, -sz, 0.0, sz, cz, 0.0, 0.0, 0.0, 1.0);
    x * y * z
}

/// The head's rotation as (pitch, yaw, roll) in degrees: rx about the model's horizontal axis
/// (nodding), ry about its vertical axis (turning), rz about the viewing axis (tilting), the
/// intrinsic x-y′-z″ angles of R = Rx·Ry·Rz.
pub fn pitch_yaw_roll_degrees(state: &[f32; DIMS]) -> [f32; 3] {
    [state[RX], state[RY], state[RZ]].map(f32::to_degrees)
}

/// The head's rotation R = Rx·Ry·Rz as a unit quaternion (w, x, y, z), w ≥ 0.
pub fn rotation_quaternion(state: &[f32; DIMS]) -> [f32; 4] {
    let r = rotation(state[RX], state[RY], state[RZ]);
    let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    let sign = if q.w < 0.0 { -1.0 } else { 1.0 };
    [q.w, q.i, q.j, q.k].map(|v| v * sign)
}

/// A posed face: the state's rotation computed once.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    pub translation: Vector2<f32>,
    pub scale: f32,
    pub rotation: Matrix3<f32>,
    pub alpha: f32,
}

impl Pose {
    pub fn new(state: &[f32; DIMS]) -> Self {
        Self {
            translation: Vector2::new(state[TX], state[TY]),
            scale: state[SCALE],
            rotation: rotation(state[RX], state[RY], state[RZ]),
            alpha: state[ALPHA],
        }
    }

    /// The image position of model point `p` (eq. 5–9).
    pub fn project(&self, p: &Vector3<f32>) -> Vector2<f32> {
        let r = self.rotation * p;
        Vector2::new(r.x, r.y) * self.scale + self.translation
    }

    /// Whether a point with model normal `n` faces the camera.
    pub fn faces_camera(&self, n: &Vector3<f32>) -> bool {
        (self.rotation * n).z >= 0.0
    }
}

#[cfg(test)]
mod angle_output_tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn the_quaternion_rotates_as_the_matrix_does(
            rx in -1.3f32..1.3, ry in -1.3f32..1.3, rz in -3.2f32..3.2,
            v in prop::array::uniform3(-1.0f32..1.0),
        ) {
            let state = [0.0, 0.0, 1.0, rx, ry, rz, 1.0];
            let [w, x, y, z] = rotation_quaternion(&state);
            prop_assert!(w >= 0.0);
            prop_assert!(((w * w + x * x + y * y + z * z) - 1.0).abs() < 1e-5);
            let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z));
            let v = Vector3::from(v);
            let by_matrix = rotation(rx, ry, rz) * v;
            prop_assert!((q * v - by_matrix).norm() < 1e-5);
            let [pitch, yaw, roll] = pitch_yaw_roll_degrees(&state);
            prop_assert!((pitch.to_radians() - rx).abs() < 1e-6);
            prop_assert!((yaw.to_radians() - ry).abs() < 1e-6);
            prop_assert!((roll.to_radians() - rz).abs() < 1e-6);
        }
    }
}
