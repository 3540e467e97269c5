//! The personalised face model: the generic head warped onto one person's face.
//!
//! As in the paper (which fits an AAM), each new face's landmarks are fitted (here with dlib's
//! 68-point shape predictor, [`crate::landmarks`]) and the generic model's heightmap and normalmap
//! are warped piecewise-affinely so that the generic head's landmarks land on the person's: the
//! nose's relief sits under this person's nose, the brow ridge under their brows, and the head is
//! as wide as their jaw. Template points then take person-specific depths and normals.
//!
//! The generic head's own landmarks ([`Personaliser::generic_landmarks`]) are dlib's mean shape,
//! placed on the generic model by the two features the model names: the nose tip and the brow
//! ridge, in the proportions of the tracker's face rectangle (1.25 times as tall as wide), so a
//! mean face has equal scales across and down. Eight points on a square around the model (at
//! ±[`BORDER`]) close the triangulation; they move with the similarity (turn, scale, shift) that
//! best takes the generic landmarks to the fitted ones, so a tilted face turns the whole model and
//! the thin triangles out to the border never fold.

use std::sync::Arc;

use crate::error::FaceError;
use crate::extraction::FaceRect;
use crate::image::GrayImage;
use crate::landmarks::{Landmarks, ShapePredictor, ibug68, similarity};
use crate::lens::Lens;
use crate::model::{BROW_RIDGE_V, FaceModel, NOSE_TIP_V};
use crate::synth::HEIGHT_RATIO;
use crate::view::View;

/// Half the side of the square of fixed border points, in model units (the model spans ±1).
pub const BORDER: f32 = 3.0;

/// The landmarks the warp follows: the jaw, brows and nose, and only the corners of the eyes and
/// the corners and middles of the outer lips. Eyelids and inner lips open and close (a closed
/// mouth puts its inner points on top of each other), which would fold triangles between them,
/// and they carry no depth the model has.
const WARP_LANDMARKS: [usize; 44] = [
    0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, // jaw
    17, 18, 19, 20, 21, 22, 23, 24, 25, 26, // brows
    27, 28, 29, 30, 31, 32, 33, 34, 35, // nose
    36, 39, 42, 45, // eye corners
    48, 51, 54, 57, // mouth corners, top and bottom of the outer lips
];

/// A triangle whose area changes by more than this factor (or turns over) means the landmark fit
/// went wrong: the warp would fold or tear the head.
const MAX_AREA_CHANGE: f32 = 8.0;

/// Fits landmarks and warps the face model onto them.
#[derive(Debug, Clone)]
pub struct Personaliser {
    predictor: Arc<ShapePredictor>,
    /// The generic head's 68 landmarks in model coordinates.
    generic_landmarks: Vec<[f32; 2]>,
    /// The warp's vertices: the generic [`WARP_LANDMARKS`], then the border points.
    generic: Vec<[f32; 2]>,
    /// Triangles over `generic` (vertex indices), counter-clockwise.
    triangles: Vec<[usize; 3]>,
}

/// One face's personalisation.
#[derive(Debug, Clone)]
pub struct Personalised {
    /// The fitted landmarks, frame pixels.
    pub landmarks: Landmarks,
    /// The warped model (model coordinates over the face rectangle, as the generic one).
    pub model: FaceModel,
}

impl Personaliser {
    /// A personaliser for a 68-point (iBUG) landmark model such as dlib's.
    pub fn new(predictor: Arc<ShapePredictor>) -> Result<Self, FaceError> {
        if predictor.landmark_count() != ibug68::COUNT {
            return Err(FaceError::InvalidInput(format!(
                "the face model is warped by the 68 iBUG landmarks; this landmark model places {}",
                predictor.landmark_count()
            )));
        }
        let generic_landmarks = generic_landmarks(&predictor.mean_shape())?;
        let generic: Vec<[f32; 2]> = WARP_LANDMARKS
            .iter()
            .map(|&k| generic_landmarks[k])
            .chain(border_points())
            .collect();
        let points: Vec<delaunator::Point> = generic
            .iter()
            .map(|p| delaunator::Point {
                x: p[0] as f64,
                y: p[1] as f64,
            })
            .collect();
        let triangles = delaunator::triangulate(&points)
            .triangles
            .chunks_exact(3)
            .map(|t| [t[0], t[1], t[2]])
            .collect();
        Ok(Self {
            predictor,
            generic_landmarks,
            generic,
            triangles,
        })
    }

    /// The generic head's 68 landmarks in model coordinates.
    pub fn generic_landmarks(&self) -> &[[f32; 2]] {
        &self.generic_landmarks
    }

    /// The warp's vertices in the generic head (model coordinates): the landmarks it follows,
    /// then the eight border points.
    pub fn warp_vertices(&self) -> &[[f32; 2]] {
        &self.generic
    }

    /// The triangulation the warp is piecewise affine over (indices into [`Self::warp_vertices`]).
    pub fn triangles(&self) -> &[[usize; 3]] {
        &self.triangles
    }

    pub fn predictor(&self) -> &ShapePredictor {
        &self.predictor
    }

    /// Fits the landmarks of the face in `rect` (a tracker face rectangle; the landmark box is
    /// the square of its height around its centre, the detector's box) and warps `model` onto
    /// them.
    pub fn personalise(
        &self,
        frame: &GrayImage,
        rect: &FaceRect,
        model: &FaceModel,
    ) -> Result<Personalised, FaceError> {
        self.personalise_seen(frame, rect, model, &View::frontal(), &Lens::WEAK)
    }

    /// [`Self::personalise`] for a face seen with `view` (a track that restarts turned): each
    /// fitted landmark is cast onto `model` turned by the view, so the warp moves the model's
    /// landmarks to where the turned face has them, not to where they appear in the frame;
    /// through `lens`, as the camera shows them.
    pub fn personalise_seen(
        &self,
        frame: &GrayImage,
        rect: &FaceRect,
        model: &FaceModel,
        view: &View,
        lens: &Lens,
    ) -> Result<Personalised, FaceError> {
        let (cx, cy) = rect.centre();
        let side = rect.height;
        let face_box = FaceRect {
            x: cx - side / 2.0,
            y: cy - side / 2.0,
            width: side,
            height: side,
        };
        let landmarks = self.predictor.fit(frame, &face_box)?;
        let (hw, hh) = (rect.width / 2.0, rect.height / 2.0);
        // A landmark whose ray misses the model (always, seen frontally, for one outside the
        // rectangle such as a jaw's end) keeps its frontal coordinates: the warp's own checks
        // judge it.
        let in_model: Vec<[f32; 2]> = (landmarks.iter())
            .map(|p| {
                let offset = [p[0] - cx, p[1] - cy];
                let cast = view.unproject_through(lens, [cx, cy], model, (hw, hh), offset);
                cast.map_or([offset[0] / hw, offset[1] / hh], |(u, v)| [u, v])
            })
            .collect();
        let model = self.warp(model, &in_model)?;
        Ok(Personalised { landmarks, model })
    }

    /// `model` warped so that the generic landmarks move to `fitted` (model coordinates): the
    /// warped model at p is the generic one at W(p), W piecewise affine taking each fitted
    /// triangle to its generic one. Heights are carried over; normals are turned by W's linear
    /// part (a surface h(W(p)) has gradient Aᵀ∇h), so loaded normalmaps keep their detail.
    pub fn warp(&self, model: &FaceModel, fitted: &[[f32; 2]]) -> Result<FaceModel, FaceError> {
        check_fitted(fitted)?;
        let (turn, shift) = self.similarity_to(fitted);
        let moved: Vec<[f32; 2]> = WARP_LANDMARKS
            .iter()
            .map(|&k| fitted[k])
            .chain(border_points().map(|b| {
                [
                    turn[0][0] * b[0] + turn[0][1] * b[1] + shift[0],
                    turn[1][0] * b[0] + turn[1][1] * b[1] + shift[1],
                ]
            }))
            .collect();
        let size = model.size;
        let last = (size - 1) as f32;
        let node = |i: u32| -1.0 + 2.0 * i as f32 / last;
        let mut heights = vec![f32::NAN; (size * size) as usize];
        let mut normals = vec![[0.0f32; 3]; (size * size) as usize];
        for t in &self.triangles {
            let from = t.map(|k| moved[k]);
            let to = t.map(|k| self.generic[k]);
            let (area_from, area_to) = (signed_area(from), signed_area(to));
            let ratio = area_from / area_to;
            if !(ratio > 1.0 / MAX_AREA_CHANGE && ratio < MAX_AREA_CHANGE) {
                return Err(FaceError::InvalidInput(format!(
                    "the fitted landmarks fold or stretch the face model (a triangle's area changes {ratio:.2}x): the fit missed the face"
                )));
            }
            // The affine map from this fitted triangle to its generic one: W(p) = A·p + b.
            let (a, b) = affine_between(from, to);
            let Some((columns, rows)) = grid_box(from, last) else {
                continue;
            };
            for j in rows {
                for i in columns.clone() {
                    let k = (j * size + i) as usize;
                    let p = [node(i), node(j)];
                    if !heights[k].is_nan() || !inside(from, p) {
                        continue;
                    }
                    let w = [
                        a[0][0] * p[0] + a[0][1] * p[1] + b[0],
                        a[1][0] * p[0] + a[1][1] * p[1] + b[1],
                    ];
                    let (h, n) = model.sample(w[0], w[1]);
                    heights[k] = h;
                    normals[k] = turn_normal(n, a);
                }
            }
        }
        if heights.iter().any(|h| h.is_nan()) {
            // Only when the border square, moved with the face, no longer covers the model.
            return Err(FaceError::InvalidInput(
                "the fitted landmarks move the face too far to warp the whole model: the fit missed the face".into(),
            ));
        }
        Ok(FaceModel {
            size,
            heights,
            normals,
        })
    }
}

/// Checks a fit before warping: 68 landmarks, none far outside the face rectangle (which spans
/// ±1; beyond ±2 the fit has surely missed).
fn check_fitted(fitted: &[[f32; 2]]) -> Result<(), FaceError> {
    if fitted.len() != ibug68::COUNT {
        return Err(FaceError::InvalidInput(format!(
            "the warp needs {} landmarks, got {}",
            ibug68::COUNT,
            fitted.len()
        )));
    }
    let limit = 2.0;
    if let Some(p) = fitted
        .iter()
        .find(|p| !(p[0].abs() < limit && p[1].abs() < limit))
    {
        return Err(FaceError::InvalidInput(format!(
            "a fitted landmark lies at {p:?} of the face rectangle (which spans ±1): the fit missed the face"
        )));
    }
    Ok(())
}

/// The grid nodes (columns, rows; `last` the last node's index) in a triangle's bounding box,
/// clipped to the grid; `None` when the box misses the grid.
fn grid_box(
    triangle: [[f32; 2]; 3],
    last: f32,
) -> Option<(std::ops::RangeInclusive<u32>, std::ops::RangeInclusive<u32>)> {
    let to_index = |c: f32| (c + 1.0) / 2.0 * last;
    let lo = |c: f32| to_index(c).ceil().clamp(0.0, last) as u32;
    let hi = |c: f32| to_index(c).floor().clamp(0.0, last) as u32;
    let xs = triangle.map(|p| p[0]);
    let ys = triangle.map(|p| p[1]);
    let (min_x, max_x) = (
        xs.iter().copied().fold(f32::MAX, f32::min),
        xs.iter().copied().fold(f32::MIN, f32::max),
    );
    let (min_y, max_y) = (
        ys.iter().copied().fold(f32::MAX, f32::min),
        ys.iter().copied().fold(f32::MIN, f32::max),
    );
    if max_x < -1.0 || min_x > 1.0 || max_y < -1.0 || min_y > 1.0 {
        return None;
    }
    Some((lo(min_x)..=hi(max_x), lo(min_y)..=hi(max_y)))
}

impl Personaliser {
    /// The least-squares similarity (2×2 part, shift) from the generic warp landmarks to the
    /// fitted ones.
    fn similarity_to(&self, fitted: &[[f32; 2]]) -> ([[f32; 2]; 2], [f32; 2]) {
        let from: Vec<f32> = WARP_LANDMARKS
            .iter()
            .flat_map(|&k| self.generic_landmarks[k])
            .collect();
        let to: Vec<f32> = WARP_LANDMARKS.iter().flat_map(|&k| fitted[k]).collect();
        let m = similarity(&from, &to);
        let mean = |s: &[f32], axis: usize| {
            s.iter().skip(axis).step_by(2).sum::<f32>() / WARP_LANDMARKS.len() as f32
        };
        let (fx, fy, tx, ty) = (mean(&from, 0), mean(&from, 1), mean(&to, 0), mean(&to, 1));
        let shift = [
            tx - (m[0][0] * fx + m[0][1] * fy),
            ty - (m[1][0] * fx + m[1][1] * fy),
        ];
        (m, shift)
    }
}

/// dlib's mean shape (box coordinates) placed on the generic head: the nose tip (landmark 30) on
/// the model's nose tip, the brows' mean height on its brow ridge, and the horizontal scale the
/// vertical one times the face rectangle's height/width ratio (equal scales in pixels).
/// A model file whose mean shape has the nose tip level with or above the brows is not a face's.
fn generic_landmarks(mean: &[[f32; 2]]) -> Result<Vec<[f32; 2]>, FaceError> {
    let tip = mean[ibug68::NOSE_TIP];
    let brow = ibug68::BROWS.map(|k| mean[k][1]).sum::<f32>() / ibug68::BROWS.len() as f32;
    let down = (NOSE_TIP_V - BROW_RIDGE_V) / (tip[1] - brow);
    if !(down.is_finite() && down > 0.0) {
        return Err(FaceError::InvalidInput(format!(
            "the landmark model's mean shape has its nose tip (y = {}) not below its brows (y = {brow}): not a 68-point face model",
            tip[1]
        )));
    }
    let across = down * HEIGHT_RATIO;
    Ok(mean
        .iter()
        .map(|p| {
            [
                (p[0] - tip[0]) * across,
                NOSE_TIP_V + (p[1] - tip[1]) * down,
            ]
        })
        .collect())
}

/// The fixed points: corners and edge midpoints of the square ±[`BORDER`].
fn border_points() -> [[f32; 2]; 8] {
    let b = BORDER;
    [
        [-b, -b],
        [0.0, -b],
        [b, -b],
        [b, 0.0],
        [b, b],
        [0.0, b],
        [-b, b],
        [-b, 0.0],
    ]
}

fn signed_area(t: [[f32; 2]; 3]) -> f32 {
    0.5 * ((t[1][0] - t[0][0]) * (t[2][1] - t[0][1]) - (t[2][0] - t[0][0]) * (t[1][1] - t[0][1]))
}

/// Whether p lies in triangle t (edges included; either orientation).
fn inside(t: [[f32; 2]; 3], p: [f32; 2]) -> bool {
    let edge =
        |a: [f32; 2], b: [f32; 2]| (b[0] - a[0]) * (p[1] - a[1]) - (p[0] - a[0]) * (b[1] - a[1]);
    let (e0, e1, e2) = (edge(t[0], t[1]), edge(t[1], t[2]), edge(t[2], t[0]));
    let eps = 1e-6;
    (e0 >= -eps && e1 >= -eps && e2 >= -eps) || (e0 <= eps && e1 <= eps && e2 <= eps)
}

/// The affine map (A, b) with A·from[k] + b = to[k] for the three vertices.
fn affine_between(from: [[f32; 2]; 3], to: [[f32; 2]; 3]) -> ([[f32; 2]; 2], [f32; 2]) {
    let f = nalgebra::Matrix2::new(
        from[1][0] - from[0][0],
        from[2][0] - from[0][0],
        from[1][1] - from[0][1],
        from[2][1] - from[0][1],
    );
    let t = nalgebra::Matrix2::new(
        to[1][0] - to[0][0],
        to[2][0] - to[0][0],
        to[1][1] - to[0][1],
        to[2][1] - to[0][1],
    );
    // The area check before the call keeps `f` invertible.
    let a = t * f.try_inverse().unwrap_or_else(nalgebra::Matrix2::identity);
    let b = [
        to[0][0] - (a[(0, 0)] * from[0][0] + a[(0, 1)] * from[0][1]),
        to[0][1] - (a[(1, 0)] * from[0][0] + a[(1, 1)] * from[0][1]),
    ];
    ([[a[(0, 0)], a[(0, 1)]], [a[(1, 0)], a[(1, 1)]]], b)
}

/// The normal of h(A·p + b) from the normal n of h: gradient g = (−n_x, −n_y)/n_z becomes Aᵀg.
fn turn_normal(n: [f32; 3], a: [[f32; 2]; 2]) -> [f32; 3] {
    let nz = n[2].max(1e-3);
    let g = [-n[0] / nz, -n[1] / nz];
    let turned = [
        a[0][0] * g[0] + a[1][0] * g[1],
        a[0][1] * g[0] + a[1][1] * g[1],
    ];
    let m = [-turned[0], -turned[1], 1.0];
    let len = (m[0] * m[0] + m[1] * m[1] + 1.0f32).sqrt();
    m.map(|c| c / len)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Whether p lies in triangle t at least 1e-4 (in the area's units) from every edge.
    fn well_inside(t: [[f32; 2]; 3], p: [f32; 2]) -> bool {
        let area = signed_area(t);
        let sub = [[p, t[1], t[2]], [t[0], p, t[2]], [t[0], t[1], p]];
        sub.iter().all(|s| signed_area(*s) / area > 1e-4)
    }

    /// A personaliser over a made-up 68-point mean shape (a jittered grid in the unit box), so
    /// the warp is tested without dlib's model file.
    fn personaliser() -> Personaliser {
        let mut mean: Vec<[f32; 2]> = (0..68)
            .map(|k| {
                let (i, j) = ((k % 9) as f32, (k / 9) as f32);
                let jitter = ((k * 7919) % 13) as f32 / 13.0 - 0.5;
                [
                    0.1 + 0.1 * i + 0.02 * jitter,
                    0.1 + 0.1 * j - 0.015 * jitter,
                ]
            })
            .collect();
        mean[ibug68::NOSE_TIP] = [0.5, 0.55];
        Personaliser::new(Arc::new(ShapePredictor::from_mean_shape(mean))).unwrap()
    }

    #[test]
    fn warping_onto_the_generic_landmarks_changes_nothing() {
        let p = personaliser();
        let model = FaceModel::generic(33).unwrap();
        let same = p.warp(&model, p.generic_landmarks()).unwrap();
        for (a, b) in same.heights.iter().zip(&model.heights) {
            assert!((a - b).abs() < 1e-4, "{a} vs {b}");
        }
        for (a, b) in same.normals.iter().zip(&model.normals) {
            let dot: f32 = a.iter().zip(b).map(|(x, y)| x * y).sum();
            assert!(dot > 0.9999, "{a:?} vs {b:?}");
        }
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(24))]

        /// Landmarks moved by one affine map T: inside the fitted landmarks' hull the warped
        /// model is the generic one pulled back through T (heights), with normals turned by
        /// T⁻¹'s linear part.
        #[test]
        fn an_affine_move_of_all_landmarks_warps_the_model_by_that_map(
            scale_u in 0.7f32..1.3, scale_v in 0.7f32..1.3, shear in -0.2f32..0.2,
            angle in -0.3f32..0.3, shift_u in -0.2f32..0.2, shift_v in -0.2f32..0.2,
        ) {
            let p = personaliser();
            let model = FaceModel::generic(33).unwrap();
            let (c, s) = (angle.cos(), angle.sin());
            let t = nalgebra::Matrix2::new(c, -s, s, c) * nalgebra::Matrix2::new(scale_u, shear, 0.0, scale_v);
            let shift = nalgebra::Vector2::new(shift_u, shift_v);
            let to_fitted = |q: [f32; 2]| t * nalgebra::Vector2::new(q[0], q[1]) + shift;
            let fitted: Vec<[f32; 2]> = p.generic_landmarks().iter().map(|&q| { let f = to_fitted(q); [f[0], f[1]] }).collect();
            // A landmark moved beyond twice the face rectangle: the warp refuses the fit as one
            // that missed the face (its guard), which is all there is to check.
            if fitted.iter().any(|f| !(f[0].abs() < 2.0 && f[1].abs() < 2.0)) {
                proptest::prop_assert!(p.warp(&model, &fitted).is_err());
                return Ok(());
            }
            let warped = p.warp(&model, &fitted).unwrap();
            let back = t.try_inverse().unwrap();
            let a = [[back[(0, 0)], back[(0, 1)]], [back[(1, 0)], back[(1, 1)]]];
            // Nodes whose generic point lies in a triangle of landmarks only (not of the border,
            // which moves by a similarity, not by T), and not on its edges: a node on an edge
            // the triangle shares with a border triangle may have been warped by that one, whose
            // heights agree on the edge but whose Jacobian (so the normal) does not.
            let vertices = p.warp_vertices();
            let inner_triangles: Vec<[[f32; 2]; 3]> = p.triangles().iter()
                .filter(|t| t.iter().all(|&k| k < WARP_LANDMARKS.len()))
                .map(|t| t.map(|k| vertices[k]))
                .collect();
            let mut checked = 0;
            for j in 0..33u32 {
                for i in 0..33u32 {
                    let q = [-1.0 + 2.0 * i as f32 / 32.0, -1.0 + 2.0 * j as f32 / 32.0];
                    let pulled = back * (nalgebra::Vector2::new(q[0], q[1]) - shift);
                    let inner = inner_triangles.iter().any(|&t| well_inside(t, [pulled[0], pulled[1]]));
                    if !inner {
                        continue;
                    }
                    let k = (j * 33 + i) as usize;
                    let (h, n) = model.sample(pulled[0], pulled[1]);
                    proptest::prop_assert!((warped.heights[k] - h).abs() < 3e-3, "node {q:?}: {} vs {h}", warped.heights[k]);
                    let want = turn_normal(n, a);
                    let dot: f32 = warped.normals[k].iter().zip(want).map(|(x, y)| x * y).sum();
                    proptest::prop_assert!(dot > 0.999, "node {q:?}: {:?} vs {want:?}", warped.normals[k]);
                    checked += 1;
                }
            }
            proptest::prop_assert!(checked > 20, "only {checked} nodes inside");
        }
    }

    #[test]
    fn a_model_whose_mean_shape_is_not_a_face_is_refused() {
        let upside_down = vec![[0.5f32, 0.5]; 68];
        let e = Personaliser::new(Arc::new(ShapePredictor::from_mean_shape(upside_down)))
            .unwrap_err()
            .to_string();
        assert!(e.contains("not a 68-point face model"), "{e}");
        let e = Personaliser::new(Arc::new(ShapePredictor::from_mean_shape(vec![
            [0.5, 0.5];
            5
        ])))
        .unwrap_err()
        .to_string();
        assert!(e.contains("places 5"), "{e}");
    }

    #[test]
    fn landmarks_that_fold_the_face_or_leave_it_are_refused() {
        let p = personaliser();
        let model = FaceModel::generic(17).unwrap();
        let mut swapped = p.generic_landmarks().to_vec();
        swapped.swap(0, 16);
        let e = p.warp(&model, &swapped).unwrap_err().to_string();
        assert!(e.contains("fold or stretch"), "{e}");
        let mut far = p.generic_landmarks().to_vec();
        far[8] = [0.0, 5.0];
        let e = p.warp(&model, &far).unwrap_err().to_string();
        assert!(e.contains("missed the face"), "{e}");
        assert!(p.warp(&model, &far[..10]).is_err());
        let mut nan = p.generic_landmarks().to_vec();
        nan[3] = [f32::NAN, 0.0];
        assert!(p.warp(&model, &nan).is_err());
    }
}
