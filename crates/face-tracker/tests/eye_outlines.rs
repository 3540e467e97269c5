//! Where a template leaves the eyes out: the point-in-outline test on random polygons, the eyes'
//! outlines grown about their centres, and a template that takes no point inside an outline it
//! is told to avoid (and does take one there when it is not).

use face_tracker::GrayImage;
use face_tracker::extraction::{
    ExtractionConfig, FaceRect, Outline, extract_template_seen, eye_outlines, inside_outline,
};
use face_tracker::landmarks::ibug68;
use face_tracker::model::FaceModel;
use face_tracker::view::View;
use proptest::prelude::*;
use std::f32::consts::TAU;

/// A regular polygon of `sides` vertices on the circle of `radius` about `centre`.
fn regular(sides: usize, centre: [f32; 2], radius: f32, turn: f32) -> Outline {
    (0..sides)
        .map(|k| {
            let a = turn + TAU * k as f32 / sides as f32;
            [centre[0] + radius * a.cos(), centre[1] + radius * a.sin()]
        })
        .collect()
}

proptest! {
    /// Inside the polygon's inscribed circle is inside, outside its circumscribed circle is
    /// outside, whichever way round its vertices go.
    #[test]
    fn a_point_is_inside_a_regular_polygon_exactly_when_it_should_be(
        sides in 3usize..13,
        cx in -500.0f32..500.0,
        cy in -500.0f32..500.0,
        radius in 0.5f32..200.0,
        turn in 0.0f32..TAU,
        angle in 0.0f32..TAU,
        reach in 0.0f32..3.0,
        reversed in any::<bool>(),
    ) {
        let mut outline = regular(sides, [cx, cy], radius, turn);
        if reversed {
            outline.reverse();
        }
        let inscribed = radius * (std::f32::consts::PI / sides as f32).cos();
        let d = reach * radius;
        let (x, y) = (cx + d * angle.cos(), cy + d * angle.sin());
        if d < 0.99 * inscribed {
            prop_assert!(inside_outline(&outline, x, y), "({x}, {y}) at {d} of {radius}");
        } else if d > 1.01 * radius {
            prop_assert!(!inside_outline(&outline, x, y), "({x}, {y}) at {d} of {radius}");
        }
    }

    /// Each eye's outline is its six landmarks moved away from their mean by the growth factor;
    /// a set that is not 68 landmarks gives no outline at all.
    #[test]
    fn eye_outlines_are_the_eyes_landmarks_grown_about_their_centre(
        landmarks in proptest::collection::vec((0.0f32..1000.0, 0.0f32..1000.0), 68),
        growth in 0.5f32..3.0,
        wrong in 0usize..68,
    ) {
        let landmarks: Vec<[f32; 2]> = landmarks.into_iter().map(|(x, y)| [x, y]).collect();
        let outlines = eye_outlines(&landmarks, growth);
        prop_assert_eq!(outlines.len(), 2);
        for (outline, eye) in outlines.iter().zip([ibug68::RIGHT_EYE, ibug68::LEFT_EYE]) {
            let own = &landmarks[eye];
            prop_assert_eq!(outline.len(), 6);
            let centre = |ps: &[[f32; 2]]| {
                let n = ps.len() as f32;
                ps.iter().fold([0.0, 0.0], |c, p| [c[0] + p[0] / n, c[1] + p[1] / n])
            };
            let c = centre(own);
            for (grown, p) in outline.iter().zip(own) {
                for k in 0..2 {
                    let want = c[k] + growth * (p[k] - c[k]);
                    prop_assert!((grown[k] - want).abs() < 1e-2, "{grown:?} vs {want}");
                }
            }
            let g = centre(outline);
            prop_assert!((g[0] - c[0]).abs() < 1e-2 && (g[1] - c[1]).abs() < 1e-2);
        }
        prop_assert!(eye_outlines(&landmarks[..wrong], growth).is_empty());
    }
}

/// Gaussian blobs (centre x, centre y, amplitude) on mid gray, 120×120.
fn blob_image(blobs: &[(f32, f32, f32)]) -> GrayImage {
    let (w, h) = (120u32, 120u32);
    let data: Vec<f32> = (0..w * h)
        .map(|k| {
            let (x, y) = ((k % w) as f32, (k / w) as f32);
            128.0
                + blobs
                    .iter()
                    .map(|&(bx, by, a)| a * (-((x - bx).powi(2) + (y - by).powi(2)) / 8.0).exp())
                    .sum::<f32>()
        })
        .collect();
    GrayImage::from_levels(w, h, &data).unwrap()
}

#[test]
fn a_template_takes_no_point_inside_an_outline_it_avoids() {
    // The strongest blob sits where an eye would be; three weaker ones elsewhere.
    let blobs = [
        (45.0, 50.0, -110.0),
        (70.0, 60.0, 80.0),
        (55.0, 80.0, 60.0),
        (75.0, 40.0, -50.0),
    ];
    let image = blob_image(&blobs);
    let rect = FaceRect {
        x: 20.0,
        y: 20.0,
        width: 80.0,
        height: 80.0,
    };
    let model = FaceModel::generic(33).unwrap();
    let config = ExtractionConfig {
        max_points: 3,
        extrema_share: 1.0,
        ..ExtractionConfig::default()
    };
    let eye = regular(6, [45.0, 50.0], 6.0, 0.0);
    let taken = |avoid: &[Outline]| {
        let template =
            extract_template_seen(&image, &rect, &model, &config, &View::frontal(), avoid).unwrap();
        let (cx, cy) = rect.centre();
        (template.points.iter())
            .map(|q| (q.position[0] + cx, q.position[1] + cy))
            .collect::<Vec<_>>()
    };
    let near = |(x, y): (f32, f32), (bx, by): (f32, f32)| (x - bx).hypot(y - by) < 1.0;
    let all = taken(&[]);
    assert!(near(all[0], (45.0, 50.0)), "{all:?}");
    let avoiding = taken(std::slice::from_ref(&eye));
    assert_eq!(avoiding.len(), 3, "{avoiding:?}");
    for p in &avoiding {
        assert!(!inside_outline(&eye, p.0, p.1), "{p:?} is inside the eye");
    }
    for blob in &blobs[1..] {
        assert!(
            avoiding.iter().any(|&p| near(p, (blob.0, blob.1))),
            "blob {blob:?} not taken: {avoiding:?}"
        );
    }
}

#[test]
fn a_bad_growth_is_a_clear_error() {
    let image = blob_image(&[(60.0, 60.0, 100.0)]);
    let rect = FaceRect {
        x: 20.0,
        y: 20.0,
        width: 80.0,
        height: 80.0,
    };
    let model = FaceModel::generic(33).unwrap();
    for growth in [0.0, -1.0, f32::NAN, f32::INFINITY] {
        let config = ExtractionConfig {
            eye_outline_growth: Some(growth),
            ..ExtractionConfig::default()
        };
        let error = extract_template_seen(&image, &rect, &model, &config, &View::frontal(), &[])
            .unwrap_err()
            .to_string();
        assert!(error.contains("invalid extraction settings"), "{error}");
    }
}
