//! The CPU path's fast forms against their definitions: the likelihood weighed LANES particles
//! at a time against `residual_error`, one particle at a time (bit for bit, through weak
//! perspective and through a pinhole); the video renderer,
//! which keeps what frames share, against rendering each frame from nothing.

use face_tracker::likelihood::{
    LANES, Lens, least_squares_gain, residual_error, residual_error_through, residual_errors,
    residual_errors_of, residual_errors_of_baseline, residual_errors_of_through, weigh_parallel,
    weigh_parallel_through, weigh_single_thread,
};
use face_tracker::model::FaceModel;
use face_tracker::projection::DIMS;
use face_tracker::synth::{FaceSynthConfig, FaceVideoRenderer, render_frame};
use face_tracker::{FeaturePoint, GrayImage, Template};
use proptest::prelude::*;

fn unit(v: [f32; 3]) -> [f32; 3] {
    let len = v.iter().map(|c| c * c).sum::<f32>().sqrt().max(1e-3);
    v.map(|c| c / len)
}

fn frame(width: u32, height: u32, seed: u64) -> GrayImage {
    let data = (0..u64::from(width * height))
        .map(|i| (pf_core::random::splitmix64(seed ^ i) >> 56) as u8)
        .collect();
    GrayImage::new(width, height, data).unwrap()
}

/// A particle: anywhere from well inside to well off a small frame, any rotation (so points
/// turn away), NaN in one value now and then.
fn particle() -> impl Strategy<Value = [f32; DIMS]> {
    (
        prop::array::uniform2(-30.0f32..110.0),
        0.2f32..2.5,
        prop::array::uniform3(-3.2f32..3.2),
        0.3f32..2.0,
        0usize..40,
    )
        .prop_map(|(t, s, r, a, nan_at)| {
            let mut x = [t[0], t[1], s, r[0], r[1], r[2], a];
            if nan_at < DIMS {
                x[nan_at] = f32::NAN;
            }
            x
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(128))]
    #[test]
    fn lanes_weigh_as_one_particle_at_a_time(
        (width, height) in (2u32..90, 2u32..70),
        seed in any::<u64>(),
        points in prop::collection::vec(
            (prop::array::uniform3(-40.0f32..40.0), prop::array::uniform3(-1.0f32..1.0), 1.0f32..255.0),
            1..80,
        ),
        states in prop::collection::vec(particle(), 0..(3 * LANES + 3)),
    ) {
        let frame = frame(width, height, seed);
        let template = Template::new(
            points
                .into_iter()
                .map(|(p, n, j)| FeaturePoint::new(p, unit([n[0], n[1], n[2] + 1e-2]), j))
                .collect(),
        )
        .unwrap();
        let one_at_a_time: Vec<f64> =
            states.iter().map(|s| residual_error(s, &template, &frame)).collect();
        // NaN compares unequal to itself: compare the bits.
        let bits = |v: &[f64]| v.iter().map(|e| e.to_bits()).collect::<Vec<_>>();
        let mut batched = vec![-1.0; states.len()];
        residual_errors_of(&states, &template, &frame, &mut batched);
        prop_assert_eq!(bits(&batched), bits(&one_at_a_time));
        // Where the CPU has AVX2 the call above ran the AVX2 build of the lanes: the baseline
        // build must give the same bits.
        let mut baseline = vec![-1.0; states.len()];
        residual_errors_of_baseline(&states, &template, &frame, &mut baseline);
        prop_assert_eq!(bits(&baseline), bits(&one_at_a_time));
        prop_assert_eq!(bits(&weigh_single_thread(&states, &template, &frame)), bits(&one_at_a_time));
        prop_assert_eq!(bits(&weigh_parallel(&states, &template, &frame)), bits(&one_at_a_time));
        if let Some(group) = states.first_chunk::<LANES>() {
            let lanes = residual_errors(group, &template, &frame);
            prop_assert_eq!(bits(&lanes), bits(&one_at_a_time[..LANES]));
        }
    }

    /// The same through a pinhole (the lanes' own copy of `Lens::apply`), from a lens longer than
    /// the frame to one that puts points at or behind the camera.
    #[test]
    fn lanes_weigh_as_one_particle_at_a_time_through_a_lens(
        (width, height) in (2u32..90, 2u32..70),
        seed in any::<u64>(),
        focal in 5.0f32..400.0,
        points in prop::collection::vec(
            (prop::array::uniform3(-40.0f32..40.0), prop::array::uniform3(-1.0f32..1.0), 1.0f32..255.0),
            1..80,
        ),
        states in prop::collection::vec(particle(), 0..(3 * LANES + 3)),
    ) {
        let frame = frame(width, height, seed);
        let lens = Lens::pinhole(focal, width, height).unwrap();
        let template = Template::new(
            points
                .into_iter()
                .map(|(p, n, j)| FeaturePoint::new(p, unit([n[0], n[1], n[2] + 1e-2]), j))
                .collect(),
        )
        .unwrap();
        let one_at_a_time: Vec<f64> =
            states.iter().map(|s| residual_error_through(s, &template, &frame, &lens)).collect();
        let bits = |v: &[f64]| v.iter().map(|e| e.to_bits()).collect::<Vec<_>>();
        let mut batched = vec![-1.0; states.len()];
        residual_errors_of_through(&states, &template, &frame, &lens, &mut batched);
        prop_assert_eq!(bits(&batched), bits(&one_at_a_time));
        prop_assert_eq!(
            bits(&weigh_parallel_through(&states, &template, &frame, &lens)),
            bits(&one_at_a_time)
        );
    }
}

proptest! {
    /// The pose search's starting contrast: on a flat frame of level L, a template of gray G
    /// anywhere in view fits best at α = G / L (None where no point is in view); on any frame,
    /// grays c times as bright give c times the α.
    #[test]
    fn the_least_squares_gain_is_the_contrast_that_fits(
        (width, height) in (2u32..90, 2u32..70),
        seed in any::<u64>(),
        level in 1u8..=255,
        gray in 1.0f32..255.0,
        brighter in 0.25f32..4.0,
        points in prop::collection::vec(
            (prop::array::uniform3(-40.0f32..40.0), prop::array::uniform3(-1.0f32..1.0)),
            1..80,
        ),
        state in particle(),
    ) {
        let template_of = |gray_of: &dyn Fn(usize) -> f32| {
            Template::new(
                (points.iter().enumerate())
                    .map(|(i, (p, n))| FeaturePoint::new(*p, unit([n[0], n[1], n[2] + 1e-2]), gray_of(i)))
                    .collect(),
            )
            .unwrap()
        };
        let flat = GrayImage::new(width, height, vec![level; (width * height) as usize]).unwrap();
        let even = template_of(&|_| gray);
        if let Some(gain) = least_squares_gain(&state, &even, &flat, &Lens::WEAK) {
            let expected = gray / f32::from(level);
            prop_assert!((gain - expected).abs() <= 1e-4 * expected, "{} vs {}", gain, expected);
        }
        let black = GrayImage::new(width, height, vec![0; (width * height) as usize]).unwrap();
        prop_assert_eq!(least_squares_gain(&state, &even, &black, &Lens::WEAK), None);

        let textured = frame(width, height, seed);
        let varied = |i: usize| 4.0 + (i * 37 % 251) as f32;
        let dim = template_of(&varied);
        let bright = template_of(&|i| brighter * varied(i));
        let pair = (
            least_squares_gain(&state, &dim, &textured, &Lens::WEAK),
            least_squares_gain(&state, &bright, &textured, &Lens::WEAK),
        );
        match pair {
            (Some(a), Some(b)) => prop_assert!((b - brighter * a).abs() <= 1e-4 * b, "{} vs {} x {}", b, brighter, a),
            (a, b) => prop_assert_eq!(a.is_none(), b.is_none()),
        }
    }
}

#[test]
fn the_video_renderer_draws_what_each_frame_alone_draws_in_any_order() {
    let config = FaceSynthConfig {
        width: 320,
        height: 240,
        faces: 2,
        half_width: 24.0,
        frames: 30,
        ..FaceSynthConfig::paper(30)
    };
    let model = FaceModel::generic(65).unwrap();
    let renderer = FaceVideoRenderer::new(&config, &model).unwrap();
    // Forwards, backwards and jumping: the kept surfaces must follow the heads' scales. Frames
    // 10 to 19 carry the occluder.
    for frame in [0, 1, 2, 29, 15, 3, 12, 0, 28] {
        assert_eq!(
            renderer.render(frame).unwrap(),
            render_frame(&config, &model, frame).unwrap(),
            "frame {frame}"
        );
    }
    // Many frames at once (a frame per core, sharing the cached surfaces while the heads'
    // scales change under them), from a fresh renderer and from this one: the same frames.
    for renderer in [FaceVideoRenderer::new(&config, &model).unwrap(), renderer] {
        for (frame, image) in (0..30).zip(renderer.render_frames(0..30)) {
            assert_eq!(
                image.unwrap(),
                render_frame(&config, &model, frame).unwrap(),
                "frame {frame} of a batch"
            );
        }
    }
    let bad = FaceSynthConfig { faces: 0, ..config };
    assert!(FaceVideoRenderer::new(&bad, &model).is_err());
}
