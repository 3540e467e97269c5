//! The initialisation thread and the tracker together: four synthetic faces enter a video one
//! after another; the Viola–Jones detector (opencv-data's frontal alt2 cascade) runs in its own
//! thread on every other frame and starts tracks. Every face must be found and tracked to the
//! end, and no face tracked twice.
//!
//! Thresholds. A face counts as found when a track starts within 8 frames of its entry plus the
//! detection delay (the detector sees every other frame and its result is used exactly `delay`
//! frames later; the rest is room for frames where the cascade misses the face). A track belongs to the face whose true
//! centre is nearest its estimate, and must stay within half a face width (25 px) of it: the
//! tracker's mean error on these videos is 2–5 px.

mod common;

use std::collections::BTreeMap;

use common::media;
use face_tracker::detect::{Cascade, FaceDetector, GpuCascade};
use face_tracker::extraction::FaceRect;
use face_tracker::model::FaceModel;
use face_tracker::projection::{TX, TY};
use face_tracker::synth::{FaceSynthConfig, FaceVideoRenderer, face_state, initial_rect};
use face_tracker::{
    AutoConfig, AutoFrame, AutoTracker, FaceBackend, FaceTracker, FaceTrackerConfig, TrackStatus,
};

const ENTER_EVERY: usize = 8;
const FRAMES: usize = 40;
const FOUND_WITHIN: usize = 8;
const MAX_DRIFT_PX: f32 = 25.0;

fn video() -> FaceSynthConfig {
    FaceSynthConfig {
        width: 640,
        height: 480,
        faces: 4,
        half_width: 50.0,
        max_yaw: 30f32.to_radians(),
        occlusion: false,
        enter_every: ENTER_EVERY,
        ..FaceSynthConfig::paper(FRAMES)
    }
}

fn auto_config(delay: usize) -> AutoConfig {
    let mut config = AutoConfig {
        detect_every: 2,
        max_faces: 6,
        detection_delay: Some(delay),
        tracker: FaceTrackerConfig {
            particles: 256,
            best: 32,
            ..FaceTrackerConfig::default()
        },
        ..AutoConfig::default()
    };
    // The faces are 100 px wide: smaller windows would only cost time.
    config.detect.min_size = 80;
    config
}

fn nearest_face(video: &FaceSynthConfig, frame: usize, x: f32, y: f32) -> (usize, f32) {
    (0..video.faces)
        .filter(|&k| video.present(k, frame))
        .map(|k| {
            let s = face_state(video, k, frame);
            (k, ((s[TX] - x).powi(2) + (s[TY] - y).powi(2)).sqrt())
        })
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .expect("a face in the frame")
}

fn cascade() -> Cascade {
    Cascade::load(&media::cascade_path("haarcascade_frontalface_alt2.xml")).unwrap()
}

/// Tracks the video with detections used `delay` frames after the frame they saw; returns what
/// happened at every frame.
fn run(backend: FaceBackend, detector: FaceDetector, delay: usize) -> Vec<AutoFrame> {
    let video = video();
    let model = FaceModel::generic(129).unwrap();
    let mut tracker = AutoTracker::new(
        (video.width, video.height),
        detector,
        &model,
        auto_config(delay),
        backend,
    )
    .unwrap();
    // Track → (face, frame it started).
    let mut owner: BTreeMap<usize, (usize, usize)> = BTreeMap::new();
    let mut last_frame_tracks = Vec::new();
    let renderer = FaceVideoRenderer::new(&video, &model).unwrap();
    let mut frames = Vec::new();
    for frame in 0..FRAMES {
        let out = tracker.step(&renderer.render(frame).unwrap()).unwrap();
        for (_, _, seen) in out.started.iter().chain(&out.restarted) {
            assert_eq!(seen + delay, frame, "a detection used at another delay");
        }
        for (track, rect, seen) in &out.started {
            let (cx, cy) = rect.centre();
            let (face, distance) = nearest_face(&video, *seen, cx, cy);
            assert!(
                distance < MAX_DRIFT_PX,
                "track {track} started {distance} px from face {face} (a detection on no face)"
            );
            owner.insert(*track, (face, frame));
        }
        let mut faces_now = Vec::new();
        for e in &out.estimates {
            let (face, distance) = nearest_face(&video, frame, e.state[TX], e.state[TY]);
            assert_eq!(
                e.status,
                TrackStatus::Tracking,
                "track {} (face {face}) lost at frame {frame}",
                e.track
            );
            assert_eq!(
                owner[&e.track].0, face,
                "track {} moved from face {} to face {face} at frame {frame}",
                e.track, owner[&e.track].0
            );
            assert!(
                distance < MAX_DRIFT_PX,
                "track {} is {distance} px from face {face} at frame {frame}",
                e.track
            );
            assert!(
                !faces_now.contains(&face),
                "face {face} is tracked twice at frame {frame}: {:?}",
                out.estimates
            );
            faces_now.push(face);
        }
        last_frame_tracks = faces_now;
        frames.push(out);
    }
    eprintln!("tracks (face, first frame): {owner:?}");
    for k in 0..video.faces {
        let starts: Vec<usize> = owner
            .values()
            .filter(|(face, _)| *face == k)
            .map(|(_, frame)| *frame)
            .collect();
        assert_eq!(starts.len(), 1, "face {k} got {} tracks", starts.len());
        let entry = video.entry_frame(k);
        assert!(
            (entry..=entry + delay + FOUND_WITHIN).contains(&starts[0]),
            "face {k} entered at frame {entry}, its track started at frame {}",
            starts[0]
        );
    }
    last_frame_tracks.sort();
    assert_eq!(last_frame_tracks, vec![0, 1, 2, 3]);
    frames
}

#[test]
fn four_entering_faces_are_each_found_once_on_cpu() {
    if media::opted_out("automatic tracking with opencv-data's cascade") {
        return;
    }
    run(FaceBackend::Cpu, cascade().into(), 2);
}

/// A delay of three detection periods: four frames are in the detector threads at once, their
/// answers come back in any order, and each is used exactly 6 frames after the frame it saw, so
/// two runs agree to the bit.
#[test]
fn detections_in_flight_are_used_at_their_delay_and_runs_repeat() {
    if media::opted_out("automatic tracking with opencv-data's cascade") {
        return;
    }
    let first = run(FaceBackend::Cpu, cascade().into(), 6);
    let second = run(FaceBackend::Cpu, cascade().into(), 6);
    assert_eq!(first, second);
}

/// The tracker and the detector both on the GPU (each a device of its own, as `face track`
/// opens them).
#[test]
fn four_entering_faces_are_each_found_once_on_gpu() {
    if media::opted_out("automatic tracking with opencv-data's cascade") {
        return;
    }
    let test = "automatic face tracking on the GPU";
    let (Some(tracker_ctx), Some(detector_ctx)) =
        (common::gpu_context(test), common::gpu_context(test))
    else {
        return;
    };
    let detector = GpuCascade::new(detector_ctx, cascade()).unwrap();
    run(FaceBackend::Gpu(Box::new(tracker_ctx)), detector.into(), 2);
}

/// A video's (or a shot's) first frames go to the detector one after another, whatever its
/// period: the identity scenario's four people, in the picture from frame 0, with the
/// detector's period at 10 frames and its results used a frame late, are each confirmed by
/// frame 1's detection and tracked from frame 2, not from frame 11.
#[test]
fn faces_in_a_videos_first_frames_are_confirmed_a_frame_later() {
    if media::opted_out("automatic tracking with opencv-data's cascade") {
        return;
    }
    let video = FaceSynthConfig::paper(300).exits_and_crossings(300);
    let model = FaceModel::generic(129).unwrap();
    let mut config = auto_config(1);
    config.detect_every = 10;
    let mut tracker = AutoTracker::new(
        (video.width, video.height),
        FaceDetector::from(cascade()),
        &model,
        config,
        FaceBackend::Cpu,
    )
    .unwrap();
    let renderer = FaceVideoRenderer::new(&video, &model).unwrap();
    let mut started = Vec::new();
    for frame in 0..3 {
        let out = tracker.step(&renderer.render(frame).unwrap()).unwrap();
        for (track, rect, seen) in &out.started {
            assert_eq!((frame, *seen), (2, 1), "track {track} started at {rect:?}");
            let (cx, cy) = rect.centre();
            started.push(nearest_face(&video, *seen, cx, cy).0);
        }
    }
    started.sort();
    assert_eq!(started, vec![0, 1, 2, 3]);
}

/// One face of 640×480, 100 px wide, walking 30 px a frame from frame 1 (`exit_after`), over
/// `frames` frames, with its model and renderer.
fn walking_face(frames: usize) -> (FaceSynthConfig, FaceModel, FaceVideoRenderer) {
    let video = FaceSynthConfig {
        width: 640,
        height: 480,
        faces: 1,
        half_width: 50.0,
        occlusion: false,
        exit_after: Some(0),
        ..FaceSynthConfig::paper(frames)
    };
    let model = FaceModel::generic(129).unwrap();
    let renderer = FaceVideoRenderer::new(&video, &model).unwrap();
    (video, model, renderer)
}

/// The walking face's rectangle at `frame`: its first one moved as the face has.
fn walking_rect(video: &FaceSynthConfig, frame: usize) -> FaceRect {
    let home = initial_rect(video, 0);
    let (now, start) = (face_state(video, 0, frame), face_state(video, 0, 0));
    FaceRect {
        x: home.x + now[TX] - start[TX],
        y: home.y + now[TY] - start[TY],
        ..home
    }
}

/// A track left behind by its face (the face jumps 150 px between two frames, farther than the
/// track can follow; its template then sits on background) has drifted: a detection of the face
/// near it would restart it (`AutoTracker::drifted_track`). A detection on the track is its
/// own face, and a face more than two widths away is not the track's.
#[test]
fn a_track_left_behind_by_its_face_is_found_drifted() {
    let (video, model, renderer) = walking_face(10);
    let mut tracker = AutoTracker::new(
        (video.width, video.height),
        FaceDetector::from(cascade()),
        &model,
        auto_config(0),
        FaceBackend::Cpu,
    )
    .unwrap();
    let (first, jumped) = (renderer.render(0).unwrap(), renderer.render(5).unwrap());
    let home = initial_rect(&video, 0);
    let track = tracker.add_face(&first, &home).unwrap();
    tracker.step(&first).unwrap();
    assert_eq!(tracker.drifted_track(&first, &home), None, "on its face");
    let at = |frame: usize| walking_rect(&video, frame);
    assert!(
        at(5).x - home.x > 100.0,
        "the face moved {}",
        at(5).x - home.x
    );
    tracker.step(&jumped).unwrap();
    assert_eq!(tracker.drifted_track(&jumped, &at(5)), Some(track));
    // Beyond two widths the detection is another face's, not this track's.
    let far = FaceRect {
        x: home.x + 250.0,
        ..home
    };
    let far_frame = renderer.render(9).unwrap();
    assert!(at(9).x - home.x > 250.0);
    assert_eq!(tracker.drifted_track(&far_frame, &far), None);
}

/// A face walking 30 px a frame outruns a track started on it at rest; one set moving at that
/// speed (`FaceTracker::set_track_drift`, as a face found walking by two detections is: half its
/// speed, the constant-velocity drift's share) stays on it. Setting a track that does not run
/// moving is an error.
#[test]
fn a_track_set_moving_keeps_up_with_a_walking_face() {
    let (video, model, renderer) = walking_face(12);
    let (start, last) = (2, 7);
    let at_start = face_state(&video, 0, start);
    let rect = walking_rect(&video, start);
    let walked = face_state(&video, 0, start + 1)[TX] - at_start[TX];
    assert!(
        (walked - 30.0).abs() < 3.0,
        "the face walks {walked} px a frame"
    );
    let error_at_last = |moving: bool| {
        let first = renderer.render(start).unwrap();
        let mut tracker = FaceTracker::new(
            &first,
            &[rect],
            &model,
            FaceTrackerConfig::default(),
            FaceBackend::Cpu,
        )
        .unwrap();
        if moving {
            let from = [rect.centre().0, rect.centre().1];
            let drift = [0.5 * walked, 0.0];
            tracker.set_track_drift(0, from, drift).unwrap();
            assert!(tracker.set_track_drift(7, from, drift).is_err());
        }
        let mut estimate = None;
        for frame in start + 1..=last {
            let out = tracker.step(&renderer.render(frame).unwrap()).unwrap();
            estimate = out.into_iter().find(|e| e.track == 0);
        }
        let e = estimate.expect("the track's estimate");
        (e.state[TX] - face_state(&video, 0, last)[TX]).abs()
    };
    let (at_rest, moving) = (error_at_last(false), error_at_last(true));
    eprintln!(
        "x error at frame {last}: started at rest {at_rest:.1} px, set moving {moving:.1} px"
    );
    assert!(
        moving < 20.0 && moving < 0.3 * at_rest,
        "{moving} vs {at_rest}"
    );
}
