//! A small face enlarged before its template is taken (`face_tracker::enlarge`): the region maps
//! back onto the frame exactly, the lens sees the same scene, and a template taken in the
//! enlarged region is the template of the same face in the whole frame enlarged, scaled back.

use face_tracker::enlarge::{Enlarged, MAX_FACTOR};
use face_tracker::extraction::{ExtractionConfig, FaceRect};
use face_tracker::image::GrayImage;
use face_tracker::lens::Lens;
use face_tracker::model::FaceModel;
use face_tracker::synth::{FaceSynthConfig, initial_rect, render_frame};
use face_tracker::tracker::{FaceBackend, FaceTracker, FaceTrackerConfig};
use proptest::prelude::*;

/// A frame of random gray levels.
fn noise_frame(width: u32, height: u32, levels: &[u8]) -> GrayImage {
    let data = (0..width * height)
        .map(|i| levels[i as usize % levels.len()])
        .collect();
    GrayImage::new(width, height, data).unwrap()
}

/// `frame` enlarged `factor` times as `Enlarged` samples it: pixel (i, j) is the bilinear
/// sample at (i, j) / factor, rounded.
fn enlarged_whole(frame: &GrayImage, factor: u32) -> GrayImage {
    let (width, height) = (
        (frame.width - 1) * factor + 1,
        (frame.height - 1) * factor + 1,
    );
    let mut data = Vec::with_capacity((width * height) as usize);
    for j in 0..height {
        for i in 0..width {
            let x = i as f32 / factor as f32;
            let y = j as f32 / factor as f32;
            data.push(frame.bilinear(x, y).unwrap().round() as u8);
        }
    }
    GrayImage::new(width, height, data).unwrap()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    /// The factor is the smallest whole one (2 to 4) that makes the face `min_width` wide; the
    /// face's rectangle lies inside the region (a rectangle ending at the frame's edge too); the
    /// region's pixels are the frame's bilinear samples where `to_frame` puts them (past the
    /// frame's last pixel, that pixel repeated); a face already that wide is not enlarged.
    #[test]
    fn the_region_holds_the_face_and_maps_back_onto_the_frame(
        width in 10u32..90,
        height in 10u32..70,
        levels in prop::collection::vec(any::<u8>(), 1..64),
        fx in 0.0f32..=1.0, fy in 0.0f32..=1.0, fw in 0.0f32..=1.0, fh in 0.0f32..=1.0,
        min_width in 0.0f32..200.0,
    ) {
        let frame = noise_frame(width, height, &levels);
        // A face rectangle is at least 8x8 and within the frame, up to its far edges.
        let rect_width = 8.0 + fw * (width - 8) as f32;
        let rect_height = 8.0 + fh * (height - 8) as f32;
        let rect = FaceRect {
            x: fx * (width as f32 - rect_width),
            y: fy * (height as f32 - rect_height),
            width: rect_width,
            height: rect_height,
        };
        prop_assert!(rect.validate(&frame).is_ok());
        let enlarged = Enlarged::around(&frame, &rect, min_width).unwrap();
        let Some(enlarged) = enlarged else {
            prop_assert!(rect.width >= min_width);
            return Ok(());
        };
        prop_assert!(rect.width < min_width);
        let factor = enlarged.factor();
        prop_assert!((2.0..=MAX_FACTOR as f32).contains(&factor));
        prop_assert!(factor == 2.0 || rect.width * (factor - 1.0) < min_width);
        prop_assert!(factor == MAX_FACTOR as f32 || rect.width * factor >= min_width);
        let region = &enlarged.frame;
        prop_assert!(
            enlarged.rect.validate(region).is_ok(),
            "{:?} in a {}x{} region",
            enlarged.rect,
            region.width,
            region.height
        );
        let (last_x, last_y) = ((width - 1) as f32, (height - 1) as f32);
        for j in (0..region.height).step_by(3) {
            for i in (0..region.width).step_by(3) {
                let [x, y] = enlarged.to_frame([i as f32, j as f32]);
                prop_assert!(x <= width as f32 && y <= height as f32);
                let expected = frame.bilinear(x.min(last_x), y.min(last_y)).unwrap();
                prop_assert!((region.at(i, j) - expected).abs() <= 0.5 + 1e-3);
            }
        }
    }

    /// Through the enlarged region's lens a point is seen where the frame's lens sees it, scaled
    /// by the factor: the principal point moves with the region, the focal length grows.
    #[test]
    fn the_lens_sees_the_same_scene(
        fov in 20.0f32..120.0,
        weak_x in 0.0f32..160.0, weak_y in 0.0f32..120.0,
        depth in -30.0f32..30.0,
        min_width in 30.0f32..150.0,
    ) {
        let frame = noise_frame(160, 120, &[10, 200, 90]);
        let rect = FaceRect { x: 60.0, y: 40.0, width: 28.0, height: 35.0 };
        let enlarged = Enlarged::around(&frame, &rect, min_width).unwrap().unwrap();
        let k = enlarged.factor();
        let focal = Lens::focal_length_for(fov, frame.width).unwrap();
        let lens = Lens::pinhole(focal, frame.width, frame.height).unwrap();
        let seen = lens.apply([weak_x, weak_y], depth);
        // The weak image in the region's pixels: the frame's, moved and scaled like the region.
        let origin = enlarged.to_frame([0.0, 0.0]);
        let weak_there = [(weak_x - origin[0]) * k, (weak_y - origin[1]) * k];
        let seen_there = enlarged.lens(&lens).apply(weak_there, depth * k);
        match (seen, seen_there) {
            (Some(p), Some(q)) => {
                let back = enlarged.to_frame(q);
                prop_assert!((back[0] - p[0]).abs() < 1e-2 && (back[1] - p[1]).abs() < 1e-2,
                    "{p:?} against {back:?}");
            }
            (None, None) => {}
            (p, q) => prop_assert!(false, "seen {p:?} in the frame, {q:?} in the region"),
        }
        prop_assert_eq!(enlarged.lens(&Lens::WEAK), Lens::WEAK);
    }
}

/// A synthetic head drawn small, its rectangle, and the generic model it was drawn with.
fn small_head(half_width: f32) -> (GrayImage, FaceRect, FaceModel) {
    let config = FaceSynthConfig {
        width: 200,
        height: 160,
        faces: 1,
        half_width,
        ..FaceSynthConfig::paper(1)
    };
    let model = FaceModel::generic(129).unwrap();
    let frame = render_frame(&config, &model, 0).unwrap();
    (frame, initial_rect(&config, 0), model)
}

/// A camera: its focal length and principal point (pixels); `None`: weak perspective.
type Camera = Option<(f32, [f32; 2])>;

fn tracker_for(
    frame: &GrayImage,
    model: &FaceModel,
    enlarge_below: Option<f32>,
    camera: Camera,
) -> FaceTracker {
    let config = FaceTrackerConfig {
        extraction: ExtractionConfig {
            enlarge_below,
            ..ExtractionConfig::default()
        },
        focal_length: camera.map(|(focal, _)| focal),
        principal_point: camera.map(|(_, principal)| principal),
        ..FaceTrackerConfig::default()
    };
    FaceTracker::with_capacity(
        (frame.width, frame.height),
        1,
        model,
        config,
        FaceBackend::Cpu,
    )
    .unwrap()
}

/// Enlarging inside the tracker is tracking an enlarged video: the template a small face takes
/// enlarged is, point for point, the template the whole frame enlarged gives the same face,
/// its positions divided by the factor (the same gray levels, the same normals); through weak
/// perspective and through a pinhole camera (whose focal length and principal point the
/// enlarged video's camera has doubled).
#[test]
fn an_enlarged_template_is_the_enlarged_frames_template_scaled_back() {
    let (frame, rect, model) = small_head(18.0);
    assert!(rect.width < 48.0, "a small face: {rect:?}");
    let whole = enlarged_whole(&frame, 2);
    let rect2 = FaceRect {
        x: rect.x * 2.0,
        y: rect.y * 2.0,
        width: rect.width * 2.0,
        height: rect.height * 2.0,
    };
    for camera in [None, Some((150.0, [95.0, 83.0]))] {
        let doubled = camera.map(|(focal, [px, py])| (focal * 2.0, [px * 2.0, py * 2.0]));
        let small = tracker_for(&frame, &model, Some(rect.width * 2.0), camera);
        let template = small.extract(&frame, &rect).unwrap();
        let as_is = (tracker_for(&frame, &model, None, camera).extract(&frame, &rect)).unwrap();
        let reference = tracker_for(&whole, &model, None, doubled)
            .extract(&whole, &rect2)
            .unwrap();
        assert_eq!(template.points.len(), reference.points.len(), "{camera:?}");
        assert!(
            template.points.len() > as_is.points.len(),
            "enlarged, the face takes more points: {} against {} at its own size",
            template.points.len(),
            as_is.points.len()
        );
        for (ours, theirs) in template.points.iter().zip(&reference.points) {
            for c in 0..3 {
                assert!(
                    (ours.position[c] * 2.0 - theirs.position[c]).abs() < 1e-3,
                    "{camera:?}: {ours:?} against {theirs:?}"
                );
            }
            assert_eq!(ours.gray, theirs.gray);
            for c in 0..3 {
                assert!((ours.normal[c] - theirs.normal[c]).abs() < 1e-5);
            }
        }
    }
}

/// A face as wide as the threshold, or any face with enlarging off, gets the template it always
/// had; a bad threshold is a clear error, not a silent template.
#[test]
fn a_face_wide_enough_is_taken_as_it_is_and_bad_widths_are_refused() {
    let (frame, rect, model) = small_head(18.0);
    let as_is = (tracker_for(&frame, &model, None, None).extract(&frame, &rect)).unwrap();
    let at_threshold = tracker_for(&frame, &model, Some(rect.width), None)
        .extract(&frame, &rect)
        .unwrap();
    assert_eq!(as_is.points, at_threshold.points);
    for bad in [-1.0, f32::NAN, f32::INFINITY] {
        assert!(Enlarged::around(&frame, &rect, bad).is_err(), "{bad}");
        let config = ExtractionConfig {
            enlarge_below: Some(bad),
            ..ExtractionConfig::default()
        };
        assert!(
            face_tracker::extraction::extract_template(&frame, &rect, &model, &config).is_err(),
            "{bad}"
        );
    }
}

/// A small face whose rectangle ends at the frame's right and bottom edges (where the detector
/// may put one) is enlarged and gets its template, as it does at its own size.
#[test]
fn a_small_face_at_the_frame_s_edge_gets_its_template() {
    let (frame, rect, model) = small_head(18.0);
    let at_edge = FaceRect {
        x: frame.width as f32 - rect.width,
        y: frame.height as f32 - rect.height,
        ..rect
    };
    let as_is = (tracker_for(&frame, &model, None, None).extract(&frame, &at_edge)).unwrap();
    let enlarged = tracker_for(&frame, &model, Some(rect.width * 2.0), None)
        .extract(&frame, &at_edge)
        .unwrap();
    assert!(!as_is.points.is_empty() && !enlarged.points.is_empty());
}

/// With `points_per_width`, an enlarged face takes the points its own width allows, not its
/// enlarged width's.
#[test]
fn an_enlarged_face_takes_the_points_of_its_own_width() {
    let (frame, rect, model) = small_head(18.0);
    let per_pixel = |enlarge_below| {
        let config = FaceTrackerConfig {
            extraction: ExtractionConfig {
                points_per_width: Some(0.5),
                enlarge_below,
                ..ExtractionConfig::default()
            },
            ..FaceTrackerConfig::default()
        };
        FaceTracker::with_capacity(
            (frame.width, frame.height),
            1,
            &model,
            config,
            FaceBackend::Cpu,
        )
        .unwrap()
        .extract(&frame, &rect)
        .unwrap()
    };
    let allowed = (0.5 * rect.width).round() as usize;
    assert_eq!(per_pixel(Some(rect.width * 2.0)).points.len(), allowed);
    assert_eq!(per_pixel(None).points.len(), allowed);
}
