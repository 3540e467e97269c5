//! Sparse templates: the feature points a face is tracked by.

use bytemuck::{Pod, Zeroable};

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
}
