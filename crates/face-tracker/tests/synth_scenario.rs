//! The identity scenario of the synthetic video (`FaceSynthConfig::exits_and_crossings`): the
//! first face leaves the picture and comes back to its place, faces 1 and 2 end in each other's
//! place, and face 3 stays.

use face_tracker::extraction::FaceRect;
use face_tracker::identity::{Identities, IdentityConfig, NewFace};
use face_tracker::model::FaceModel;
use face_tracker::projection::{TX, TY};
use face_tracker::synth::{FaceSynthConfig, FaceVideoRenderer, HEIGHT_RATIO, face_state};
use face_tracker::{FaceBackend, FaceTracker, FaceTrackerConfig};

#[test]
fn the_first_face_leaves_and_returns_and_two_faces_cross() {
    let sizes = [
        (90, 640, 480),
        (300, 1024, 768),
        (400, 1920, 1080),
        (300, 640, 480),
        (60, 320, 240),
        (40, 160, 120),
    ];
    for (frames, width, height) in sizes {
        let config = FaceSynthConfig {
            width,
            height,
            ..FaceSynthConfig::paper(1)
        }
        .exits_and_crossings(frames);
        config.validate().unwrap();
        let seen: Vec<bool> = (0..frames).map(|f| config.visible(0, f)).collect();
        // In the picture, then out for a stretch, then back in to the end.
        let first_out = seen.iter().position(|v| !v).expect("face 0 never leaves");
        let back = first_out
            + seen[first_out..]
                .iter()
                .position(|v| *v)
                .expect("never back");
        assert!(
            first_out > 0 && back > first_out + 3,
            "{frames}: out {first_out}, back {back}"
        );
        assert!(seen[back..].iter().all(|v| *v), "{frames}: leaves again");
        let start = face_state(&config, 0, 0);
        let end = face_state(&config, 0, frames - 1);
        assert!(
            (end[TX] - start[TX]).abs() < 90.0,
            "face 0 ends near its place"
        );
        // Faces 1 and 2 end in each other's place (within their wobble); face 3 is always in.
        for (k, other) in [(1, 2), (2, 1)] {
            let from = face_state(&config, other, 0);
            let to = face_state(&config, k, frames - 1);
            let apart = ((to[TX] - from[TX]).powi(2) + (to[TY] - from[TY]).powi(2)).sqrt();
            assert!(
                apart < 100.0,
                "{frames}: face {k} is {apart} px from face {other}'s place"
            );
        }
        assert!((0..frames).all(|f| config.visible(3, f)));
    }
}

/// The scenario made smaller is the same scenario: its walking face moves 30 px a frame at
/// 1024 px wide and in proportion at other widths, as its heads and places scale, so that it
/// crosses the frame in as many frames; only a video too short for that walks it faster (the
/// test above: it still leaves). A speed that is no number of pixels is refused.
#[test]
fn the_walking_face_keeps_pace_with_the_frame() {
    for (width, height, speed) in [(1024, 768, 30.0), (640, 480, 18.75), (1920, 1080, 56.25)] {
        let config = FaceSynthConfig {
            width,
            height,
            ..FaceSynthConfig::paper(1)
        }
        .exits_and_crossings(300);
        assert_eq!(config.walk_speed, speed, "{width}");
        let stepped = face_state(&config, 0, 100)[TX] - face_state(&config, 0, 99)[TX];
        assert!(
            (stepped - speed).abs() < 2.0,
            "{width}: {stepped} px a frame"
        );
    }
    let short = FaceSynthConfig::paper(1).exits_and_crossings(100);
    assert!(short.walk_speed > 30.0, "{}", short.walk_speed);
    assert_eq!(
        FaceSynthConfig::paper(100).walk_speed,
        30.0,
        "the paper's setting"
    );
    for bad in [f32::NAN, -1.0, f32::INFINITY] {
        let config = FaceSynthConfig {
            walk_speed: bad,
            ..FaceSynthConfig::paper(300).exits_and_crossings(300)
        };
        let err = config.validate().unwrap_err().to_string();
        assert!(err.contains("walking speed"), "{err}");
    }
}

/// The face rectangle of scenario face `k` at `frame`, as a detector would frame it.
fn true_rect(config: &FaceSynthConfig, k: usize, frame: usize) -> FaceRect {
    let s = face_state(config, k, frame);
    let width = 2.0 * config.half_width * s[face_tracker::projection::SCALE];
    let height = width * HEIGHT_RATIO;
    FaceRect {
        x: s[TX] - width / 2.0,
        y: s[TY] - height / 2.0,
        width,
        height,
    }
}

/// A person whose track ended is known again ([`Identities`]): the scenario's four people,
/// their tracks started at frame 0 and ended, are found at frame 266 (near frontal, face 0
/// back from its walk, faces 1 and 2 at each other's places) in another order, each given their
/// own identity; a person of another video, seen after every track ended, is a new identity.
#[test]
fn a_face_found_again_keeps_its_identity() {
    let config = FaceSynthConfig::paper(300).exits_and_crossings(300);
    let model = FaceModel::generic(129).unwrap();
    let renderer = FaceVideoRenderer::new(&config, &model).unwrap();
    let mut tracker = FaceTracker::with_capacity(
        (config.width, config.height),
        16,
        &model,
        FaceTrackerConfig::default(),
        FaceBackend::Cpu,
    )
    .unwrap();
    let mut identities = Identities::new(IdentityConfig::default());
    let start = |tracker: &mut FaceTracker, identities: &mut Identities, frame, rect| {
        let track = tracker.add_face(frame, &rect).unwrap();
        let face = NewFace {
            frame,
            rect: &rect,
            template: tracker.template(track).unwrap(),
            off_face_error: tracker.off_face_error(track).unwrap(),
        };
        (track, identities.start(track, &face, &tracker.lens()))
    };
    let first = renderer.render(0).unwrap();
    let mut first_tracks = Vec::new();
    for k in 0..4 {
        let (track, identity) = start(
            &mut tracker,
            &mut identities,
            &first,
            true_rect(&config, k, 0),
        );
        assert_eq!(identity, k, "a new face is a new identity");
        first_tracks.push(track);
    }
    first_tracks.iter().for_each(|&t| identities.end(t));
    let later = renderer.render(266).unwrap();
    for k in [2, 0, 3, 1] {
        assert!(config.visible(k, 266));
        let (_, identity) = start(
            &mut tracker,
            &mut identities,
            &later,
            true_rect(&config, k, 266),
        );
        assert_eq!(identity, k, "face {k} found again");
    }
    // Every track ends; someone never seen before comes.
    (4..8).for_each(|t| identities.end(t));
    let stranger = FaceSynthConfig {
        seed: config.seed + 1,
        ..config.clone()
    };
    let other = FaceVideoRenderer::new(&stranger, &model)
        .unwrap()
        .render(0)
        .unwrap();
    let (_, identity) = start(
        &mut tracker,
        &mut identities,
        &other,
        true_rect(&stranger, 0, 0),
    );
    assert_eq!(identity, 4, "a stranger matched a known person");
    assert_eq!(identities.len(), 5);
}

/// A face found again where a track was just lost is that track's person when their template
/// fits it better than background, though not well enough for the strict match
/// (`Identities::start_found_again`): face 0, its track started at frame 0 (near frontal) and
/// ended, turned 60° at frame 224, is not matched by its template's fit alone, but is when
/// found again where its track was lost. A person whose track still runs is not taken.
#[test]
fn a_face_found_again_where_its_track_was_lost_keeps_its_identity() {
    let config = FaceSynthConfig::paper(300).exits_and_crossings(300);
    let model = FaceModel::generic(129).unwrap();
    let renderer = FaceVideoRenderer::new(&config, &model).unwrap();
    let mut tracker = FaceTracker::with_capacity(
        (config.width, config.height),
        8,
        &model,
        FaceTrackerConfig::default(),
        FaceBackend::Cpu,
    )
    .unwrap();
    let first = renderer.render(0).unwrap();
    let rect = true_rect(&config, 0, 0);
    let track = tracker.add_face(&first, &rect).unwrap();
    let mut identities = Identities::new(IdentityConfig::default());
    let face = NewFace {
        frame: &first,
        rect: &rect,
        template: tracker.template(track).unwrap(),
        off_face_error: tracker.off_face_error(track).unwrap(),
    };
    assert_eq!(identities.start(track, &face, &tracker.lens()), 0);
    let running = identities.clone();
    identities.end(track);

    let turned = renderer.render(224).unwrap();
    assert!(config.visible(0, 224));
    let rect = true_rect(&config, 0, 224);
    let again = tracker.add_face(&turned, &rect).unwrap();
    let face = NewFace {
        frame: &turned,
        rect: &rect,
        template: tracker.template(again).unwrap(),
        off_face_error: tracker.off_face_error(again).unwrap(),
    };
    let lens = tracker.lens();
    assert_eq!(
        identities.clone().start(again, &face, &lens),
        1,
        "the template alone matched the turned face (the test needs a weaker fit)"
    );
    assert_eq!(identities.start_found_again(again, &face, &lens, track), 0);
    assert_eq!(
        running
            .clone()
            .start_found_again(again, &face, &lens, track),
        1,
        "a running track's person taken"
    );
}
