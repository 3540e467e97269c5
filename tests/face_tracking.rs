//! Tracking a short synthetic video of two textured heads (turning up to ±50°, light changing,
//! an occluder passing over one) on the CPU and on the GPU, and failure detection when a face
//! walks out of the frame.
//!
//! Thresholds. With 256 particles per face over 30 frames of 640×480 and the tracker's default
//! annealing (five layers), the mean errors measured 1.6 px and 2.7° on both paths (2.8 px and
//! 4.8° with one layer). The test asks for at most 3 px and 4.5°: the eyes are about 25 px wide
//! and the brows and mouth 5–6 px tall, so a track within 3 px keeps the template's features on
//! their own structures, and 4.5° of rotation moves the face's outline by under 4 px.

mod common;

use face_tracker::extraction::{ExtractionConfig, FaceRect};
use face_tracker::model::FaceModel;
use face_tracker::projection::{RX, RY, RZ, SCALE, TX, TY};
use face_tracker::synth::{
    FaceSynthConfig, FaceVideoRenderer, HEIGHT_RATIO, face_state, initial_rect,
};
use face_tracker::tracker::in_flight::MAX_FRAMES_IN_FLIGHT;
use face_tracker::tracker::pose_errors;
use face_tracker::{FaceBackend, FaceEstimate, FaceTracker, FaceTrackerConfig, TrackStatus};

const MAX_TRANSLATION_PX: f32 = 3.0;
/// One frame of a track that started mid-video may stray further than the mean (the old bound
/// of the mean; measured up to 3.7 px).
const MAX_FRAME_TRANSLATION_PX: f32 = 5.0;
const MAX_ROTATION_DEG: f32 = 4.5;

fn video(frames: usize) -> FaceSynthConfig {
    FaceSynthConfig {
        width: 640,
        height: 480,
        faces: 2,
        half_width: 50.0,
        max_yaw: 50f32.to_radians(),
        ..FaceSynthConfig::paper(frames)
    }
}

fn config() -> FaceTrackerConfig {
    FaceTrackerConfig {
        particles: 256,
        best: 32,
        ..FaceTrackerConfig::default()
    }
}

/// Mean translation (px) and rotation (°) errors over the video, and each track's last status
/// (a lost track is reported once, at the frame it is lost).
fn run(video: &FaceSynthConfig, backend: FaceBackend) -> (f32, f32, Vec<TrackStatus>) {
    run_with(video, backend, config())
}

/// [`run`] with the tracker's settings given.
fn run_with(
    video: &FaceSynthConfig,
    backend: FaceBackend,
    config: FaceTrackerConfig,
) -> (f32, f32, Vec<TrackStatus>) {
    let model = FaceModel::generic(129).unwrap();
    let renderer = FaceVideoRenderer::new(video, &model).unwrap();
    let first = renderer.render(0).unwrap();
    let rects: Vec<_> = (0..video.faces).map(|k| initial_rect(video, k)).collect();
    let mut tracker = FaceTracker::new(&first, &rects, &model, config, backend).unwrap();
    let (mut translation, mut rotation, mut count) = (0.0, 0.0, 0);
    let mut statuses = vec![TrackStatus::Tracking; video.faces];
    for frame in 0..video.frames {
        let image = renderer.render(frame).unwrap();
        let estimates = tracker.step(&image).unwrap();
        for e in &estimates {
            // Tracks are numbered in the rectangles' order.
            statuses[e.track] = e.status;
            if e.status == TrackStatus::Tracking {
                let (t, r) = pose_errors(&e.state, &face_state(video, e.track, frame));
                translation += t;
                rotation += r;
                count += 1;
            }
        }
    }
    (
        translation / count as f32,
        rotation / count as f32,
        statuses,
    )
}

fn check(backend: impl Fn() -> Option<FaceBackend>) {
    let Some(backend) = backend() else { return };
    let (t, r, statuses) = run(&video(30), backend);
    eprintln!("mean errors: {t:.2} px, {r:.2}°");
    assert!(
        statuses.iter().all(|s| *s == TrackStatus::Tracking),
        "{statuses:?}"
    );
    assert!(t <= MAX_TRANSLATION_PX, "translation error {t} px");
    assert!(r <= MAX_ROTATION_DEG, "rotation error {r}°");
}

#[test]
fn tracks_two_faces_on_cpu() {
    check(|| Some(FaceBackend::Cpu));
}

/// Small synthetic faces (80 px wide) keep their pose with a template of one point per pixel of
/// the face's width (`ExtractionConfig::points_per_width`): the paper's 230 points packed into
/// so small a synthetic head take weak features that pin its pose worse. Over 60 frames turning
/// to 60°, measured 1.48 px and 3.81° against 3.87 px and 8.62° with 230. (Not the default: on
/// real faces fewer points lost pitch and yaw; docs/ACCURACY.md, "Small faces".)
#[test]
fn small_synthetic_faces_keep_their_pose_with_a_point_per_pixel() {
    let video = FaceSynthConfig {
        half_width: 40.0,
        max_yaw: 60f32.to_radians(),
        ..video(60)
    };
    let per_pixel = FaceTrackerConfig {
        extraction: ExtractionConfig {
            points_per_width: Some(1.0),
            ..ExtractionConfig::default()
        },
        ..config()
    };
    let (t, r, statuses) = run_with(&video, FaceBackend::Cpu, per_pixel);
    let (t_paper, r_paper, _) = run_with(&video, FaceBackend::Cpu, config());
    eprintln!("80 px faces: {t:.2} px, {r:.2}°; with 230 points {t_paper:.2} px, {r_paper:.2}°");
    assert!(
        statuses.iter().all(|s| *s == TrackStatus::Tracking),
        "{statuses:?}"
    );
    assert!(t <= 2.5 && r <= 5.0, "80 px faces: {t} px, {r}°");
    assert!(r < r_paper, "{r}° against {r_paper}° with 230 points");
}

#[test]
fn tracks_two_faces_on_gpu() {
    check(|| {
        common::gpu_context("face tracking on the GPU").map(|c| FaceBackend::Gpu(Box::new(c)))
    });
}

/// Two faces split over two GPU contexts, one face each: they track to the same bounds, and
/// exactly as on one GPU (each shard numbers its slots as the whole tracker does, so every slot
/// draws the numbers it draws on one GPU); the several-GPU path with one context is the one-GPU
/// tracker too.
#[test]
fn tracks_two_faces_split_over_two_gpu_contexts() {
    let context = || common::gpu_context("face tracking on two GPU contexts");
    check(|| Some(FaceBackend::Gpus(vec![context()?, context()?])));
    let (Some(a), Some(b), Some(c), Some(d)) = (context(), context(), context(), context()) else {
        return;
    };
    let short = video(6);
    let one_gpu = run(&short, FaceBackend::Gpu(Box::new(b)));
    assert_eq!(run(&short, FaceBackend::Gpus(vec![a])), one_gpu);
    assert_eq!(run(&short, FaceBackend::Gpus(vec![c, d])), one_gpu);
}

#[test]
fn a_face_leaving_the_frame_ends_its_track() {
    let video = FaceSynthConfig {
        exit_after: Some(8),
        return_at: None,
        crossing_at: None,
        occlusion: false,
        ..video(30)
    };
    let (_, _, statuses) = run(&video, FaceBackend::Cpu);
    // Face 0 is out of the frame by frame 8 + 320/30 ≈ 19; face 1 stays.
    match statuses[0] {
        TrackStatus::Lost { frame } => assert!((9..=25).contains(&frame), "lost at {frame}"),
        other => panic!("face 0 is still {other:?}"),
    }
    assert_eq!(statuses[1], TrackStatus::Tracking);
}

/// The confidence tells a track on its face from one that is not: on the textured heads it reads
/// CONFIDENCE_ON_FACE or more in every frame (measured 0.43–1.00 with the likelihood's
/// sharpness, 0.59–1.00 from the fit alone; the lowest as the light changes; the test runs the
/// same particles every time, on the CPU); the same tracks on a frame of uniform gray (a flat
/// wall), where α can match the template's mean level but not its pattern, read at most
/// CONFIDENCE_OFF_FACE: their fit alone read 0.05–0.08 there, and the likelihood is nearly
/// flat (the last layer's ESS 255 of 256 particles at full β, a sharpness of about 0.01), so
/// the confidence reads 0.0004–0.0005.
#[test]
fn the_confidence_tells_a_face_from_a_flat_wall() {
    const CONFIDENCE_ON_FACE: f32 = 0.4;
    // Below the wall's fit alone (0.05–0.08): the likelihood's sharpness brings it down.
    const CONFIDENCE_OFF_FACE: f32 = 0.01;
    let video = video(6);
    let model = FaceModel::generic(129).unwrap();
    let renderer = FaceVideoRenderer::new(&video, &model).unwrap();
    let first = renderer.render(0).unwrap();
    let rects: Vec<_> = (0..video.faces).map(|k| initial_rect(&video, k)).collect();
    let mut tracker = FaceTracker::new(&first, &rects, &model, config(), FaceBackend::Cpu).unwrap();
    for frame in 0..video.frames {
        for e in tracker.step(&renderer.render(frame).unwrap()).unwrap() {
            assert!(e.confidence >= CONFIDENCE_ON_FACE, "frame {frame}: {e:?}");
        }
    }
    let wall = face_tracker::GrayImage::filled(video.width, video.height, 120).unwrap();
    for e in tracker.step(&wall).unwrap() {
        assert!(e.confidence <= CONFIDENCE_OFF_FACE, "{e:?}");
    }
}

#[test]
fn a_lost_track_frees_its_slot_for_a_new_face() {
    let video = FaceSynthConfig {
        exit_after: Some(4),
        return_at: None,
        crossing_at: None,
        occlusion: false,
        ..video(30)
    };
    let model = FaceModel::generic(129).unwrap();
    let renderer = FaceVideoRenderer::new(&video, &model).unwrap();
    let first = renderer.render(0).unwrap();
    let mut tracker = FaceTracker::with_capacity(
        (video.width, video.height),
        1,
        &model,
        config(),
        FaceBackend::Cpu,
    )
    .unwrap();
    assert_eq!(
        tracker.add_face(&first, &initial_rect(&video, 0)).unwrap(),
        0
    );
    // The one slot is taken: a second face is refused with a clear error.
    let refused = tracker
        .add_face(&first, &initial_rect(&video, 1))
        .unwrap_err();
    assert!(refused.to_string().contains("slots are taken"), "{refused}");
    let mut lost_at = None;
    // Track 0's confidence per frame, until it is lost.
    let mut confidences = Vec::new();
    for frame in 0..video.frames {
        let image = renderer.render(frame).unwrap();
        let estimates = tracker.step(&image).unwrap();
        if lost_at.is_none() {
            assert_eq!(estimates.len(), 1);
            let e = &estimates[0];
            assert!((0.0..=1.0).contains(&e.confidence), "{}", e.confidence);
            assert!(e.ess >= 1.0 && e.ess <= 256.0 + 1e-3, "{}", e.ess);
            assert!(e.spread.iter().all(|s| s.is_finite() && *s >= 0.0));
            confidences.push(e.confidence);
            if let TrackStatus::Lost { frame } = estimates[0].status {
                lost_at = Some(frame);
                assert_eq!(tracker.free_slots(), 1);
                assert!(tracker.template(0).is_none());
                // The freed slot takes the other face, where it is now, as track 1, tracked from
                // the next frame.
                let rect = true_rect(&video, 1, frame);
                assert_eq!(tracker.add_face(&image, &rect).unwrap(), 1);
            }
        } else {
            assert_eq!(estimates.len(), 1, "only the new track is reported");
            let e = &estimates[0];
            assert_eq!((e.track, e.slot, e.status), (1, 0, TrackStatus::Tracking));
            let (t, _) = pose_errors(&e.state, &face_state(&video, 1, frame));
            // The new track started mid-video: its state is relative to that frame's pose, so
            // only the position is compared.
            assert!(
                t <= MAX_FRAME_TRANSLATION_PX,
                "new track {t} px off at frame {frame}"
            );
        }
    }
    assert!(lost_at.is_some_and(|f| f < 25), "{lost_at:?}");
    // The confidence falls as the face leaves, before the track is declared lost: the frames
    // just before the loss are far less sure than the first frames.
    eprintln!("track 0's confidence: {confidences:?}");
    let early = confidences[..4].iter().sum::<f32>() / 4.0;
    let before_loss = confidences[confidences.len() - 3..confidences.len() - 1]
        .iter()
        .sum::<f32>()
        / 2.0;
    assert!(
        before_loss < 0.5 * early,
        "confidence {before_loss} just before the loss, {early} at the start"
    );
}

/// The face rectangle of synthetic face `face` at `frame`: the tracker's rectangle, as a
/// detector would give it.
fn true_rect(video: &FaceSynthConfig, face: usize, frame: usize) -> FaceRect {
    let s = face_state(video, face, frame);
    let hw = video.half_width * s[SCALE];
    let hh = hw * HEIGHT_RATIO;
    FaceRect {
        x: s[TX] - hw,
        y: s[TY] - hh,
        width: 2.0 * hw,
        height: 2.0 * hh,
    }
}

/// A track restarted on a new template while its face is turned goes on from its pose: its
/// rotation and scale stay near the truth after the restart, where starting again from R = 0
/// and S = 1 would be off by the whole turn. Judged on the median of three filter seeds: with
/// 256 particles one seed's 10 frames after the restart scatter (2.1–4.6° over seeds 1–5 on
/// lavapipe), while the failure this guards against is off by the whole turn (over 15°).
#[test]
fn a_restarted_track_keeps_its_pose_on_cpu() {
    restarted_track_keeps_its_pose(|| FaceBackend::Cpu);
}

#[test]
fn a_restarted_track_keeps_its_pose_on_gpu() {
    if let Some(context) = common::gpu_context("a restarted track on the GPU") {
        restarted_track_keeps_its_pose(|| FaceBackend::Gpu(Box::new(context.clone())));
    }
}

fn restarted_track_keeps_its_pose(backend: impl Fn() -> FaceBackend) {
    let video = FaceSynthConfig {
        faces: 1,
        occlusion: false,
        ..video(30)
    };
    let model = FaceModel::generic(129).unwrap();
    let renderer = FaceVideoRenderer::new(&video, &model).unwrap();
    // The restart comes at the largest turn from the first frame's pose in frames 8–19.
    let mut unturned = face_state(&video, 0, 0);
    (unturned[RX], unturned[RY], unturned[RZ]) = (0.0, 0.0, 0.0);
    let turn = |frame| pose_errors(&unturned, &face_state(&video, 0, frame)).1;
    let restart_at = (8..20)
        .max_by(|&a, &b| turn(a).total_cmp(&turn(b)))
        .unwrap();
    assert!(
        turn(restart_at) > 15.0,
        "the face turned only {}°",
        turn(restart_at)
    );
    let mut runs: Vec<(f32, f32)> = (1..=3)
        .map(|seed| {
            let config = FaceTrackerConfig { seed, ..config() };
            errors_after_restart(&video, &renderer, &model, config, backend(), restart_at)
        })
        .collect();
    eprintln!(
        "turned {:.1}° at the restart (frame {restart_at}); after it, seeds 1–3: {runs:?} (rotation °, scale share)",
        turn(restart_at)
    );
    let median = |runs: &mut Vec<(f32, f32)>, key: fn(&(f32, f32)) -> f32| {
        runs.sort_by(|a, b| key(a).total_cmp(&key(b)));
        key(&runs[1])
    };
    let rotation = median(&mut runs, |r| r.0);
    let scale = median(&mut runs, |r| r.1);
    assert!(
        rotation <= MAX_ROTATION_DEG,
        "median rotation error {rotation}° after the restart"
    );
    assert!(
        scale <= 0.05,
        "median scale off by {scale} after the restart"
    );
}

/// The mean rotation error (°) and relative scale error of the one face over the frames after a
/// restart on the template taken at `restart_at`.
fn errors_after_restart(
    video: &FaceSynthConfig,
    renderer: &FaceVideoRenderer,
    model: &FaceModel,
    config: FaceTrackerConfig,
    backend: FaceBackend,
    restart_at: usize,
) -> (f32, f32) {
    let first = renderer.render(0).unwrap();
    let rect = initial_rect(video, 0);
    let mut tracker = FaceTracker::new(&first, &[rect], model, config, backend).unwrap();
    let mut unturned = face_state(video, 0, 0);
    (unturned[RX], unturned[RY], unturned[RZ]) = (0.0, 0.0, 0.0);
    let (mut rotation_after, mut scale_after) = (Vec::new(), Vec::new());
    for frame in 0..video.frames {
        let image = renderer.render(frame).unwrap();
        let e = tracker.step(&image).unwrap().remove(0);
        assert_eq!(e.status, TrackStatus::Tracking, "frame {frame}");
        let truth = face_state(video, 0, frame);
        if frame > restart_at {
            rotation_after.push(pose_errors(&e.state, &truth).1);
            // S is relative to the rectangle the track started from.
            scale_after.push((e.state[SCALE] * unturned[SCALE] / truth[SCALE] - 1.0).abs());
        }
        if frame == restart_at {
            let rect = true_rect(video, 0, frame);
            let restart = tracker
                .template_for_restart(0, &image, &rect, frame)
                .unwrap();
            tracker.restart_template(0, restart).unwrap();
        }
    }
    let mean = |v: &[f32]| v.iter().sum::<f32>() / v.len() as f32;
    (mean(&rotation_after), mean(&scale_after))
}

/// Every frame's estimates, stepped one at a time or with two frames in flight.
fn estimates_per_frame(
    video: &FaceSynthConfig,
    backend: FaceBackend,
    in_flight: bool,
) -> Vec<Vec<FaceEstimate>> {
    let model = FaceModel::generic(129).unwrap();
    let renderer = FaceVideoRenderer::new(video, &model).unwrap();
    let first = renderer.render(0).unwrap();
    let rects: Vec<_> = (0..video.faces).map(|k| initial_rect(video, k)).collect();
    let mut tracker = FaceTracker::new(&first, &rects, &model, config(), backend).unwrap();
    let mut out = Vec::new();
    for frame in 0..video.frames {
        let image = renderer.render(frame).unwrap();
        if !in_flight {
            out.push(tracker.step(&image).unwrap());
            continue;
        }
        tracker.submit(&image).unwrap();
        if tracker.frames_in_flight() == MAX_FRAMES_IN_FLIGHT {
            out.push(tracker.finish().unwrap().unwrap());
        }
    }
    while let Some(estimates) = tracker.finish().unwrap() {
        out.push(estimates);
    }
    out
}

/// Two frames in flight give the estimates of one frame at a time, bit for bit, frame by frame:
/// on the CPU, on a GPU context and split over two, through a track lost (face 0 walks out of
/// the frame) while the next frame was already in flight.
#[test]
fn frames_in_flight_give_the_estimates_of_one_frame_at_a_time() {
    let video = FaceSynthConfig {
        exit_after: Some(0),
        return_at: None,
        crossing_at: None,
        occlusion: false,
        ..video(22)
    };
    let context = || common::gpu_context("frames in flight on the GPU");
    type MakeBackend = Box<dyn Fn() -> Option<FaceBackend>>;
    let backends: Vec<(&str, MakeBackend)> = vec![
        ("cpu", Box::new(|| Some(FaceBackend::Cpu))),
        (
            "one gpu",
            Box::new(move || context().map(|c| FaceBackend::Gpu(Box::new(c)))),
        ),
        (
            "two gpu contexts",
            Box::new(move || Some(FaceBackend::Gpus(vec![context()?, context()?]))),
        ),
    ];
    for (name, backend) in backends {
        let (Some(one), Some(two)) = (backend(), backend()) else {
            continue;
        };
        let alone = estimates_per_frame(&video, one, false);
        assert_eq!(alone.len(), video.frames, "{name}");
        assert!(
            alone
                .iter()
                .flatten()
                .any(|e| e.track == 0 && matches!(e.status, TrackStatus::Lost { .. })),
            "{name}: face 0 was never lost, so the test does not reach a lost track"
        );
        assert_eq!(estimates_per_frame(&video, two, true), alone, "{name}");
    }
}

/// While frames are in flight the tracker refuses what would change a filter or wait on it.
#[test]
fn frames_in_flight_refuse_what_would_change_the_filters() {
    let video = video(3);
    let backends: Vec<FaceBackend> = [Some(FaceBackend::Cpu)]
        .into_iter()
        .chain([common::gpu_context("frames in flight on the GPU")
            .map(|c| FaceBackend::Gpu(Box::new(c)))])
        .flatten()
        .collect();
    for backend in backends {
        let model = FaceModel::generic(129).unwrap();
        let renderer = FaceVideoRenderer::new(&video, &model).unwrap();
        let first = renderer.render(0).unwrap();
        let mut tracker =
            FaceTracker::with_capacity((video.width, video.height), 2, &model, config(), backend)
                .unwrap();
        tracker.add_face(&first, &initial_rect(&video, 0)).unwrap();
        assert_eq!(tracker.finish().unwrap(), None);
        for frame in 0..MAX_FRAMES_IN_FLIGHT {
            tracker.submit(&renderer.render(frame).unwrap()).unwrap();
        }
        let refused = |e: Result<_, face_tracker::FaceError>| {
            e.expect_err("refused while frames are in flight")
                .to_string()
        };
        assert!(refused(tracker.submit(&first)).contains("in flight"));
        assert!(refused(tracker.step(&first).map(|_| ())).contains("in flight"));
        assert!(
            refused(
                tracker
                    .add_face(&first, &initial_rect(&video, 1))
                    .map(|_| ())
            )
            .contains("in flight")
        );
        assert!(refused(tracker.particles().map(|_| ())).contains("in flight"));
        let small = face_tracker::GrayImage::new(64, 64, vec![0; 64 * 64]).unwrap();
        assert_eq!(tracker.frames_in_flight(), MAX_FRAMES_IN_FLIGHT);
        tracker.finish().unwrap().unwrap();
        assert!(refused(tracker.submit(&small)).contains("64x64"));
        tracker.finish().unwrap().unwrap();
        assert_eq!(tracker.frames_in_flight(), 0);
        tracker.add_face(&first, &initial_rect(&video, 1)).unwrap();
        assert_eq!(tracker.step(&first).unwrap().len(), 2);
    }
}
