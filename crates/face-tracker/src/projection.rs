//! The 7-D face state and its weak-perspective projection (eq. 5–9 of the face paper).
//!
//! State x = (Tx, Ty, S, Rx, Ry, Rz, α): image translation (pixels), scale, rotation angles
//! (radians) and illumination gain. A model point P projects to p = S·R₂ₓ₃·P + (Tx, Ty), with
//! R = Rx·Ry·Rz and R₂ₓ₃ its first two rows; its normal rotates to R·N, and the point is
//! self-occluded when (R·N)_z < 0 (it faces away from the camera).

use nalgebra::{Matrix3, Vector2, Vector3};

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
