//! The body tracker's whole step per frame — resample, diffuse, forward kinematics, the capsule
//! likelihood, normalise, weighted mean — on the GPU (`Backend::Gpu`: one submission, the frame's
//! rays the only upload) against all CPU cores (`Backend::Cpu`: the same filter with the culled
//! likelihood on rayon). Frames are synthetic (48 capsules, walking and waving, noise, dropout,
//! outliers); the camera's size sets the points: 160×120 gives about 1 000 points, 1024×768 about
//! 43 000 (the paper's largest cloud). GPU times include the host's ray preparation (Morton sort,
//! tile cones), the submission, the wait, the readback of the estimate and the host's check of
//! the estimate (its confidence, timed alone as `host_confidence`); `gpu_frames_in_flight` times
//! a stream of frames with each frame's preparation on a reader thread, overlapping the GPU's
//! step of the frame before, as `streampf body track` runs, and `gpu_two_steps_in_flight` the
//! same with two steps in flight on the GPU (frame t − 1 read while the GPU works on frame t). The step is the paper's: one
//! weighing a frame (`Annealing::none()`); `gpu_annealed_default` times the tracker's default,
//! eight annealing layers (the first seven coarse: at most 5 000 of the frame's points), on the
//! GPU (one frame at a time, and as a stream with two steps in flight:
//! `gpu_annealed_two_steps_in_flight`), and `gpu_annealed_every_point` the same layers each
//! weighing every point.

mod common;

use body_tracker::camera::Intrinsics;
use body_tracker::human::human_skeleton;
use body_tracker::likelihood::{CoarseLayers, Rays, culled_sum_of_squared_distances_parallel};
use body_tracker::synth::{SynthConfig, pose_at, render};
use body_tracker::{Backend, BodyTracker, TrackerConfig};
use common::context;
use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use nalgebra::Vector3;
use pf_core::anneal::Annealing;

const K: usize = 48;

/// `cargo bench` passes `--bench`; under `cargo test --benches` each benchmark runs once on tiny
/// sizes, as a smoke test.
fn full_size() -> bool {
    std::env::args().any(|a| a == "--bench")
}

/// Frame 10 of the default synthetic sequence seen by a `width × height` camera, and the pose
/// of frame 9 to start from.
fn frame(width: u32, height: u32) -> (Vec<Vector3<f32>>, Vec<f32>) {
    let skeleton = human_skeleton(K).unwrap();
    let config = SynthConfig {
        camera: Intrinsics::with_fov(width, height, 60.0).unwrap(),
        ..SynthConfig::small(20).unwrap()
    };
    let points = render(
        &skeleton,
        &pose_at(&skeleton, &config, 10).unwrap(),
        &config,
        10,
    )
    .unwrap()
    .points;
    (points, pose_at(&skeleton, &config, 9).unwrap())
}

fn tracker(
    particles: usize,
    points: usize,
    start: &[f32],
    backend: Backend,
    annealing: Annealing,
) -> BodyTracker {
    tracker_with(
        particles,
        points,
        start,
        backend,
        annealing,
        TrackerConfig::default().coarse,
    )
}

/// [`tracker`] with the given coarse layers (`None`: every layer weighs every point).
fn tracker_with(
    particles: usize,
    points: usize,
    start: &[f32],
    backend: Backend,
    annealing: Annealing,
    coarse: Option<CoarseLayers>,
) -> BodyTracker {
    let config = TrackerConfig {
        particles,
        max_points: points,
        annealing,
        coarse,
        ..TrackerConfig::default()
    };
    BodyTracker::new(human_skeleton(K).unwrap(), start, config, backend).unwrap()
}

/// Prints the step's own GPU time (timestamps) beside its wall clock over a few steps: how much
/// of a whole step is the GPU's work and how much the host's preparation and the round trip.
fn report_gpu_share(tracker: &mut BodyTracker, points: &[Vector3<f32>], label: &str) {
    const STEPS: u32 = 20;
    let (mut gpu, mut source) = (std::time::Duration::ZERO, "");
    let started = std::time::Instant::now();
    for _ in 0..STEPS {
        std::hint::black_box(tracker.step(points).unwrap());
        if let Some(time) = tracker.last_gpu_time() {
            gpu += time.duration();
            source = time.source();
        }
    }
    let wall = started.elapsed();
    eprintln!(
        "body_step/gpu_whole_step/{label}: {:.3} ms a step, {:.3} ms of it on the GPU ({source})",
        wall.as_secs_f64() * 1e3 / f64::from(STEPS),
        gpu.as_secs_f64() * 1e3 / f64::from(STEPS),
    );
}

/// `frames` steps as a stream runs them: a reader thread prepares each frame (rays, Morton
/// order, tile cones) while the tracker steps the one before (`streampf body track`). With
/// `two_on_gpu` the tracker also keeps two steps in flight on the GPU
/// (`BodyTracker::submit_prepared`, `finish`), reading frame t − 1 while the GPU works on frame
/// t. Criterion divides the time by `frames`: the time per frame, ray preparation included.
fn frames_in_flight(
    tracker: &mut BodyTracker,
    points: &[Vector3<f32>],
    frames: u64,
    two_on_gpu: bool,
) -> std::time::Duration {
    let preparer = tracker.preparer();
    let started = std::time::Instant::now();
    std::thread::scope(|scope| {
        let (send, prepared) = std::sync::mpsc::sync_channel(2);
        scope.spawn(move || {
            for _ in 0..frames {
                send.send(preparer.prepare(points).unwrap()).unwrap();
            }
        });
        for frame in prepared.iter() {
            if two_on_gpu {
                tracker.submit_prepared(frame).unwrap();
                if tracker.frames_in_flight() == 2 {
                    std::hint::black_box(tracker.finish().unwrap());
                }
            } else {
                std::hint::black_box(tracker.step_prepared(&frame).unwrap());
            }
        }
        while let Some(result) = tracker.finish().unwrap() {
            std::hint::black_box(result);
        }
    });
    started.elapsed()
}

fn bench(c: &mut Criterion) {
    let sizes: &[(usize, u32, u32)] = if full_size() {
        &[
            (1000, 160, 120),
            (1000, 320, 240),
            (3500, 320, 240),
            (3500, 1024, 768),
        ]
    } else {
        &[(20, 48, 36)]
    };
    let mut group = c.benchmark_group("body_step");
    group.sample_size(10);
    for &(j, width, height) in sizes {
        let (points, start) = frame(width, height);
        let i = points.len();
        let label = format!("j{j}_i{i}");
        group.throughput(Throughput::Elements((j * i * K) as u64));
        let gpu_tracker =
            |annealing| tracker(j, i, &start, Backend::Gpu(Box::new(context())), annealing);
        let mut gpu = gpu_tracker(Annealing::none());
        group.bench_function(BenchmarkId::new("gpu_whole_step", &label), |b| {
            b.iter(|| std::hint::black_box(gpu.step(&points).unwrap()))
        });
        report_gpu_share(&mut gpu, &points, &label);
        group.bench_function(BenchmarkId::new("gpu_frames_in_flight", &label), |b| {
            b.iter_custom(|frames| frames_in_flight(&mut gpu, &points, frames, false))
        });
        group.bench_function(BenchmarkId::new("gpu_two_steps_in_flight", &label), |b| {
            b.iter_custom(|frames| frames_in_flight(&mut gpu, &points, frames, true))
        });
        drop(gpu);
        let mut annealed = gpu_tracker(TrackerConfig::default().annealing);
        group.bench_function(BenchmarkId::new("gpu_annealed_default", &label), |b| {
            b.iter(|| std::hint::black_box(annealed.step(&points).unwrap()))
        });
        report_gpu_share(&mut annealed, &points, &format!("{label}_annealed"));
        group.bench_function(
            BenchmarkId::new("gpu_annealed_two_steps_in_flight", &label),
            |b| b.iter_custom(|frames| frames_in_flight(&mut annealed, &points, frames, true)),
        );
        drop(annealed);
        let mut every_point = tracker_with(
            j,
            i,
            &start,
            Backend::Gpu(Box::new(context())),
            TrackerConfig::default().annealing,
            None,
        );
        group.bench_function(BenchmarkId::new("gpu_annealed_every_point", &label), |b| {
            b.iter(|| std::hint::black_box(every_point.step(&points).unwrap()))
        });
        drop(every_point);
        let rays = Rays::through(Vector3::zeros(), &points).unwrap();
        let capsules = human_skeleton(K).unwrap().capsules(&start).unwrap();
        group.bench_function(BenchmarkId::new("host_confidence", &label), |b| {
            b.iter(|| {
                std::hint::black_box(culled_sum_of_squared_distances_parallel(
                    &capsules, &rays, 0.1,
                ))
            })
        });
        let mut cpu = tracker(j, i, &start, Backend::Cpu, Annealing::none());
        group.bench_function(BenchmarkId::new("cpu_all_cores", &label), |b| {
            b.iter(|| std::hint::black_box(cpu.step(&points).unwrap()))
        });
    }
    group.finish();
}

/// One GPU against every GPU (one island of the samples on each, `Backend::SplitGpus`) on the
/// tracker's default eight layers, at 1024×768 with all of its points: the split's own speed,
/// without the synthetic renderer that shares the host's cores in `body track --synthetic`.
/// Skipped, saying so, on a machine with fewer than two hardware GPUs.
fn over_gpus(c: &mut Criterion) {
    let count = pf_gpu::GpuContext::all(&pf_gpu::ContextOptions::default())
        .map(|all| all.len())
        .unwrap_or(0);
    if count < 2 {
        eprintln!("body_step_over_gpus: {count} hardware GPU(s); skipped");
        return;
    }
    let (samples, (width, height)): (&[usize], _) = if full_size() {
        (&[7000, 14000], (1024, 768))
    } else {
        (&[40], (48, 36))
    };
    let (points, start) = frame(width, height);
    let i = points.len();
    let mut group = c.benchmark_group("body_step_over_gpus");
    group.sample_size(10);
    for &j in samples {
        let label = format!("j{j}_i{i}");
        group.throughput(Throughput::Elements((j * i * K) as u64));
        let annealing = TrackerConfig::default().annealing;
        let mut one = tracker(
            j,
            i,
            &start,
            Backend::Gpu(Box::new(context())),
            annealing.clone(),
        );
        group.bench_function(BenchmarkId::new("one_gpu", &label), |b| {
            b.iter(|| std::hint::black_box(one.step(&points).unwrap()))
        });
        drop(one);
        let all = pf_gpu::GpuContext::all(&pf_gpu::ContextOptions::default()).unwrap();
        let mut split = tracker(j, i, &start, Backend::SplitGpus(all), annealing);
        group.bench_function(BenchmarkId::new("all_gpus", &label), |b| {
            b.iter(|| std::hint::black_box(split.step(&points).unwrap()))
        });
    }
    group.finish();
}

criterion_group!(benches, bench, over_gpus);
criterion_main!(benches);
