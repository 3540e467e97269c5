//! A face estimate in OpenFace 2.0's units and conventions (`FeatureExtraction`'s CSV columns
//! `pose_Tx … pose_Rz`), so that analysis scripts written for OpenFace read streampf's results.
//!
//! OpenFace's camera frame: x right, y down, z away from the camera, millimetres; a head's
//! rotation R = Rx·Ry·Rz of (pose_Rx, pose_Ry, pose_Rz) radians maps its model into that frame,
//! and a point X projects to (fx·X/Z + cx, fy·Y/Z + cy). streampf's model frame has z towards
//! the camera (`crate::model`): the same frame mirrored in z, so R_OpenFace = P·R·P with
//! P = diag(1, 1, −1), which is Rx(−rx)·Ry(−ry)·Rz(rz).
//!
//! Distance needs a size: a template's units are the pixels of the frame it was built in, so
//! the face's metric size comes from its landmarks, the outer eye corners taken
//! [`OUTER_EYE_CORNERS_MM`] apart (an adult's mean). Through a pinhole ([`Lens`] with a focal
//! length: `--fov`, `--camera`) the pose then reprojects every model point exactly where
//! [`crate::Pose::project_through`] puts it; under weak perspective (no focal length) the
//! distance uses OpenFace's own default focal length, 500 px per 640 px of width.

use nalgebra::{Matrix3, Vector3};

use crate::landmarks::ibug68::{LEFT_EYE_OUTER, RIGHT_EYE_OUTER};
use crate::likelihood::Lens;
use crate::projection::{DIMS, RX, RY, RZ, SCALE, TX, TY};

/// The distance between the outer corners of the eyes (exocanthion to exocanthion) taken for
/// every face, in millimetres: an adult's mean, about 90 mm.
pub const OUTER_EYE_CORNERS_MM: f32 = 90.0;

/// OpenFace's focal length when it is not given: 500 px for a 640 px wide frame, scaled.
pub fn openface_default_focal(width: u32) -> f32 {
    500.0 * width as f32 / 640.0
}

/// A head's pose as OpenFace reports it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OpenFacePose {
    /// (pose_Tx, pose_Ty, pose_Tz): the model's origin in the camera frame, millimetres.
    pub translation_mm: [f32; 3],
    /// (pose_Rx, pose_Ry, pose_Rz), radians: R = Rx·Ry·Rz.
    pub rotation: [f32; 3],
}

/// The camera OpenFace's columns are read through: focal length and principal point, pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OpenFaceCamera {
    pub focal: f32,
    pub principal: [f32; 2],
}

impl OpenFaceCamera {
    /// The lens's pinhole, or OpenFace's default camera for a `width × height` frame under
    /// weak perspective.
    pub fn of(lens: &Lens, width: u32, height: u32) -> Self {
        if lens.inverse_focal > 0.0 {
            Self {
                focal: 1.0 / lens.inverse_focal,
                principal: lens.principal,
            }
        } else {
            Self {
                focal: openface_default_focal(width),
                principal: [width as f32 / 2.0, height as f32 / 2.0],
            }
        }
    }

    /// Where a point of OpenFace's camera frame projects (`None` at or behind the camera).
    pub fn project(&self, x: &Vector3<f32>) -> Option<[f32; 2]> {
        (x.z > 0.0).then(|| {
            [
                self.focal * x.x / x.z + self.principal[0],
                self.focal * x.y / x.z + self.principal[1],
            ]
        })
    }
}

/// Millimetres per template unit of a face whose 68 landmarks (template frame) are
/// `landmarks`: [`OUTER_EYE_CORNERS_MM`] over the outer eye corners' distance; `None` for
/// landmarks without two distinct eye corners.
pub fn millimetres_per_unit(landmarks: &[[f32; 3]]) -> Option<f32> {
    let (right, left) = (
        landmarks.get(RIGHT_EYE_OUTER)?,
        landmarks.get(LEFT_EYE_OUTER)?,
    );
    let apart = (Vector3::from(*right) - Vector3::from(*left)).norm();
    (apart.is_finite() && apart > 1e-6).then(|| OUTER_EYE_CORNERS_MM / apart)
}

/// The pose of `state` in OpenFace's conventions, seen by `camera`, for a face of
/// `mm_per_unit` millimetres per template unit; `None` for a non-positive scale.
pub fn openface_pose(
    state: &[f32; DIMS],
    mm_per_unit: f32,
    camera: &OpenFaceCamera,
) -> Option<OpenFacePose> {
    let scale = state[SCALE];
    if !(scale > 0.0 && mm_per_unit > 0.0) {
        return None;
    }
    // The template's origin shows at (tx, ty) whatever the lens; a template unit spans `scale`
    // pixels there, so the origin lies at depth f·mm_per_unit/scale.
    let depth = camera.focal * mm_per_unit / scale;
    let along = |pixel: f32, principal: f32| (pixel - principal) * depth / camera.focal;
    Some(OpenFacePose {
        translation_mm: [
            along(state[TX], camera.principal[0]),
            along(state[TY], camera.principal[1]),
            depth,
        ],
        rotation: [-state[RX], -state[RY], state[RZ]],
    })
}

/// A template point `p` (template units, streampf's model frame) in OpenFace's camera frame
/// under `pose`: R_OpenFace·(P·p·mm_per_unit) + T. What OpenFace's `X_i, Y_i, Z_i` would be.
pub fn openface_point(pose: &OpenFacePose, p: &[f32; 3], mm_per_unit: f32) -> Vector3<f32> {
    let [rx, ry, rz] = pose.rotation;
    let rotation: Matrix3<f32> = crate::projection::rotation(rx, ry, rz);
    let mirrored = Vector3::new(p[0], p[1], -p[2]) * mm_per_unit;
    rotation * mirrored + Vector3::from(pose.translation_mm)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Pose;
    use proptest::prelude::*;

    /// OpenFace's own `Euler2RotationMatrix` (RotationHelpers.h), written out as it has it:
    /// R = Rx·Ry·Rz of (pose_Rx, pose_Ry, pose_Rz).
    fn openface_rotation([rx, ry, rz]: [f32; 3]) -> Matrix3<f32> {
        let (s1, c1, s2, c2, s3, c3) = (rx.sin(), rx.cos(), ry.sin(), ry.cos(), rz.sin(), rz.cos());
        Matrix3::new(
            c2 * c3,
            -c2 * s3,
            s2,
            c1 * s3 + c3 * s1 * s2,
            c1 * c3 - s1 * s2 * s3,
            -c2 * s1,
            s1 * s3 - c1 * c3 * s2,
            c3 * s1 + c1 * s2 * s3,
            c1 * c2,
        )
    }

    proptest! {
        /// Through a pinhole, OpenFace's reading of a pose puts every model point where
        /// streampf's projection does: its rotation convention, the mirrored z and the
        /// distance from the eye corners are consistent (a sign flipped anywhere moves the
        /// points by pixels).
        #[test]
        fn openface_pose_reprojects_model_points_where_streampf_does(
            focal in 200.0f32..3000.0,
            size in (320u32..2000, 240u32..1500),
            centre in prop::array::uniform2(0.2f32..0.8),
            scale in 0.3f32..3.0,
            angles in prop::array::uniform3(-0.6f32..0.6),
            points in prop::collection::vec(prop::array::uniform3(-60.0f32..60.0), 68),
            eyes in 30.0f32..80.0,
        ) {
            let lens = Lens::pinhole(focal, size.0, size.1).unwrap();
            let mut landmarks = points.clone();
            // The depth of a point stays well in front of the camera.
            for p in &mut landmarks {
                p[2] *= 0.5;
            }
            landmarks[RIGHT_EYE_OUTER] = [-eyes / 2.0, -10.0, 5.0];
            landmarks[LEFT_EYE_OUTER] = [eyes / 2.0, -10.0, 5.0];
            let state = [
                centre[0] * size.0 as f32,
                centre[1] * size.1 as f32,
                scale,
                angles[0],
                angles[1],
                angles[2],
                1.0,
            ];
            let mm = millimetres_per_unit(&landmarks).unwrap();
            prop_assert!((mm * eyes - OUTER_EYE_CORNERS_MM).abs() < 1e-3);
            let camera = OpenFaceCamera::of(&lens, size.0, size.1);
            let pose = openface_pose(&state, mm, &camera).unwrap();
            let ours = Pose::new(&state);
            for p in &landmarks {
                let want = ours.project_through(&Vector3::from(*p), &lens);
                // OpenFace's model point (its z away from the camera), rotated by its own
                // formula and moved by pose_T.
                let model = Vector3::new(p[0], p[1], -p[2]) * mm;
                let seen = openface_rotation(pose.rotation) * model + Vector3::from(pose.translation_mm);
                prop_assert!((seen - openface_point(&pose, p, mm)).norm() < 1e-2);
                let got = camera.project(&seen);
                match (want, got) {
                    (Some(w), Some(g)) => prop_assert!(
                        (w.x - g[0]).abs() < 0.02 && (w.y - g[1]).abs() < 0.02,
                        "{p:?}: streampf {w:?}, OpenFace {g:?}"
                    ),
                    (None, None) => {}
                    other => prop_assert!(false, "{p:?}: {other:?}"),
                }
            }
            // The face is in front of the camera, at the distance its eye corners say.
            prop_assert!(pose.translation_mm[2] > 0.0);
        }
    }

    #[test]
    fn weak_perspective_uses_openfaces_default_camera_and_bad_inputs_give_none() {
        let camera = OpenFaceCamera::of(&Lens::WEAK, 1280, 720);
        assert_eq!(camera.focal, 1000.0);
        assert_eq!(camera.principal, [640.0, 360.0]);
        // A face 90 px between the outer eye corners at scale 1 lies f px·mm / px away: 1 m.
        let mut landmarks = vec![[0.0f32; 3]; 68];
        landmarks[LEFT_EYE_OUTER] = [90.0, 0.0, 0.0];
        let mm = millimetres_per_unit(&landmarks).unwrap();
        let state = [640.0, 360.0, 1.0, 0.1, -0.2, 0.3, 1.0];
        let pose = openface_pose(&state, mm, &camera).unwrap();
        assert_eq!(pose.translation_mm, [0.0, 0.0, 1000.0]);
        assert_eq!(pose.rotation, [-0.1, 0.2, 0.3]);
        assert!(millimetres_per_unit(&[[0.0; 3]; 68]).is_none());
        assert!(millimetres_per_unit(&[[0.0; 3]; 10]).is_none());
        assert!(openface_pose(&[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], mm, &camera).is_none());
    }
}
