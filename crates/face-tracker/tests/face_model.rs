//! Projection against hand-computed cases, the likelihood's pieces, the face model, template
//! extraction on synthetic images with known extrema and edges, and bad inputs.

use face_tracker::extraction::{ExtractionConfig, FaceRect, Outline, extract_template};
use face_tracker::likelihood::{log_weight, residual_error, rho};
use face_tracker::model::{EYE_CORNER_U, EYE_CORNER_V, FaceModel, NOSE_TIP_V};
use face_tracker::projection::{DIMS, Pose};
use face_tracker::{FeaturePoint, GrayImage, Template};
use nalgebra::Vector3;
use std::f32::consts::FRAC_PI_2;

fn state(values: [f32; DIMS]) -> Pose {
    Pose::new(&values)
}

#[test]
fn projection_matches_hand_computed_cases() {
    let p = Vector3::new(3.0, 4.0, 5.0);
    // No rotation: p = S·(x, y) + T.
    let pose = state([100.0, 50.0, 2.0, 0.0, 0.0, 0.0, 1.0]);
    let q = pose.project(&p);
    assert!(
        (q.x - 106.0).abs() < 1e-5 && (q.y - 58.0).abs() < 1e-5,
        "{q:?}"
    );
    // Rz = 90°: x → y, y → −x.
    let q = state([0.0, 0.0, 1.0, 0.0, 0.0, FRAC_PI_2, 1.0]).project(&p);
    assert!(
        (q.x + 4.0).abs() < 1e-5 && (q.y - 3.0).abs() < 1e-5,
        "{q:?}"
    );
    // Ry = 90°: the depth z becomes x, x becomes −z (dropped by the projection).
    let q = state([0.0, 0.0, 1.0, 0.0, FRAC_PI_2, 0.0, 1.0]).project(&p);
    assert!(
        (q.x - 5.0).abs() < 1e-5 && (q.y - 4.0).abs() < 1e-5,
        "{q:?}"
    );
    // Rx = 90°: y becomes z, z becomes −y.
    let q = state([0.0, 0.0, 1.0, FRAC_PI_2, 0.0, 0.0, 1.0]).project(&p);
    assert!(
        (q.x - 3.0).abs() < 1e-5 && (q.y + 5.0).abs() < 1e-5,
        "{q:?}"
    );
    // R = Rx·Ry·Rz: Rz first. Rz = 90° then Rx = 90°: (1, 0, 0) → (0, 1, 0) → (0, 0, 1).
    let r = state([0.0, 0.0, 1.0, FRAC_PI_2, 0.0, FRAC_PI_2, 1.0]).rotation * Vector3::x();
    assert!((r - Vector3::z()).norm() < 1e-6, "{r:?}");
    // Self-occlusion: a normal facing the camera turns away past 90° of yaw.
    let out = Vector3::z();
    assert!(state([0.0, 0.0, 1.0, 0.0, 1.5, 0.0, 1.0]).faces_camera(&out));
    assert!(!state([0.0, 0.0, 1.0, 0.0, 1.7, 0.0, 1.0]).faces_camera(&out));
    assert!(!state([0.0, 0.0, 1.0, 3.0, 0.0, 0.0, 1.0]).faces_camera(&out));
}

#[test]
fn bilinear_sampling_is_exact_on_a_ramp_and_none_outside() {
    let (w, h) = (7u32, 5u32);
    let data: Vec<f32> = (0..w * h)
        .map(|k| (3 * (k % w) + 10 * (k / w)) as f32)
        .collect();
    let image = GrayImage::from_levels(w, h, &data).unwrap();
    for (x, y) in [
        (0.0, 0.0),
        (2.25, 1.5),
        (6.0, 4.0),
        (5.999, 0.001),
        (6.0, 2.5),
    ] {
        let v = image.bilinear(x, y).unwrap();
        assert!((v - (3.0 * x + 10.0 * y)).abs() < 1e-3, "({x}, {y}): {v}");
    }
    for (x, y) in [(-0.01, 1.0), (6.01, 1.0), (1.0, 4.001), (f32::NAN, 1.0)] {
        assert!(image.bilinear(x, y).is_none());
    }
}

#[test]
fn the_residual_is_zero_on_the_template_and_grows_with_illumination() {
    let image = GrayImage::new(32, 32, (0..1024).map(|k| 20 + (k % 97) as u8).collect()).unwrap();
    let points: Vec<FeaturePoint> = (0..50)
        .map(|i| {
            let (x, y) = (3 + (i * 7) % 25, 4 + (i * 3) % 23);
            FeaturePoint::new(
                [x as f32 - 16.0, y as f32 - 16.0, 2.0],
                [0.0, 0.0, 1.0],
                image.at(x, y),
            )
        })
        .collect();
    let template = Template::new(points).unwrap();
    let at = [16.0, 16.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    assert!(residual_error(&at, &template, &image) < 1e-10);
    // α = 2: κ = 1 for every point, ρ = 1/2.
    let doubled = [16.0, 16.0, 1.0, 0.0, 0.0, 0.0, 2.0];
    assert!((residual_error(&doubled, &template, &image) - 0.5).abs() < 1e-6);
    // Out of the frame: ρ = 1; turned away: no point visible, ε = 1.
    let gone = [1000.0, 16.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    assert_eq!(residual_error(&gone, &template, &image), 1.0);
    let away = [16.0, 16.0, 1.0, 0.0, 3.0, 0.0, 1.0];
    assert_eq!(residual_error(&away, &template, &image), 1.0);
    assert!((rho(1.0) - 0.5).abs() < 1e-7 && rho(0.0) == 0.0);
    assert!(log_weight(0.5, 1.0) > log_weight(0.9, 1.0));
    assert!(log_weight(0.0, 1.0).is_finite());
}

#[test]
fn the_generic_model_is_a_head() {
    let model = FaceModel::generic(65).unwrap();
    let (centre, _) = model.sample(0.0, 0.0);
    let (nose, _) = model.sample(0.0, 0.12);
    let (cheek_edge, side) = model.sample(0.95, 0.0);
    assert!(
        nose > centre && centre > cheek_edge,
        "{nose} {centre} {cheek_edge}"
    );
    // The forehead faces the camera.
    let (_, forehead) = model.sample(0.0, -0.6);
    assert!(forehead[2] > 0.8, "{forehead:?}");
    // The nose tip stands about one eye-corner half-distance in front of the eyes' outer corners,
    // as a real face's does (the generic head's eye corners, placed by dlib's mean shape, are at
    // u = ±0.62, v = −0.10): the depth that sets how far the tracker's yaw turns.
    let (tip, _) = model.sample(0.0, NOSE_TIP_V);
    let (eye_corner, _) = model.sample(EYE_CORNER_U, EYE_CORNER_V);
    let ratio = (tip - eye_corner) / EYE_CORNER_U;
    assert!((0.9..=1.1).contains(&ratio), "{ratio}");
    // At the right edge the surface turns right (towards +x).
    assert!(side[0] > 0.5, "{side:?}");
    for k in 0..model.normals.len() {
        let len: f32 = model.normals[k].iter().map(|c| c * c).sum::<f32>().sqrt();
        assert!((len - 1.0).abs() < 1e-5);
    }
    assert!(FaceModel::generic(2).is_err());
}

#[test]
fn the_photographed_model_is_a_real_face_on_the_generic_skull() {
    let (photographed, generic) = (
        FaceModel::photographed(97).unwrap(),
        FaceModel::generic(97).unwrap(),
    );
    // Heights above the eyes' outer corners.
    let relief = |model: &FaceModel, u: f32, v: f32| {
        model.sample(u, v).0 - model.sample(EYE_CORNER_U, EYE_CORNER_V).0
    };
    // A real nose: its tip about one eye-corner half-distance in front of the eye corners, and a
    // ridge that rises from between the eyes to the tip (the generic one is highest above it).
    let tip = relief(&photographed, 0.0, NOSE_TIP_V) / EYE_CORNER_U;
    assert!((0.9..=1.15).contains(&tip), "{tip}");
    assert!(relief(&photographed, 0.0, EYE_CORNER_V) < relief(&photographed, 0.0, NOSE_TIP_V));
    // A real mouth and chin stand well forward of the generic head's, which falls away below the
    // nose; the forehead a little.
    for (v, by) in [(0.6, 0.15), (0.9, 0.2), (-0.5, 0.05)] {
        let (real, parametric) = (relief(&photographed, 0.0, v), relief(&generic, 0.0, v));
        assert!(
            real > parametric + by,
            "v = {v}: {real} against {parametric}"
        );
    }
    // Left and right alike; off the face it is the generic skull.
    for (u, v) in [(0.3, 0.2), (0.62, -0.1), (0.5, 0.7), (0.2, -0.4)] {
        let (left, right) = (photographed.sample(-u, v).0, photographed.sample(u, v).0);
        assert!((left - right).abs() < 1e-3, "({u}, {v}): {left} {right}");
    }
    for (u, v) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
        let (a, b) = (photographed.sample(u, v).0, generic.sample(u, v).0);
        assert!((a - b).abs() < 1e-4, "({u}, {v}): {a} {b}");
    }
    assert!(FaceModel::photographed(2).is_err());
}

/// The face rectangle the blob images' tests extract from.
const BLOB_RECT: FaceRect = FaceRect {
    x: 20.0,
    y: 20.0,
    width: 80.0,
    height: 80.0,
};

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
fn extraction_finds_known_extrema_in_order() {
    let blobs = [
        (40.0, 45.0, 90.0),
        (70.0, 60.0, -100.0),
        (55.0, 80.0, 60.0),
        (75.0, 35.0, -40.0),
    ];
    let image = blob_image(&blobs);
    let rect = BLOB_RECT;
    let model = FaceModel::generic(33).unwrap();
    let config = ExtractionConfig {
        max_points: 4,
        extrema_share: 1.0,
        ..ExtractionConfig::default()
    };
    let template = extract_template(&image, &rect, &model, &config).unwrap();
    assert_eq!(template.len(), 4);
    // Strongest first: the dark −100 blob ranks with the bright +90 one, by how extreme it is.
    for (q, &(bx, by, a)) in template
        .points
        .iter()
        .zip(&[blobs[1], blobs[0], blobs[2], blobs[3]])
    {
        let (x, y) = (q.position[0] + 60.0, q.position[1] + 60.0);
        assert!(
            (x - bx).abs() < 0.5 && (y - by).abs() < 0.5,
            "({x}, {y}) vs blob ({bx}, {by})"
        );
        assert!(
            (q.gray - (128.0 + a)).abs() < 2.0,
            "gray {} for amplitude {a}",
            q.gray
        );
        assert!(q.position[2] > 0.0);
    }
}

#[test]
fn extraction_puts_dipoles_across_edges_and_keeps_points_apart() {
    // A vertical step edge at x = 60 (dark left, bright right) with a gentle vertical shading.
    let (w, h) = (120u32, 120u32);
    let data: Vec<f32> = (0..w * h)
        .map(|k| {
            let (x, y) = (k % w, k / w);
            (if x < 60 { 60.0 } else { 200.0 }) + 0.05 * y as f32
        })
        .collect();
    let image = GrayImage::from_levels(w, h, &data).unwrap();
    let rect = BLOB_RECT;
    let model = FaceModel::generic(33).unwrap();
    let config = ExtractionConfig {
        max_points: 20,
        extrema_share: 0.0,
        ..ExtractionConfig::default()
    };
    let template = extract_template(&image, &rect, &model, &config).unwrap();
    assert!(template.len() >= 10, "{} points", template.len());
    for pair in template.points.chunks(2) {
        let (a, b) = (pair[0].position[0] + 60.0, pair[1].position[0] + 60.0);
        assert!(a < 59.5 && b > 59.5, "dipole ends at x {a}, {b}");
        assert!(pair[0].gray < 100.0 && pair[1].gray > 160.0);
    }
    // On a textured face, the default extraction keeps its separation.
    let cfg = face_tracker::synth::FaceSynthConfig {
        faces: 1,
        ..face_tracker::synth::FaceSynthConfig::paper(1)
    };
    let model = FaceModel::generic(129).unwrap();
    let frame = face_tracker::synth::render_frame(&cfg, &model, 0).unwrap();
    let rect = face_tracker::synth::initial_rect(&cfg, 0);
    let template = extract_template(&frame, &rect, &model, &ExtractionConfig::default()).unwrap();
    assert_eq!(template.len(), 230);
    // Asked for one point per pixel of the face's width, a 120 px face takes 120; a bad ratio
    // is refused.
    let per_pixel = |points_per_width| ExtractionConfig {
        points_per_width,
        ..ExtractionConfig::default()
    };
    assert_eq!(rect.width, 120.0);
    let fewer = extract_template(&frame, &rect, &model, &per_pixel(Some(1.0))).unwrap();
    assert_eq!(fewer.len(), 120);
    for bad in [0.0, -1.0, f32::NAN] {
        assert!(extract_template(&frame, &rect, &model, &per_pixel(Some(bad))).is_err());
    }
    let dipole_partner = |i: usize, j: usize| i / 2 == j / 2;
    for (i, a) in template.points.iter().enumerate() {
        for (j, b) in template.points.iter().enumerate().skip(i + 1) {
            let d = ((a.position[0] - b.position[0]).powi(2)
                + (a.position[1] - b.position[1]).powi(2))
            .sqrt();
            // Dipole partners are 2 x half-length apart by construction; pairs start after the extrema.
            assert!(
                d >= 3.0 - 1e-4 || dipole_partner(i, j),
                "points {i} and {j} are {d} px apart"
            );
        }
    }
}

#[test]
fn bad_inputs_are_clear_errors() {
    let image = GrayImage::filled(64, 48, 100).unwrap();
    let model = FaceModel::generic(33).unwrap();
    let config = ExtractionConfig::default();
    let zero = FaceRect {
        x: 10.0,
        y: 10.0,
        width: 0.0,
        height: 20.0,
    };
    assert!(
        extract_template(&image, &zero, &model, &config)
            .unwrap_err()
            .to_string()
            .contains("at least 8x8")
    );
    let outside = FaceRect {
        x: 50.0,
        y: 10.0,
        width: 30.0,
        height: 20.0,
    };
    assert!(
        extract_template(&image, &outside, &model, &config)
            .unwrap_err()
            .to_string()
            .contains("not inside")
    );
    let flat = FaceRect {
        x: 10.0,
        y: 10.0,
        width: 30.0,
        height: 20.0,
    };
    assert!(
        extract_template(&image, &flat, &model, &config)
            .unwrap_err()
            .to_string()
            .contains("flat")
    );
    assert!(
        Template::new(vec![])
            .unwrap_err()
            .to_string()
            .contains("at least one")
    );
    assert!(Template::new(vec![FeaturePoint::new([0.0; 3], [0.0; 3], 10.0)]).is_err());
    assert!(Template::new(vec![FeaturePoint::new([0.0; 3], [0.0, 0.0, 1.0], 0.0)]).is_err());
    assert!(GrayImage::new(1, 10, vec![0; 10]).is_err());
    assert!(GrayImage::new(4, 4, vec![0; 15]).is_err());
    assert!(GrayImage::from_levels(2, 2, &[0.0, 1.0, f32::NAN, 0.0]).is_err());
    let dir = std::env::temp_dir().join(format!("streampf-face-bad-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let text = dir.join("frame.png");
    std::fs::write(&text, "not an image").unwrap();
    assert!(
        GrayImage::load(&text)
            .unwrap_err()
            .to_string()
            .contains("frame.png")
    );
    let tiny = dir.join("tiny.png");
    image::GrayImage::new(1, 1).save(&tiny).unwrap();
    assert!(
        GrayImage::load(&tiny)
            .unwrap_err()
            .to_string()
            .contains("at least 2x2")
    );
    // User face maps: a colour heightmap and a gray normalmap are refused; good maps load.
    let gray = dir.join("height.png");
    image::GrayImage::from_fn(9, 9, |x, y| image::Luma([(x * 20 + y) as u8]))
        .save(&gray)
        .unwrap();
    let rgb = dir.join("normal.png");
    image::RgbImage::from_fn(9, 9, |_, _| image::Rgb([128, 128, 255]))
        .save(&rgb)
        .unwrap();
    assert!(
        FaceModel::load(&rgb, &rgb, 0.5)
            .unwrap_err()
            .to_string()
            .contains("gray")
    );
    assert!(
        FaceModel::load(&gray, &gray, 0.5)
            .unwrap_err()
            .to_string()
            .contains("RGB")
    );
    let loaded = FaceModel::load(&gray, &rgb, 0.5).unwrap();
    assert_eq!(loaded.size, 9);
    assert!((loaded.heights[9 * 8 + 8] - 0.5 * (8.0 * 20.0 + 8.0) / 255.0).abs() < 1e-3);
    assert!(loaded.normals[0][2] > 0.99);
    std::fs::remove_dir_all(&dir).unwrap();
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
    let rect = BLOB_RECT;
    let model = FaceModel::generic(33).unwrap();
    let config = ExtractionConfig {
        max_points: 3,
        extrema_share: 1.0,
        ..ExtractionConfig::default()
    };
    // A hexagon of radius 6 about the strongest blob.
    let eye: Outline = (0..6)
        .map(|k| {
            let a = std::f32::consts::TAU * k as f32 / 6.0;
            [45.0 + 6.0 * a.cos(), 50.0 + 6.0 * a.sin()]
        })
        .collect();
    let taken = |avoid: &[Outline]| {
        let template = face_tracker::extraction::extract_template_seen(
            &image,
            &rect,
            &model,
            &config,
            &face_tracker::view::View::frontal(),
            &face_tracker::likelihood::Lens::WEAK,
            avoid,
        )
        .unwrap();
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
        assert!(
            !face_tracker::extraction::inside_outline(&eye, p.0, p.1),
            "{p:?} is inside the eye"
        );
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
    let rect = BLOB_RECT;
    let model = FaceModel::generic(33).unwrap();
    for growth in [0.0, 0.5, -1.0, f32::NAN, f32::INFINITY] {
        let config = ExtractionConfig {
            eye_outline_growth: Some(growth),
            ..ExtractionConfig::default()
        };
        let error = face_tracker::extraction::extract_template_seen(
            &image,
            &rect,
            &model,
            &config,
            &face_tracker::view::View::frontal(),
            &face_tracker::likelihood::Lens::WEAK,
            &[],
        )
        .unwrap_err()
        .to_string();
        assert!(error.contains("invalid extraction settings"), "{error}");
    }
}

/// A deeper or shallower photographed face (`--face-depth`): the heights above the eyes' outer
/// corners scale with it down the middle of the face, the skull off the face stays, 1 is the
/// photographed head itself, and a depth outside the range is refused.
#[test]
fn the_photographed_face_can_be_made_deeper_or_shallower() {
    use face_tracker::model::{FACE_DEPTH_RANGE, photographed_height_with_face_depth as height};
    use proptest::prelude::*;
    use proptest::test_runner::{Config, TestRunner};
    assert_eq!(
        FaceModel::photographed_with_face_depth(65, 1.0).unwrap(),
        FaceModel::photographed(65).unwrap()
    );
    let relief = |u: f32, v: f32, k: f32| height(u, v, k) - height(EYE_CORNER_U, EYE_CORNER_V, k);
    let mut runner = TestRunner::new(Config {
        cases: 256,
        failure_persistence: None,
        ..Config::default()
    });
    let depths = FACE_DEPTH_RANGE;
    runner
        .run(
            &(depths.clone(), prop_oneof![Just(1.0f32), depths]),
            |(k, other)| {
                // Down the middle of the face (nose ridge, tip, mouth, chin) the relief scales.
                for v in [-0.1f32, 0.1, NOSE_TIP_V, 0.6, 0.8] {
                    let (a, b) = (relief(0.0, v, k), relief(0.0, v, other));
                    prop_assert!(
                        (a * other - b * k).abs()
                            <= 1e-4 * (1.0 + a.abs() + b.abs()) * k.max(other),
                        "v = {v}: {a} at {k}, {b} at {other}"
                    );
                }
                // The skull beyond the photographed face (the rectangle's top and corners) does
                // not move.
                for (u, v) in [
                    (-1.0f32, -1.0f32),
                    (0.0, -1.0),
                    (1.0, -1.0),
                    (-1.0, 1.0),
                    (1.0, 1.0),
                ] {
                    prop_assert_eq!(height(u, v, k), height(u, v, other));
                }
                Ok(())
            },
        )
        .unwrap();
    for bad in [0.0, 0.2, 4.5, -1.0, f32::NAN, f32::INFINITY] {
        let err = FaceModel::photographed_with_face_depth(65, bad).unwrap_err();
        assert!(err.to_string().contains("depth scale"), "{bad}: {err}");
    }
}
