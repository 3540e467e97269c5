//! Facial landmarks: dlib's 68-point regression-tree shape predictor (Kazemi & Sullivan's
//! "One millisecond face alignment with an ensemble of regression trees"), read from dlib's own
//! model file and run in Rust, and the `.pts` files that annotated face sets come in.
//!
//! The predictor starts from the mean shape placed in a face box and refines it through a cascade
//! of levels. Each level reads a few hundred pixels at offsets from landmarks of the current shape
//! (the offsets are turned and scaled with the shape: a similarity from the mean shape), and each
//! of its trees compares two of those pixels per split and adds its leaf's shape increment.
//! Debian's libdlib-data ships the 68-point model as
//! `/usr/share/dlib/shape_predictor_68_face_landmarks.dat` ([`DEFAULT_PREDICTOR`]).

mod dlib_format;
pub mod ibug68;
pub mod pts;

use std::path::Path;

use crate::error::{FaceError, file_error};
use crate::extraction::FaceRect;
use crate::image::GrayImage;
use dlib_format::{FormatError, Reader};

/// Where Debian's libdlib-data installs the 68-landmark model.
pub const DEFAULT_PREDICTOR: &str = "/usr/share/dlib/shape_predictor_68_face_landmarks.dat";

/// Landmark positions (x, y) in frame pixels, in the model's order.
pub type Landmarks = Vec<[f32; 2]>;

/// One split of a regression tree: go left when pixel `a` − pixel `b` > `threshold`.
#[derive(Debug, Clone, Copy)]
struct Split {
    a: u32,
    b: u32,
    threshold: f32,
}

/// A complete binary tree stored breadth first; leaf k's shape increment is
/// `increments[k·2L .. (k+1)·2L]` for L landmarks.
#[derive(Debug, Clone)]
struct RegressionTree {
    splits: Vec<Split>,
    increments: Vec<f32>,
}

/// One level of the cascade: where its feature pixels sit and the trees that read them.
#[derive(Debug, Clone)]
struct CascadeLevel {
    /// The landmark each feature pixel hangs from, and its offset in mean-shape coordinates.
    anchors: Vec<u32>,
    offsets: Vec<[f32; 2]>,
    trees: Vec<RegressionTree>,
}

/// A trained shape predictor.
#[derive(Debug, Clone)]
pub struct ShapePredictor {
    /// The mean shape, flattened (x0, y0, x1, y1, …), in box coordinates ([0, 1]² spans the box).
    mean_shape: Vec<f32>,
    levels: Vec<CascadeLevel>,
}

/// The largest counts a real model has, with room to spare: a corrupt count fails early.
const MAX_LANDMARKS: u64 = 10_000;
const MAX_LEVELS: u64 = 1_000;
const MAX_TREES: u64 = 100_000;
const MAX_PIXELS: u64 = 100_000;

impl ShapePredictor {
    /// Reads a dlib `shape_predictor` file (for example [`DEFAULT_PREDICTOR`]).
    pub fn load(path: &Path) -> Result<Self, FaceError> {
        let bytes = std::fs::read(path).map_err(|e| {
            let hint = if path == Path::new(DEFAULT_PREDICTOR) {
                " (Debian's libdlib-data package installs it: apt-get install libdlib-data)"
            } else {
                ""
            };
            file_error(path, format!("cannot read the landmark model: {e}{hint}"))
        })?;
        Self::from_bytes(&bytes).map_err(|e| {
            file_error(
                path,
                format!("not a dlib shape_predictor landmark model (a file like {DEFAULT_PREDICTOR}): {e}"),
            )
        })
    }

    /// Parses a dlib `shape_predictor` from its serialised bytes.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, FormatError> {
        let mut r = Reader::new(bytes);
        let version = r.signed("the version")?;
        if version != 1 {
            return Err(r.error(format!("version {version}; only version 1 is known")));
        }
        let mean_shape = r.float_column("the mean shape")?;
        if mean_shape.is_empty() || mean_shape.len() % 2 != 0 {
            return Err(r.error(format!(
                "the mean shape has {} coordinates; it needs an even number, at least 2",
                mean_shape.len()
            )));
        }
        let landmarks = mean_shape.len() / 2;
        if landmarks as u64 > MAX_LANDMARKS {
            return Err(r.error(format!("{landmarks} landmarks is not a plausible model")));
        }
        let level_count = r.length("the number of cascade levels", MAX_LEVELS)?;
        let mut forests = Vec::with_capacity(level_count);
        for _ in 0..level_count {
            let tree_count = r.length("the number of trees in a level", MAX_TREES)?;
            let mut trees = Vec::with_capacity(tree_count);
            for _ in 0..tree_count {
                trees.push(read_tree(&mut r, 2 * landmarks)?);
            }
            forests.push(trees);
        }
        let anchors = read_anchor_sets(&mut r, landmarks)?;
        let offsets = read_offset_sets(&mut r)?;
        if r.remaining() != 0 {
            return Err(r.error(format!(
                "{} bytes follow the model; the file is not one shape_predictor",
                r.remaining()
            )));
        }
        let levels = checked_levels(&r, forests, anchors, offsets)?;
        if !mean_shape.iter().all(|v| v.is_finite()) {
            return Err(r.error("the mean shape has a non-finite coordinate"));
        }
        Ok(Self { mean_shape, levels })
    }

    /// A predictor with no cascade: it places `mean_shape` (box coordinates) in the box as it is.
    pub fn from_mean_shape(mean_shape: Landmarks) -> Self {
        Self {
            mean_shape: mean_shape.into_iter().flatten().collect(),
            levels: Vec::new(),
        }
    }

    /// The number of landmarks the model places.
    pub fn landmark_count(&self) -> usize {
        self.mean_shape.len() / 2
    }

    /// The mean shape in box coordinates ([0, 1]² spans the face box).
    pub fn mean_shape(&self) -> Landmarks {
        self.mean_shape
            .chunks_exact(2)
            .map(|p| [p[0], p[1]])
            .collect()
    }

    /// The landmarks of the face in `face_box`, as dlib's `shape_predictor::operator()` places
    /// them. The box follows dlib's convention: box coordinate (0, 0) is pixel (x, y) and (1, 1)
    /// is pixel (x + width − 1, y + height − 1).
    pub fn predict(&self, frame: &GrayImage, face_box: &FaceRect) -> Result<Landmarks, FaceError> {
        let valid = [face_box.x, face_box.y, face_box.width, face_box.height]
            .iter()
            .all(|v| v.is_finite())
            && face_box.width >= 2.0
            && face_box.height >= 2.0;
        if !valid {
            return Err(FaceError::InvalidInput(format!(
                "a landmark box needs a finite position and a size of at least 2x2 pixels, got {face_box:?}"
            )));
        }
        // In f64, as dlib's point_transform_affine: pixel rounding then matches dlib's.
        let to_frame = |p: [f32; 2]| {
            [
                face_box.x as f64 + p[0] as f64 * (face_box.width as f64 - 1.0),
                face_box.y as f64 + p[1] as f64 * (face_box.height as f64 - 1.0),
            ]
        };
        let mut shape = self.mean_shape.clone();
        let mut pixels = Vec::new();
        for level in &self.levels {
            // The mean shape's offsets turn and scale with the current shape (in box coordinates).
            let m = similarity(&self.mean_shape, &shape);
            pixels.clear();
            pixels.extend(level.anchors.iter().zip(&level.offsets).map(|(&a, d)| {
                let a = a as usize;
                let p = [
                    m[0][0] * d[0] + m[0][1] * d[1] + shape[2 * a],
                    m[1][0] * d[0] + m[1][1] * d[1] + shape[2 * a + 1],
                ];
                let [x, y] = to_frame(p);
                // dlib rounds to the nearest pixel and reads 0 outside the image.
                let (x, y) = ((x + 0.5).floor(), (y + 0.5).floor());
                if x >= 0.0 && y >= 0.0 && x < frame.width as f64 && y < frame.height as f64 {
                    f32::from(frame.data[y as usize * frame.width as usize + x as usize])
                } else {
                    0.0
                }
            }));
            for tree in &level.trees {
                let increment = tree.leaf(&pixels, shape.len());
                for (s, d) in shape.iter_mut().zip(increment) {
                    *s += d;
                }
            }
        }
        Ok(shape
            .chunks_exact(2)
            .map(|p| to_frame([p[0], p[1]]).map(|c| c as f32))
            .collect())
    }

    /// Landmarks from a face detector's box, whatever its framing: a first fit in `face_box`,
    /// then a second in the box where the mean shape best matches that fit (a similarity fit of
    /// the mean shape, reduced to its scale and shift). The second pass starts the cascade the
    /// way it was trained, so a detector that frames faces differently from dlib's (a Haar
    /// cascade's box is larger and starts higher) still gets the predictor's accuracy.
    pub fn fit(&self, frame: &GrayImage, face_box: &FaceRect) -> Result<Landmarks, FaceError> {
        let first = self.predict(frame, face_box)?;
        let refined = self.box_for(&first);
        self.predict(frame, &refined)
    }

    /// The box in which the mean shape lies closest to `landmarks` (least squares over scale
    /// and shift; the box stays square in the mean shape's proportions).
    pub fn box_for(&self, landmarks: &[[f32; 2]]) -> FaceRect {
        let mean = self.mean_shape();
        let n = mean.len().min(landmarks.len()).max(1) as f32;
        let centroid = |pts: &[[f32; 2]]| {
            let s = pts
                .iter()
                .fold([0.0f32; 2], |a, p| [a[0] + p[0], a[1] + p[1]]);
            [s[0] / n, s[1] / n]
        };
        let (cm, cl) = (centroid(&mean), centroid(landmarks));
        let (mut num, mut den) = (0.0f32, 0.0f32);
        for (m, l) in mean.iter().zip(landmarks) {
            let (dm, dl) = ([m[0] - cm[0], m[1] - cm[1]], [l[0] - cl[0], l[1] - cl[1]]);
            num += dm[0] * dl[0] + dm[1] * dl[1];
            den += dm[0] * dm[0] + dm[1] * dm[1];
        }
        // landmark ≈ box origin + scale · mean (scale = box side − 1 in dlib's convention).
        let scale = if den > 0.0 { num / den } else { 1.0 };
        FaceRect {
            x: cl[0] - scale * cm[0],
            y: cl[1] - scale * cm[1],
            width: scale + 1.0,
            height: scale + 1.0,
        }
    }
}

impl RegressionTree {
    /// The shape increment of the leaf that `pixels` lead to.
    fn leaf(&self, pixels: &[f32], dims: usize) -> &[f32] {
        let mut node = 0;
        while node < self.splits.len() {
            let s = self.splits[node];
            node = if pixels[s.a as usize] - pixels[s.b as usize] > s.threshold {
                2 * node + 1
            } else {
                2 * node + 2
            };
        }
        let leaf = node - self.splits.len();
        &self.increments[leaf * dims..(leaf + 1) * dims]
    }
}

/// Each cascade level's feature pixels: the landmark each is anchored to (of `landmarks`).
fn read_anchor_sets(r: &mut Reader<'_>, landmarks: usize) -> Result<Vec<Vec<u32>>, FormatError> {
    let anchor_sets = r.length("the number of anchor sets", MAX_LEVELS)?;
    let mut anchors = Vec::with_capacity(anchor_sets);
    for _ in 0..anchor_sets {
        let n = r.length("the number of feature pixels", MAX_PIXELS)?;
        let set = (0..n)
            .map(|_| {
                let at = r.error("");
                let i = r.unsigned("an anchor landmark")?;
                if i >= landmarks as u64 {
                    return Err(FormatError {
                        message: format!("anchor landmark {i} of a {landmarks}-point model"),
                        ..at
                    });
                }
                Ok(i as u32)
            })
            .collect::<Result<Vec<_>, _>>()?;
        anchors.push(set);
    }
    Ok(anchors)
}

/// Each cascade level's feature pixels' offsets from their anchors.
fn read_offset_sets(r: &mut Reader<'_>) -> Result<Vec<Vec<[f32; 2]>>, FormatError> {
    let offset_sets = r.length("the number of offset sets", MAX_LEVELS)?;
    let mut offsets = Vec::with_capacity(offset_sets);
    for _ in 0..offset_sets {
        let n = r.length("the number of feature pixels", MAX_PIXELS)?;
        let set = (0..n)
            .map(|_| Ok([r.float("an offset")?, r.float("an offset")?]))
            .collect::<Result<Vec<_>, FormatError>>()?;
        offsets.push(set);
    }
    Ok(offsets)
}

/// The cascade's levels from their forests, anchors and offsets, checked against each other:
/// as many of each, and every split reading a feature pixel the level has.
fn checked_levels(
    r: &Reader<'_>,
    forests: Vec<Vec<RegressionTree>>,
    anchors: Vec<Vec<u32>>,
    offsets: Vec<Vec<[f32; 2]>>,
) -> Result<Vec<CascadeLevel>, FormatError> {
    let level_count = forests.len();
    if anchors.len() != level_count || offsets.len() != level_count {
        return Err(r.error(format!(
            "{level_count} cascade levels but {} anchor sets and {} offset sets",
            anchors.len(),
            offsets.len()
        )));
    }
    let mut levels = Vec::with_capacity(level_count);
    for (k, ((trees, anchors), offsets)) in
        forests.into_iter().zip(anchors).zip(offsets).enumerate()
    {
        let pixels = anchors.len();
        if offsets.len() != pixels {
            return Err(r.error(format!(
                "level {k} has {pixels} anchors but {} offsets",
                offsets.len()
            )));
        }
        let out_of_range = trees
            .iter()
            .flat_map(|t| &t.splits)
            .any(|s| s.a as usize >= pixels || s.b as usize >= pixels);
        if out_of_range {
            return Err(r.error(format!(
                "a split in level {k} reads a feature pixel beyond its {pixels}"
            )));
        }
        levels.push(CascadeLevel {
            anchors,
            offsets,
            trees,
        });
    }
    Ok(levels)
}

fn read_tree(r: &mut Reader<'_>, dims: usize) -> Result<RegressionTree, FormatError> {
    let split_count = r.length("the number of splits", MAX_PIXELS)?;
    let mut splits = Vec::with_capacity(split_count);
    for _ in 0..split_count {
        let a = r.unsigned("a split's first pixel")?;
        let b = r.unsigned("a split's second pixel")?;
        let threshold = r.float("a split's threshold")?;
        let fits = |i: u64| u32::try_from(i).is_ok();
        if !(fits(a) && fits(b)) {
            return Err(r.error("a split's pixel index is out of range"));
        }
        splits.push(Split {
            a: a as u32,
            b: b as u32,
            threshold,
        });
    }
    let leaf_count = r.length("the number of leaves", MAX_PIXELS + 1)?;
    // A complete binary tree with s splits has s + 1 leaves; `leaf` relies on it.
    if leaf_count != split_count + 1 {
        return Err(r.error(format!(
            "a tree with {split_count} splits has {leaf_count} leaves; a complete tree has {}",
            split_count + 1
        )));
    }
    let mut increments = Vec::with_capacity(leaf_count * dims);
    for _ in 0..leaf_count {
        let leaf = r.float_column("a leaf's shape increment")?;
        if leaf.len() != dims {
            return Err(r.error(format!(
                "a leaf moves {} coordinates; the mean shape has {dims}",
                leaf.len()
            )));
        }
        increments.extend(leaf);
    }
    Ok(RegressionTree { splits, increments })
}

/// The 2×2 part (scale and rotation) of the least-squares similarity that takes shape `from` to
/// shape `to` (both flattened x, y pairs), as dlib's `find_tform_between_shapes`: in 2-D the
/// Umeyama solution is the complex ratio Σ conj(a)·b / Σ |a|² of the centred points.
pub(crate) fn similarity(from: &[f32], to: &[f32]) -> [[f32; 2]; 2] {
    let n = (from.len() / 2) as f64;
    if n < 2.0 {
        return [[1.0, 0.0], [0.0, 1.0]];
    }
    let mean = |s: &[f32]| {
        let (mut x, mut y) = (0.0f64, 0.0f64);
        for p in s.chunks_exact(2) {
            x += p[0] as f64;
            y += p[1] as f64;
        }
        (x / n, y / n)
    };
    let (fx, fy) = mean(from);
    let (tx, ty) = mean(to);
    let (mut re, mut im, mut norm) = (0.0f64, 0.0f64, 0.0f64);
    for (a, b) in from.chunks_exact(2).zip(to.chunks_exact(2)) {
        let (ax, ay) = (a[0] as f64 - fx, a[1] as f64 - fy);
        let (bx, by) = (b[0] as f64 - tx, b[1] as f64 - ty);
        re += ax * bx + ay * by;
        im += ax * by - ay * bx;
        norm += ax * ax + ay * ay;
    }
    if norm <= 0.0 {
        return [[1.0, 0.0], [0.0, 1.0]];
    }
    let (c, s) = ((re / norm) as f32, (im / norm) as f32);
    [[c, -s], [s, c]]
}

#[cfg(test)]
mod tests {
    use super::dlib_format::{pack, pack_float};
    use super::*;

    /// A two-landmark model with one level and one tree of one split: pixel 0 (at landmark 0)
    /// brighter than pixel 1 (at landmark 1) by more than 10 moves both landmarks +0.125 in x,
    /// otherwise −0.125.
    fn tiny_model(leaves: usize) -> Vec<u8> {
        let column = |values: &[f32]| {
            let mut out = pack(-(values.len() as i64));
            out.extend(pack(-1));
            for &v in values {
                out.extend(pack_float(v));
            }
            out
        };
        let mut b = pack(1); // version
        b.extend(column(&[0.25, 0.5, 0.75, 0.5]));
        b.extend(pack(1)); // levels
        b.extend(pack(1)); // trees in the level
        b.extend(pack(1)); // splits
        b.extend(pack(0));
        b.extend(pack(1));
        b.extend(pack_float(10.0));
        b.extend(pack(leaves as i64));
        for k in 0..leaves {
            let dx = if k == 0 { 0.125 } else { -0.125 };
            b.extend(column(&[dx, 0.0, dx, 0.0]));
        }
        b.extend(pack(1)); // anchor sets
        b.extend(pack(2));
        b.extend(pack(0));
        b.extend(pack(1));
        b.extend(pack(1)); // offset sets
        b.extend(pack(2));
        for _ in 0..4 {
            b.extend(pack_float(0.0));
        }
        b
    }

    /// An 11x11 frame, `left` on the left half and `right` on the right.
    fn halves(left: u8, right: u8) -> GrayImage {
        let data = (0..121)
            .map(|k| if k % 11 < 5 { left } else { right })
            .collect();
        GrayImage::new(11, 11, data).unwrap()
    }

    #[test]
    fn a_hand_built_model_moves_its_landmarks_by_the_leaf_its_pixels_choose() {
        let model = ShapePredictor::from_bytes(&tiny_model(2)).unwrap();
        assert_eq!(model.landmark_count(), 2);
        let full = FaceRect {
            x: 0.0,
            y: 0.0,
            width: 11.0,
            height: 11.0,
        };
        // Landmark 0 reads pixel (2.5→3, 5), landmark 1 pixel (7.5→8, 5).
        let bright_left = model.predict(&halves(200, 0), &full).unwrap();
        assert_eq!(bright_left, vec![[3.75, 5.0], [8.75, 5.0]]);
        let dark_left = model.predict(&halves(0, 200), &full).unwrap();
        assert_eq!(dark_left, vec![[1.25, 5.0], [6.25, 5.0]]);
        // A box partly outside the frame reads 0 there instead of failing: landmark 0 falls
        // outside (0), landmark 1 on the bright column 0 (200), so the other leaf.
        let shifted = FaceRect { x: -8.0, ..full };
        let outside = model.predict(&halves(200, 0), &shifted).unwrap();
        assert_eq!(outside, vec![[-6.75, 5.0], [-1.75, 5.0]]);
        let bad_box = FaceRect {
            width: f32::NAN,
            ..full
        };
        assert!(model.predict(&halves(0, 0), &bad_box).is_err());
    }

    #[test]
    fn broken_model_files_are_errors_that_say_why() {
        let good = tiny_model(2);
        for cut in [0, 1, 5, good.len() / 2, good.len() - 1] {
            let e = ShapePredictor::from_bytes(&good[..cut]).unwrap_err();
            assert!(e.message.contains("ends"), "cut at {cut}: {e}");
        }
        let mut trailing = good.clone();
        trailing.push(0);
        let e = ShapePredictor::from_bytes(&trailing).unwrap_err();
        assert!(e.message.contains("follow the model"), "{e}");
        let e = ShapePredictor::from_bytes(&tiny_model(3)).unwrap_err();
        assert!(e.message.contains("a complete tree has 2"), "{e}");
        let e = ShapePredictor::from_bytes(b"<?xml version=\"1.0\"?>").unwrap_err();
        assert!(e.message.contains("not a dlib integer header"), "{e}");
        let dir = std::env::temp_dir().join(format!("streampf-dlib-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("half.dat");
        std::fs::write(&path, &good[..good.len() / 2]).unwrap();
        let e = ShapePredictor::load(&path).unwrap_err().to_string();
        assert!(
            e.contains("half.dat") && e.contains("not a dlib shape_predictor"),
            "{e}"
        );
        let e = ShapePredictor::load(&dir.join("missing.dat"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("missing.dat") && e.contains("cannot read"),
            "{e}"
        );
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn the_similarity_of_a_turned_scaled_shifted_shape_is_recovered() {
        let from = [0.0f32, 0.0, 1.0, 0.0, 0.0, 2.0, 3.0, 1.0];
        let (angle, scale) = (0.3f32, 1.7f32);
        let (c, s) = (scale * angle.cos(), scale * angle.sin());
        let to: Vec<f32> = from
            .chunks_exact(2)
            .flat_map(|p| [c * p[0] - s * p[1] + 5.0, s * p[0] + c * p[1] - 2.0])
            .collect();
        let m = similarity(&from, &to);
        for (got, want) in [m[0][0], m[0][1], m[1][0], m[1][1]]
            .iter()
            .zip([c, -s, s, c])
        {
            assert!((got - want).abs() < 1e-5, "{m:?}");
        }
    }
}
