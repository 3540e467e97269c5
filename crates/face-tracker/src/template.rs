//! Sparse templates: the feature points a face is tracked by.

use bytemuck::{Pod, Zeroable};
use nalgebra::{Matrix3, Vector3};

use crate::error::FaceError;

/// One feature point q = (P, N, J): its position in the face model (pixels of the frame where the
/// template was taken, relative to the face centre; x right, y down, z towards the camera), the
/// unit surface normal there, and the gray level J it had. The layout is the GPU's.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct FeaturePoint {
    pub position: [f32; 3],
    /// J, the template's gray level (> 0: the residual is relative to it).
    pub gray: f32,
    pub normal: [f32; 3],
    pub _pad: f32,
}

impl FeaturePoint {
    pub fn new(position: [f32; 3], normal: [f32; 3], gray: f32) -> Self {
        Self {
            position,
            gray,
            normal,
            _pad: 0.0,
        }
    }
}

/// The smallest template gray level: the residual (αI − J)/J divides by J.
pub const MIN_GRAY: f32 = 1.0;

/// A face's feature points.
#[derive(Debug, Clone, PartialEq)]
pub struct Template {
    pub points: Vec<FeaturePoint>,
    /// The face's 68 iBUG landmarks in the same frame as the points, on the model's surface,
    /// when the template was built with a landmark model: the fitted landmarks on a
    /// personalised template, the generic head's where the fit failed; posed by an estimate
    /// they give the landmarks' pixels in a frame (`face track --landmarks-out`).
    pub landmarks: Option<Vec<[f32; 3]>>,
}

impl Template {
    /// Checks the points: at least one, finite values, J ≥ [`MIN_GRAY`], non-zero normals.
    pub fn new(points: Vec<FeaturePoint>) -> Result<Self, FaceError> {
        if points.is_empty() {
            return Err(FaceError::InvalidInput(
                "a template needs at least one feature point".into(),
            ));
        }
        for (i, q) in points.iter().enumerate() {
            let finite = q
                .position
                .iter()
                .chain(&q.normal)
                .chain([&q.gray])
                .all(|v| v.is_finite());
            let normal_len = q.normal.iter().map(|v| v * v).sum::<f32>().sqrt();
            if !finite || q.gray < MIN_GRAY || normal_len < 1e-6 {
                return Err(FaceError::InvalidInput(format!(
                    "feature point {i} is invalid (position {:?}, normal {:?}, gray {}): values must be finite, the gray level at least {MIN_GRAY}, the normal non-zero",
                    q.position, q.normal, q.gray
                )));
            }
        }
        Ok(Self {
            points,
            landmarks: None,
        })
    }

    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// The layout of pf-gpu's face kernel: (P, J), (N, 0) per point.
    pub fn gpu_layout(&self) -> Vec<[f32; 4]> {
        self.points
            .iter()
            .flat_map(|q| {
                let [px, py, pz] = q.position;
                let [nx, ny, nz] = q.normal;
                [[px, py, pz, q.gray], [nx, ny, nz, 0.0]]
            })
            .collect()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The template as a face already at `scale` and `rotation` would have it: a template is
    /// taken as if the face looked straight at the camera, so posing its points (positions,
    /// normals, landmarks) back by Rᵀ/S makes a state with that scale and rotation show them
    /// exactly as they were seen. A track that takes a new template goes on from its pose.
    pub fn posed_back(mut self, scale: f32, rotation: &Matrix3<f32>) -> Self {
        let back = |v: [f32; 3]| -> [f32; 3] { (rotation.transpose() * Vector3::from(v)).into() };
        for q in &mut self.points {
            q.position = back(q.position).map(|c| c / scale);
            q.normal = back(q.normal);
        }
        if let Some(landmarks) = &mut self.landmarks {
            for p in landmarks.iter_mut() {
                *p = back(*p).map(|c| c / scale);
            }
        }
        self
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::projection::{DIMS, Pose};
    use proptest::prelude::*;

    proptest! {
        /// A template posed back by (S, R) and then posed by a state with that S and R shows
        /// every point where it was seen, facing the way it faced.
        #[test]
        fn a_template_posed_back_is_seen_as_it_was_taken(
            points in proptest::collection::vec(
                (prop::array::uniform3(-60.0f32..60.0), prop::array::uniform3(-1.0f32..1.0)),
                1..20,
            ),
            scale in 0.2f32..5.0,
            angles in prop::array::uniform3(-1.2f32..1.2),
            centre in prop::array::uniform2(0.0f32..640.0),
        ) {
            let points: Vec<FeaturePoint> = points
                .iter()
                .map(|&(p, n)| FeaturePoint::new(p, [n[0], n[1], n[2] + 2.0], 100.0))
                .collect();
            let mut seen = Template::new(points).unwrap();
            seen.landmarks = Some(seen.points.iter().map(|q| q.position).collect());
            let mut state = [0.0f32; DIMS];
            state[..3].copy_from_slice(&[centre[0], centre[1], scale]);
            state[3..6].copy_from_slice(&angles);
            state[6] = 1.0;
            let pose = Pose::new(&state);
            let posed = seen.clone().posed_back(scale, &pose.rotation);
            let landmarks = posed.landmarks.as_ref().unwrap();
            for ((was, is), landmark) in seen.points.iter().zip(&posed.points).zip(landmarks) {
                let expected = [was.position[0] + centre[0], was.position[1] + centre[1]];
                for p in [is.position, *landmark] {
                    let at = pose.project(&Vector3::from(p));
                    prop_assert!((at.x - expected[0]).abs() < 1e-3 * (1.0 + expected[0].abs()));
                    prop_assert!((at.y - expected[1]).abs() < 1e-3 * (1.0 + expected[1].abs()));
                }
                let facing = pose.rotation * Vector3::from(is.normal);
                for d in 0..3 {
                    prop_assert!((facing[d] - was.normal[d]).abs() < 1e-4);
                }
                prop_assert_eq!(is.gray, was.gray);
            }
        }
    }
}
