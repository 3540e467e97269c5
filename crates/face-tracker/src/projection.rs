//! The 7-D face state and its weak-perspective projection (eq. 5–9 of the face paper).
//!
//! State x = (Tx, Ty, S, Rx, Ry, Rz, α): image translation (pixels), scale, rotation angles
//! (radians) and illumination gain. A model point P projects to p = S·R₂ₓ₃·P + (Tx, Ty), with
//! R = Rx·Ry·Rz and R₂ₓ₃ its first two rows; its normal rotates to R·N, and the point is
//! self-occluded when (R·N)_z < 0 (it faces away from the camera).

use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector2, Vector3};

use crate::lens::Lens;

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

    /// The image position of model point `p` seen through `lens` ([`Self::project`] for weak
    /// perspective; magnified by its depth about the principal point through a pinhole), `None`
    /// at or behind the camera.
    pub fn project_through(&self, p: &Vector3<f32>, lens: &Lens) -> Option<Vector2<f32>> {
        let r = self.rotation * p;
        let weak = Vector2::new(r.x, r.y) * self.scale + self.translation;
        let [x, y] = lens.apply([weak.x, weak.y], self.scale * r.z)?;
        Some(Vector2::new(x, y))
    }

    /// Whether a point with model normal `n` faces the camera.
    pub fn faces_camera(&self, n: &Vector3<f32>) -> bool {
        (self.rotation * n).z >= 0.0
    }
}

#[cfg(test)]
mod lens_tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// Through a pinhole a point at the face's centre depth is where weak perspective puts
        /// it; nearer points move away from the principal point, further ones towards it, by
        /// f/(f − d); `unapply` undoes `apply`; a point at or behind the camera is not imaged.
        #[test]
        fn a_pinhole_magnifies_by_depth_about_its_principal_point(
            focal in 50.0f32..5000.0,
            size in (64u32..4000, 64u32..3000),
            weak in prop::array::uniform2(-500.0f32..4500.0),
            depth_share in -3.0f32..0.9,
        ) {
            let lens = Lens::pinhole(focal, size.0, size.1).unwrap();
            let [px, py] = lens.principal;
            prop_assert_eq!([px, py], [(size.0 - 1) as f32 / 2.0, (size.1 - 1) as f32 / 2.0]);
            let at_centre = lens.apply(weak, 0.0).expect("in front of the camera");
            for (s, w) in at_centre.iter().zip(weak) {
                prop_assert!((s - w).abs() <= 1e-3 * (1.0 + w.abs()), "{s} vs {w}");
            }
            let depth = depth_share * focal;
            let seen = lens.apply(weak, depth).expect("in front of the camera");
            let magnification = focal / (focal - depth);
            for (s, (w, p)) in seen.iter().zip(weak.iter().zip([px, py])) {
                let want = p + (w - p) * magnification;
                prop_assert!((s - want).abs() <= 1e-3 * (1.0 + want.abs()), "{s} vs {want}");
            }
            let back = lens.unapply(seen, depth);
            for (b, w) in back.iter().zip(weak) {
                prop_assert!((b - w).abs() <= 1e-3 * (1.0 + w.abs()), "{b} vs {w}");
            }
            prop_assert_eq!(lens.apply(weak, focal), None);
            prop_assert_eq!(lens.apply(weak, 2.0 * focal), None);
            prop_assert_eq!(Lens::WEAK.apply(weak, depth), Some(weak));
            prop_assert_eq!(Lens::WEAK.unapply(weak, depth), weak);
        }
    }

    #[test]
    fn a_focal_length_must_be_finite_and_positive() {
        for bad in [0.0, -10.0, f32::NAN, f32::INFINITY] {
            let err = Lens::pinhole(bad, 640, 480).unwrap_err().to_string();
            assert!(err.contains("focal length"), "{bad}: {err}");
        }
    }

    /// `Pose::project_through` is `Pose::project` through weak perspective, and through a
    /// pinhole the weak image magnified by the rotated point's depth times S.
    #[test]
    fn projecting_through_a_lens_magnifies_the_weak_image() {
        let state = [300.0, 200.0, 1.5, 0.2, -0.4, 0.1, 1.0];
        let pose = Pose::new(&state);
        let p = Vector3::new(12.0, -30.0, 25.0);
        let weak = pose.project(&p);
        assert_eq!(pose.project_through(&p, &Lens::WEAK), Some(weak));
        let lens = Lens::pinhole(400.0, 640, 480).unwrap();
        let depth = 1.5 * (pose.rotation * p).z;
        let seen = pose.project_through(&p, &lens).unwrap();
        let m = 400.0 / (400.0 - depth);
        assert!((seen.x - (319.5 + (weak.x - 319.5) * m)).abs() < 1e-3);
        assert!((seen.y - (239.5 + (weak.y - 239.5) * m)).abs() < 1e-3);
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
