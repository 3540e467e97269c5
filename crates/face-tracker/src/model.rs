//! The face model: a heightmap and a normalmap over the face rectangle, so that every template
//! point gets a depth and a normal.
//!
//! Model coordinates (u, v) ∈ [−1, 1]² span the rectangle (u right, v down). Heights are in units
//! of the rectangle's half-width and grow towards the camera; normals are unit vectors in the
//! image frame (x right, y down, z towards the camera). The generic model is a smooth parametric
//! head — an ellipsoid with nose, brow and cheek relief; the photographed model puts a real face's
//! depth (the mean of five photographed faces) on its skull; and users can load their own maps.

use std::path::Path;

use crate::error::{FaceError, file_error};

/// A heightmap and a normalmap sampled on the same `size × size` grid over [−1, 1]².
#[derive(Debug, Clone, PartialEq)]
pub struct FaceModel {
    pub size: u32,
    /// Height at grid node (i, j) = `heights[j·size + i]`, u = −1 + 2i/(size − 1).
    pub heights: Vec<f32>,
    pub normals: Vec<[f32; 3]>,
}

fn gaussian(u: f32, v: f32, cu: f32, cv: f32, su: f32, sv: f32) -> f32 {
    let (du, dv) = ((u - cu) / su, (v - cv) / sv);
    (-0.5 * (du * du + dv * dv)).exp()
}

/// Where the generic head's nose tip and brow ridge are (model v; both at u = 0): the two
/// features that place landmarks on it (see [`crate::personal`]).
pub const NOSE_TIP_V: f32 = 0.3;
pub const BROW_RIDGE_V: f32 = -0.32;

/// Where the generic head's eyes' outer corners are (model u, ±; and v): where personalisation
/// places dlib's mean shape, and where [`crate::mesh_head`] zeroes the real face's depth.
pub const EYE_CORNER_U: f32 = 0.62;
pub const EYE_CORNER_V: f32 = -0.10;

/// The generic head's height at (u, v).
pub fn generic_height(u: f32, v: f32) -> f32 {
    // An ellipsoid a little taller than wide, flattened in depth.
    let (a, b, c) = (1.0, 1.15, 0.75);
    let inside = 1.0 - (u / a).powi(2) - (v / b).powi(2);
    let skull = c * inside.max(0.0).sqrt();
    // The nose stands out as far as a real one: its tip 1.03 eye-corner half-distances in front
    // of the eyes' outer corners (MediaPipe's face mesh of real faces: 1.00 to 1.03, a depth the
    // talking-face clips' own motion supports; docs/ACCURACY.md). With this relief 1/1.8 as high
    // (0.68) the tracker's yaw moved a third or more further than real heads turned.
    let nose = 0.504 * gaussian(u, v, 0.0, 0.12, 0.11, 0.22);
    let tip = 0.144 * gaussian(u, v, 0.0, NOSE_TIP_V, 0.08, 0.08);
    let brow = 0.07 * gaussian(u, v, 0.0, BROW_RIDGE_V, 0.55, 0.07);
    let cheeks =
        0.06 * (gaussian(u, v, -0.42, 0.22, 0.16, 0.14) + gaussian(u, v, 0.42, 0.22, 0.16, 0.14));
    // The relief fades out where the ellipsoid does.
    let fade = (inside * 4.0).clamp(0.0, 1.0);
    skull + fade * (nose + tip + brow + cheeks)
}

/// The photographed head's height at (u, v): a real face's depth on the face (the mean of
/// MediaPipe's face mesh over five photographed faces, [`crate::mesh_head`]) on the generic
/// head's skull around it, the two joined at the eyes' outer corners.
///
/// Its mouth and chin stand 0.2–0.4 half-widths further forward than the generic head's, its
/// forehead 0.1, and its nose is a ridge that rises to the tip where the generic one is a round
/// bump between the eyes. On real talking-face clips it brings the yaw's spread nearer the
/// reference's; on the synthetic video (whose heads are the generic head) it is the wrong model
/// (docs/ACCURACY.md has both).
pub fn photographed_height(u: f32, v: f32) -> f32 {
    photographed_height_with_face_depth(u, v, 1.0)
}

/// [`photographed_height`] with the face `face_depth` times as deep: its height above the eyes'
/// outer corners scaled wherever the photographed face covers the model (all of the rectangle
/// but its top and corners), the skull beyond it as it is. One depth does not fit every face: on the
/// real clips franck's turns want a face about 1.1 times as deep, carphone's the default
/// (docs/ACCURACY.md, "The widest turns").
pub fn photographed_height_with_face_depth(u: f32, v: f32, face_depth: f32) -> f32 {
    let (face, on_face) = mesh_head_at(u, v);
    let eye_corner = generic_height(EYE_CORNER_U, EYE_CORNER_V);
    on_face * (eye_corner + face_depth * face) + (1.0 - on_face) * generic_height(u, v)
}

/// The range [`FaceModel::photographed_with_face_depth`] accepts: a face from a quarter to four
/// times as deep as the photographed one.
pub const FACE_DEPTH_RANGE: std::ops::RangeInclusive<f32> = 0.25..=4.0;

/// Nodes per side of the built-in heads' grids.
pub const BUILT_IN_GRID: u32 = 129;

/// Which built-in head a tracker takes its points' depths from: one rule for the command line
/// (`face track --face-model`) and Python (`FaceTracker(face_model=)`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum BuiltInModel {
    /// The photographed head for real frames (a video, images, a webcam, arrays); the generic
    /// head for the synthetic video, whose heads are the generic model. Chosen by measurement on
    /// real clips against MediaPipe's face mesh (docs/ACCURACY.md, "Which face model by
    /// default").
    #[default]
    Auto,
    /// The parametric head (an ellipsoid with nose, brow and cheek relief).
    Generic,
    /// A real face's depth (the mean of five photographed faces) on the generic skull.
    Photographed,
}

impl BuiltInModel {
    /// The names [`std::str::FromStr`] takes, in order.
    pub const NAMES: [&str; 3] = ["auto", "generic", "photographed"];

    /// Whether this choice is the photographed head for frames that are (`synthetic`) or are
    /// not the synthetic video.
    pub fn is_photographed(self, synthetic: bool) -> bool {
        match self {
            Self::Auto => !synthetic,
            Self::Generic => false,
            Self::Photographed => true,
        }
    }

    /// The head, on a [`BUILT_IN_GRID`] grid; the photographed one with its face `face_depth`
    /// times as deep ([`FaceModel::photographed_with_face_depth`]), which the generic head does
    /// not take (an error unless it is 1).
    pub fn build(self, synthetic: bool, face_depth: f32) -> Result<FaceModel, FaceError> {
        if self.is_photographed(synthetic) {
            return FaceModel::photographed_with_face_depth(BUILT_IN_GRID, face_depth);
        }
        if face_depth != 1.0 {
            return Err(FaceError::InvalidInput(format!(
                "a face depth scale ({face_depth}) is for the photographed head; this one is the \
                 generic head"
            )));
        }
        FaceModel::generic(BUILT_IN_GRID)
    }
}

impl std::str::FromStr for BuiltInModel {
    type Err = FaceError;

    fn from_str(name: &str) -> Result<Self, FaceError> {
        match name {
            "auto" => Ok(Self::Auto),
            "generic" => Ok(Self::Generic),
            "photographed" => Ok(Self::Photographed),
            other => Err(FaceError::InvalidInput(format!(
                "no built-in face model {other:?}: the choices are {}",
                Self::NAMES.join(", ")
            ))),
        }
    }
}

/// The real face's height above the eye corners and its weight (1 on the face, 0 off it) at
/// (u, v), bilinear between the table's nodes.
fn mesh_head_at(u: f32, v: f32) -> (f32, f32) {
    use crate::mesh_head::{MESH_HEAD_GRID, MESH_HEAD_HEIGHTS, MESH_HEAD_ON_FACE};
    let corners = bilinear_corners(MESH_HEAD_GRID, u, v);
    let bilinear = |table: &[f32]| corners.iter().map(|&(k, w)| table[k] * w).sum::<f32>();
    (bilinear(&MESH_HEAD_HEIGHTS), bilinear(&MESH_HEAD_ON_FACE))
}

/// The four grid nodes around (u, v) on a `size × size` grid over [−1, 1]² (clamped to the
/// grid; node (i, j) at index j·size + i) and their bilinear weights.
fn bilinear_corners(size: usize, u: f32, v: f32) -> [(usize, f32); 4] {
    let last = (size - 1) as f32;
    let x = ((u + 1.0) / 2.0 * last).clamp(0.0, last);
    let y = ((v + 1.0) / 2.0 * last).clamp(0.0, last);
    let x0 = (x.floor() as usize).min(size - 2);
    let y0 = (y.floor() as usize).min(size - 2);
    let (fx, fy) = (x - x0 as f32, y - y0 as f32);
    let idx = |i: usize, j: usize| j * size + i;
    [
        (idx(x0, y0), (1.0 - fx) * (1.0 - fy)),
        (idx(x0 + 1, y0), fx * (1.0 - fy)),
        (idx(x0, y0 + 1), (1.0 - fx) * fy),
        (idx(x0 + 1, y0 + 1), fx * fy),
    ]
}

impl FaceModel {
    /// The generic head on a `size × size` grid, normals from central differences.
    pub fn generic(size: u32) -> Result<Self, FaceError> {
        Self::from_heights(size, generic_height)
    }

    /// The photographed head ([`photographed_height`]) on a `size × size` grid.
    pub fn photographed(size: u32) -> Result<Self, FaceError> {
        Self::from_heights(size, photographed_height)
    }

    /// The photographed head with its face `face_depth` times as deep
    /// ([`photographed_height_with_face_depth`]; 1 is [`Self::photographed`], bit for bit), for
    /// a face or camera whose turns the default depth misreads. `face_depth` must lie in
    /// [`FACE_DEPTH_RANGE`].
    pub fn photographed_with_face_depth(size: u32, face_depth: f32) -> Result<Self, FaceError> {
        if !FACE_DEPTH_RANGE.contains(&face_depth) {
            return Err(FaceError::InvalidInput(format!(
                "the face's depth scale must lie in {} to {}, got {face_depth}",
                FACE_DEPTH_RANGE.start(),
                FACE_DEPTH_RANGE.end()
            )));
        }
        Self::from_heights(size, |u, v| {
            photographed_height_with_face_depth(u, v, face_depth)
        })
    }

    /// `height(u, v)` on a `size × size` grid, normals from central differences.
    fn from_heights(size: u32, height: impl Fn(f32, f32) -> f32) -> Result<Self, FaceError> {
        if size < 3 {
            return Err(FaceError::InvalidInput(format!(
                "a face model grid needs at least 3x3 nodes, got {size}"
            )));
        }
        let coord = |i: u32| -1.0 + 2.0 * i as f32 / (size - 1) as f32;
        let heights: Vec<f32> = (0..size * size)
            .map(|k| height(coord(k % size), coord(k / size)))
            .collect();
        let model = Self {
            size,
            normals: normals_from_heights(size, &heights),
            heights,
        };
        Ok(model)
    }

    /// Loads user maps: a gray heightmap PNG (8 or 16 bit; black 0, white `max_height` half-widths)
    /// and an RGB normalmap PNG (n = 2·rgb/255 − 1, x right, y down, z out), square and of the
    /// same size.
    pub fn load(heightmap: &Path, normalmap: &Path, max_height: f32) -> Result<Self, FaceError> {
        if !(max_height.is_finite() && max_height > 0.0) {
            return Err(FaceError::InvalidInput(format!(
                "the heightmap's scale must be > 0, got {max_height}"
            )));
        }
        let decode = |path: &Path| {
            image::ImageReader::open(path)
                .map_err(|e| file_error(path, e))?
                .with_guessed_format()
                .map_err(|e| file_error(path, e))?
                .decode()
                .map_err(|e| file_error(path, format!("cannot decode the image: {e}")))
        };
        let h = decode(heightmap)?;
        let n = decode(normalmap)?;
        if h.color().has_color() || h.color().has_alpha() {
            return Err(file_error(
                heightmap,
                format!(
                    "a heightmap must be a gray image; this one is {:?}",
                    h.color()
                ),
            ));
        }
        if !n.color().has_color() {
            return Err(file_error(
                normalmap,
                format!(
                    "a normalmap must be an RGB image; this one is {:?}",
                    n.color()
                ),
            ));
        }
        let size = h.width();
        if h.height() != size || n.width() != size || n.height() != size || size < 3 {
            return Err(file_error(
                normalmap,
                format!(
                    "the maps must be square, at least 3x3 and of one size: heightmap {}x{}, normalmap {}x{}",
                    h.width(),
                    h.height(),
                    n.width(),
                    n.height()
                ),
            ));
        }
        let heights = h
            .to_luma32f()
            .into_raw()
            .into_iter()
            .map(|v| v * max_height)
            .collect();
        let mut normals = Vec::with_capacity((size * size) as usize);
        for (k, px) in n.to_rgb32f().pixels().enumerate() {
            let v = [2.0 * px[0] - 1.0, 2.0 * px[1] - 1.0, 2.0 * px[2] - 1.0];
            let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            if len < 1e-3 {
                return Err(file_error(
                    normalmap,
                    format!("pixel {k} encodes a zero normal"),
                ));
            }
            normals.push(v.map(|c| c / len));
        }
        Ok(Self {
            size,
            heights,
            normals,
        })
    }

    /// Height and unit normal at (u, v), bilinear between grid nodes (clamped to the grid).
    pub fn sample(&self, u: f32, v: f32) -> (f32, [f32; 3]) {
        let corners = bilinear_corners(self.size as usize, u, v);
        let mut h = 0.0;
        let mut n = [0.0f32; 3];
        for (k, w) in corners {
            h += self.heights[k] * w;
            for (acc, c) in n.iter_mut().zip(self.normals[k]) {
                *acc += c * w;
            }
        }
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt().max(1e-12);
        (h, n.map(|c| c / len))
    }
}

/// Unit normals (−∂h/∂u, −∂h/∂v, 1) of a height grid over [−1, 1]², by central differences.
fn normals_from_heights(size: u32, heights: &[f32]) -> Vec<[f32; 3]> {
    let step = 2.0 / (size - 1) as f32;
    let at = |i: i64, j: i64| {
        let i = i.clamp(0, size as i64 - 1) as u32;
        let j = j.clamp(0, size as i64 - 1) as u32;
        heights[(j * size + i) as usize]
    };
    (0..size * size)
        .map(|k| {
            let (i, j) = ((k % size) as i64, (k / size) as i64);
            let du = (at(i + 1, j) - at(i - 1, j)) / (2.0 * step);
            let dv = (at(i, j + 1) - at(i, j - 1)) / (2.0 * step);
            let n = [-du, -dv, 1.0];
            let len = (n[0] * n[0] + n[1] * n[1] + 1.0f32).sqrt();
            n.map(|c| c / len)
        })
        .collect()
}

#[cfg(test)]
mod built_in_tests {
    use super::*;

    #[test]
    fn auto_is_the_photographed_head_for_real_frames_and_the_generic_for_the_synthetic_video() {
        assert!(BuiltInModel::Auto.is_photographed(false));
        assert!(!BuiltInModel::Auto.is_photographed(true));
        for synthetic in [false, true] {
            assert!(BuiltInModel::Photographed.is_photographed(synthetic));
            assert!(!BuiltInModel::Generic.is_photographed(synthetic));
        }
        let generic = FaceModel::generic(BUILT_IN_GRID).unwrap();
        let photographed = FaceModel::photographed(BUILT_IN_GRID).unwrap();
        assert_eq!(BuiltInModel::Auto.build(true, 1.0).unwrap(), generic);
        assert_eq!(BuiltInModel::Auto.build(false, 1.0).unwrap(), photographed);
        assert!(BuiltInModel::Generic.build(false, 1.5).is_err());
        assert!(BuiltInModel::Photographed.build(true, 9.0).is_err());
    }

    #[test]
    fn every_name_parses_and_a_wrong_one_lists_them() {
        for name in BuiltInModel::NAMES {
            let model: BuiltInModel = name.parse().unwrap();
            assert_eq!(BuiltInModel::NAMES[model as usize], name);
        }
        let err = "mesh".parse::<BuiltInModel>().unwrap_err().to_string();
        assert!(err.contains("auto, generic, photographed"), "{err}");
    }
}
