//! Tracking a short synthetic sequence (walking while waving, 1 000 points a frame with noise,
//! dropout, outliers and self-occlusion) on the CPU, on one GPU, and split over two GPU contexts,
//! against a filter with a flat likelihood.
//!
//! The threshold. With 256 particles over the 38 pose values of the 19-capsule body and the
//! tracker's default schedule (eight layers, partitioned: the trunk's four, then the limbs'), the
//! mean joint error over 20 frames measured 3.7 cm on the CPU, 3.0 cm on one lavapipe context and
//! 4.1 cm in two islands of 128 samples on two contexts (the paths draw the same random numbers,
//! but f32 sums on the GPU make their resampling part ways; the islands draw their own), against
//! 17.1-17.4 cm for the flat filter. The test asks for at most 6 cm and for at most 35 % of the
//! flat filter's error on the same frames; the islands for at most 1.5 × one context's error plus
//! 0.5 cm, and one island is exactly the one-GPU filter.
//!
//! Cost. A frame of 256 particles and eight layers takes seconds on lavapipe, so the GPU paths
//! share one test (one flat run on one context is their baseline: the flat filter only diffuses,
//! and its error is the same on every path to a few millimetres), and the tests of the engine's
//! plumbing (bit-identical results through a reader thread, frames in flight, one island) run
//! [`PLUMBING_PARTICLES`]: what they compare does not depend on the number of samples.

mod common;

use body_tracker::human::human_skeleton;
use body_tracker::likelihood::{CoarseLayers, Rays, culled_sum_of_squared_distances};
use body_tracker::synth::{SynthConfig, pose_at, render};
use body_tracker::{Backend, BodyTracker, Skeleton, TrackerConfig, Weighing, mean_joint_error};

const FRAMES: usize = 20;
const PARTICLES: usize = 256;
const MAX_ERROR_M: f32 = 0.06;
const MAX_RATIO_TO_FLAT: f32 = 0.35;
/// Samples of the tests that compare two ways of running the same filter bit for bit.
const PLUMBING_PARTICLES: usize = 64;

/// The mean joint error of a tracker over the sequence.
fn run(skeleton: &Skeleton, backend: Backend, weighing: Weighing, frames: usize) -> f32 {
    let config = TrackerConfig {
        particles: PARTICLES,
        weighing,
        ..TrackerConfig::default()
    };
    run_with(skeleton, backend, config, frames)
}

/// The mean joint error of a tracker of `config` over the sequence.
fn run_with(skeleton: &Skeleton, backend: Backend, config: TrackerConfig, frames: usize) -> f32 {
    let synth = SynthConfig::small(frames).unwrap();
    let start = pose_at(skeleton, &synth, 0).unwrap();
    let mut tracker = BodyTracker::new(skeleton.clone(), &start, config, backend).unwrap();
    let mut total = 0.0;
    for frame in 0..frames {
        let truth = pose_at(skeleton, &synth, frame).unwrap();
        let points = render(skeleton, &truth, &synth, frame).unwrap().points;
        assert!(points.len() > 500, "frame {frame}: {} points", points.len());
        let result = tracker.step(&points).unwrap();
        assert!(result.ess >= 1.0 && result.ess <= PARTICLES as f64 + 1e-3);
        total += mean_joint_error(skeleton, &result.pose, &truth).unwrap();
    }
    total / frames as f32
}

/// The test's tracker with six coarse layers of 250 points: about a quarter of these small
/// frames' points (the default subset holds them whole).
fn quarter_coarse() -> TrackerConfig {
    TrackerConfig {
        particles: PARTICLES,
        coarse: Some(CoarseLayers {
            points: 250,
            layers: 6,
        }),
        ..TrackerConfig::default()
    }
}

/// The tracker's and the flat filter's errors within the test's bounds.
fn assert_tracks(what: &str, tracked: f32, flat: f32) {
    eprintln!("mean joint error, {what}: tracker {tracked:.4} m, flat likelihood {flat:.4} m");
    assert!(
        tracked <= MAX_ERROR_M,
        "{what}: tracker error {tracked} m over {MAX_ERROR_M} m"
    );
    assert!(
        tracked <= MAX_RATIO_TO_FLAT * flat,
        "{what}: tracker {tracked} m is not far under the flat filter's {flat} m"
    );
}

#[test]
fn tracks_synthetic_walk_on_cpu() {
    let skeleton = human_skeleton(19).unwrap();
    let tracked = run(&skeleton, Backend::Cpu, Weighing::Capsules, FRAMES);
    let flat = run(&skeleton, Backend::Cpu, Weighing::Flat, FRAMES);
    assert_tracks("CPU", tracked, flat);
    // Coarse layers that see a quarter of the points (the default subset is larger than these
    // small frames) still track.
    let coarse = quarter_coarse();
    let coarse = run_with(&skeleton, Backend::Cpu, coarse, FRAMES);
    assert_tracks("CPU, six coarse layers of 250 points", coarse, flat);
}

/// One context, and the samples split into two islands on two contexts: each tracks, and the
/// islands about as well as the one context.
#[test]
fn tracks_synthetic_walk_on_one_gpu_and_split_over_two_contexts() {
    let skeleton = human_skeleton(19).unwrap();
    let context = || common::gpu_context("body tracking on the GPU");
    let (Some(one), Some(flat), Some(first), Some(second)) =
        (context(), context(), context(), context())
    else {
        return;
    };
    let flat = run(
        &skeleton,
        Backend::Gpu(Box::new(flat)),
        Weighing::Flat,
        FRAMES,
    );
    let one = run(
        &skeleton,
        Backend::Gpu(Box::new(one)),
        Weighing::Capsules,
        FRAMES,
    );
    assert_tracks("one GPU context", one, flat);
    let islands = run(
        &skeleton,
        Backend::SplitGpus(vec![first, second]),
        Weighing::Capsules,
        FRAMES,
    );
    assert_tracks("two islands on two contexts", islands, flat);
    assert!(
        islands <= 1.5 * one + 0.005,
        "two islands {islands} m against one context's {one} m"
    );
    // The GPU's coarse layers (a quarter of these frames' points, a second level of the
    // prepared rays) track too.
    let Some(coarse_context) = context() else {
        return;
    };
    let coarse = quarter_coarse();
    let coarse = run_with(
        &skeleton,
        Backend::Gpu(Box::new(coarse_context)),
        coarse,
        FRAMES,
    );
    assert_tracks(
        "one GPU context, six coarse layers of 250 points",
        coarse,
        flat,
    );
}

/// Coarse annealing layers weigh every k-th point with σ scaled to the subset, and the last
/// layer every point. A frame's log evidence is its first layer's weighing: with coarse layers
/// it is, bit for bit, that of a tracker without them stepping the subset (on the CPU, and on a
/// GPU context, whose subset is a second level of the frame's prepared rays), and not that of
/// one weighing every point; with one layer, which is the last, coarse layers change nothing.
#[test]
fn coarse_layers_weigh_every_kth_point_and_the_last_layer_every_point() {
    let skeleton = human_skeleton(19).unwrap();
    let (start, frames) = walk_frames(&skeleton, 2);
    let coarse = CoarseLayers {
        points: 200,
        layers: 7,
    };
    assert!(frames[0].len() > 2 * coarse.points);
    let with = TrackerConfig {
        particles: PLUMBING_PARTICLES,
        coarse: Some(coarse),
        ..TrackerConfig::default()
    };
    let without = TrackerConfig {
        coarse: None,
        ..with.clone()
    };
    let first = |config: &TrackerConfig, backend, subset: bool| -> (f64, Vec<f32>) {
        let mut tracker =
            BodyTracker::new(skeleton.clone(), &start, config.clone(), backend).unwrap();
        let points = if subset {
            coarse.subset(&frames[0])
        } else {
            frames[0].clone()
        };
        let result = tracker.step(&points).unwrap();
        (result.log_evidence, result.pose)
    };
    let cpu = first(&with, Backend::Cpu, false);
    assert_eq!(cpu.0, first(&without, Backend::Cpu, true).0);
    assert_ne!(cpu.0, first(&without, Backend::Cpu, false).0);
    let one_layer = |config: &TrackerConfig| TrackerConfig {
        annealing: pf_core::anneal::Annealing::none(),
        ..config.clone()
    };
    assert_eq!(
        first(&one_layer(&with), Backend::Cpu, false),
        first(&one_layer(&without), Backend::Cpu, false)
    );
    let context = || common::gpu_context("body coarse layers");
    let (Some(a), Some(b), Some(c), Some(d)) = (context(), context(), context(), context()) else {
        return;
    };
    let gpu = first(&with, Backend::Gpu(Box::new(a)), false);
    assert_eq!(gpu.0, first(&without, Backend::Gpu(Box::new(b)), true).0);
    assert_eq!(
        first(&one_layer(&with), Backend::Gpu(Box::new(c)), false),
        first(&one_layer(&without), Backend::Gpu(Box::new(d)), false)
    );
}

/// The poses a tracker of [`PLUMBING_PARTICLES`] estimates over `frames` frames.
fn poses(skeleton: &Skeleton, backend: Backend, frames: usize) -> Vec<Vec<f32>> {
    let synth = SynthConfig::small(frames).unwrap();
    let start = pose_at(skeleton, &synth, 0).unwrap();
    let config = TrackerConfig {
        particles: PLUMBING_PARTICLES,
        ..TrackerConfig::default()
    };
    let mut tracker = BodyTracker::new(skeleton.clone(), &start, config, backend).unwrap();
    (0..frames)
        .map(|frame| {
            let truth = pose_at(skeleton, &synth, frame).unwrap();
            let points = render(skeleton, &truth, &synth, frame).unwrap().points;
            tracker.step(&points).unwrap().pose
        })
        .collect()
}

#[test]
fn one_island_is_the_one_gpu_filter() {
    let skeleton = human_skeleton(19).unwrap();
    let context = || common::gpu_context("body tracking in one island");
    let (Some(a), Some(b)) = (context(), context()) else {
        return;
    };
    assert_eq!(
        poses(&skeleton, Backend::SplitGpus(vec![a]), 4),
        poses(&skeleton, Backend::Gpu(Box::new(b)), 4)
    );
}

/// The GPU weighs its own estimate in the step's submission (the confidence's M): the same as
/// the host's culled sum over the frame, to the capsule likelihood's tolerance.
#[test]
fn the_gpu_checks_its_estimate_as_the_host_does() {
    let Some(ctx) = common::gpu_context("the body estimate's check on the GPU") else {
        return;
    };
    let skeleton = human_skeleton(19).unwrap();
    let synth = SynthConfig::small(4).unwrap();
    let start = pose_at(&skeleton, &synth, 0).unwrap();
    let config = TrackerConfig {
        particles: PLUMBING_PARTICLES,
        ..TrackerConfig::default()
    };
    let tau = config.tau;
    let mut tracker = BodyTracker::new(
        skeleton.clone(),
        &start,
        config,
        Backend::Gpu(Box::new(ctx)),
    )
    .unwrap();
    for frame in 0..4 {
        let truth = pose_at(&skeleton, &synth, frame).unwrap();
        let points = render(&skeleton, &truth, &synth, frame).unwrap().points;
        let result = tracker.step(&points).unwrap();
        let rays = Rays::through(nalgebra::Vector3::zeros(), &points).unwrap();
        let host =
            culled_sum_of_squared_distances(&skeleton.capsules(&result.pose).unwrap(), &rays, tau);
        let host_confidence =
            (1.0 - host / (points.len() as f64 * f64::from(tau * tau))).clamp(0.0, 1.0);
        assert!(
            (f64::from(result.confidence) - host_confidence).abs() <= 2e-3,
            "frame {frame}: GPU confidence {} against the host's {host_confidence}",
            result.confidence
        );
    }
}

#[test]
fn bad_frames_are_errors() {
    let skeleton = human_skeleton(19).unwrap();
    let synth = SynthConfig::small(1).unwrap();
    let start = pose_at(&skeleton, &synth, 0).unwrap();
    let mut tracker = BodyTracker::new(
        skeleton.clone(),
        &start,
        TrackerConfig::default(),
        Backend::Cpu,
    )
    .unwrap();
    let nan = vec![nalgebra::Vector3::new(f32::NAN, 0.0, 3.0)];
    assert!(
        tracker
            .step(&nan)
            .unwrap_err()
            .to_string()
            .contains("not finite")
    );
    let at_camera = vec![nalgebra::Vector3::zeros()];
    assert!(tracker.step(&at_camera).is_err());
    // A pose of the wrong length, or a zero-particle filter, is refused at construction.
    assert!(
        BodyTracker::new(
            skeleton.clone(),
            &start[1..],
            TrackerConfig::default(),
            Backend::Cpu
        )
        .is_err()
    );
    let none = TrackerConfig {
        particles: 0,
        ..TrackerConfig::default()
    };
    assert!(BodyTracker::new(skeleton, &start, none, Backend::Cpu).is_err());
}

/// The first `count` frames of the short walk-wave, and the true pose to start from.
fn walk_frames(skeleton: &Skeleton, count: usize) -> (Vec<f32>, Vec<Vec<nalgebra::Vector3<f32>>>) {
    let synth = SynthConfig::small(count).unwrap();
    let frames = (0..count)
        .map(|f| {
            let truth = pose_at(skeleton, &synth, f).unwrap();
            render(skeleton, &truth, &synth, f).unwrap().points
        })
        .collect();
    (pose_at(skeleton, &synth, 0).unwrap(), frames)
}

/// Frames prepared on a reader thread ([`BodyTracker::preparer`], the CLI's frames in flight)
/// give the same poses, bit for bit, as stepping the points; and a frame prepared for another
/// tracker (the CPU's, or a GPU tracker with another number of points) is an error, not
/// garbage.
#[test]
fn frames_prepared_on_another_thread_track_bit_identically() {
    let skeleton = human_skeleton(19).unwrap();
    let context = || common::gpu_context("body frames prepared ahead");
    let (Some(a), Some(b)) = (context(), context()) else {
        return;
    };
    const FRAMES_AHEAD: usize = 5;
    let (start, frames) = walk_frames(&skeleton, FRAMES_AHEAD);
    let config = TrackerConfig {
        particles: PLUMBING_PARTICLES,
        ..TrackerConfig::default()
    };
    let new = |ctx| {
        BodyTracker::new(
            skeleton.clone(),
            &start,
            config.clone(),
            Backend::Gpu(Box::new(ctx)),
        )
        .unwrap()
    };
    let mut stepped = new(a);
    let want: Vec<Vec<f32>> = frames
        .iter()
        .map(|points| stepped.step(points).unwrap().pose)
        .collect();
    let mut ahead = new(b);
    let preparer = ahead.preparer();
    let got: Vec<Vec<f32>> = std::thread::scope(|scope| {
        let (send, prepared) = std::sync::mpsc::sync_channel(2);
        scope.spawn(|| {
            for points in &frames {
                send.send(preparer.prepare(points).unwrap()).unwrap();
            }
            drop(send);
        });
        prepared
            .iter()
            .map(|frame| ahead.step_prepared(&frame).unwrap().pose)
            .collect()
    });
    assert_eq!(got, want);
    let cpu = BodyTracker::new(skeleton.clone(), &start, config.clone(), Backend::Cpu).unwrap();
    let for_cpu = cpu.preparer().prepare(&frames[0]).unwrap();
    let error = ahead.step_prepared(&for_cpu).unwrap_err().to_string();
    assert!(error.contains("prepared for another tracker"), "{error}");
    let Some(c) = context() else {
        return;
    };
    let fewer = TrackerConfig {
        max_points: config.max_points / 2,
        ..config.clone()
    };
    let other = BodyTracker::new(skeleton.clone(), &start, fewer, Backend::Gpu(Box::new(c)));
    let for_other = other.unwrap().preparer().prepare(&frames[0]).unwrap();
    assert!(ahead.step_prepared(&for_other).is_err());
}

/// Frames in flight on the GPU ([`BodyTracker::submit_prepared`], [`BodyTracker::finish`]): two
/// submitted before the first is read give the poses of stepping one at a time, bit for bit, in
/// order; the CPU engine hands its results over the same way; a third frame in flight, a frame
/// stepped or particles read while frames are in flight, are errors.
#[test]
fn frames_in_flight_on_the_gpu_give_the_one_at_a_time_results() {
    let skeleton = human_skeleton(19).unwrap();
    let context = || common::gpu_context("body frames in flight");
    let (Some(a), Some(b)) = (context(), context()) else {
        return;
    };
    const FRAMES_IN_FLIGHT: usize = 6;
    let (start, frames) = walk_frames(&skeleton, FRAMES_IN_FLIGHT);
    let config = TrackerConfig {
        particles: PLUMBING_PARTICLES,
        ..TrackerConfig::default()
    };
    let new =
        |backend| BodyTracker::new(skeleton.clone(), &start, config.clone(), backend).unwrap();
    let mut one_at_a_time = new(Backend::Gpu(Box::new(a)));
    let want: Vec<_> = frames
        .iter()
        .map(|points| one_at_a_time.step(points).unwrap())
        .collect();
    let in_flight = |mut tracker: BodyTracker| {
        let preparer = tracker.preparer();
        let mut got = Vec::new();
        for points in &frames {
            tracker
                .submit_prepared(preparer.prepare(points).unwrap())
                .unwrap();
            if tracker.frames_in_flight() == 2 {
                got.push(tracker.finish().unwrap().unwrap());
            }
        }
        while let Some(result) = tracker.finish().unwrap() {
            got.push(result);
        }
        (tracker, got)
    };
    let (mut tracker, got) = in_flight(new(Backend::Gpu(Box::new(b))));
    assert_eq!(got, want);
    // Misuse: a third frame, a plain step or the particles while two are in flight.
    let prepare = |t: &BodyTracker| t.preparer().prepare(&frames[0]).unwrap();
    tracker.submit_prepared(prepare(&tracker)).unwrap();
    tracker.submit_prepared(prepare(&tracker)).unwrap();
    assert!(tracker.submit_prepared(prepare(&tracker)).is_err());
    assert!(tracker.step(&frames[0]).is_err());
    assert!(tracker.particles().is_err());
    assert!(tracker.finish().unwrap().is_some());
    assert!(tracker.finish().unwrap().is_some());
    assert!(tracker.finish().unwrap().is_none());
    assert!(tracker.particles().is_ok());
    // The CPU engine: the same results as its own steps, handed over in order.
    let mut cpu = new(Backend::Cpu);
    let cpu_want: Vec<_> = frames[..2].iter().map(|p| cpu.step(p).unwrap()).collect();
    let mut cpu = new(Backend::Cpu);
    let preparer = cpu.preparer();
    for points in &frames[..2] {
        cpu.submit_prepared(preparer.prepare(points).unwrap())
            .unwrap();
    }
    let cpu_got = vec![
        cpu.finish().unwrap().unwrap(),
        cpu.finish().unwrap().unwrap(),
    ];
    assert_eq!(cpu_got, cpu_want);
}
