//! Where a template leaves the eyes out: the point-in-outline test on random polygons and the
//! eyes' outlines grown about their centres (`face_model.rs` checks that a template avoids an
//! outline; `tests/face_landmarks.rs` that personalised templates leave real eyes out).

use face_tracker::extraction::{Outline, eye_outlines, inside_outline};
use face_tracker::landmarks::ibug68;
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
