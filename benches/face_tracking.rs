//! The face paper's figures. Fig. 6: weighting time against the number of particles (one face,
//! 230 feature points, a 1024×768 frame). Fig. 7: the whole step against the number of faces
//! (1 … 64 faces × 1000 particles, 1024×768): frame upload, weighting, resampling, diffusion and
//! the best-M′ estimate. Variants: one CPU thread, all CPU cores, and the GPU (for Fig. 6 the
//! likelihood stage alone, one face, so the paper's per-face dispatch; for Fig. 7 the tracker's
//! whole step, all faces weighed in one dispatch of the packed kernel; set
//! `FaceTrackerConfig::gpu_dispatch` to `Batched` for the paper's layout). `face_step_over_gpus`:
//! 64, 256 and 1 024 faces on one GPU and split over every GPU (where there are two or more),
//! one frame at a time and with two frames in flight. `face_step_lag_smoothing`: what smoothing
//! with a lag of 8 (from the ancestry read back, from the ancestry kept on the GPU, or the
//! marginal smoother) adds to the step. `STREAMPF_BENCH_GROUPS=lag_smoothing,fig7` sets up only
//! those groups (criterion's filter skips measurements, not a group's minutes of set-up).
//! GPU times include the submission, the wait and the readback. Fig. 6 also times the plain C
//! loop of the same arithmetic on one thread (benches/baseline/), the CPU reference's yardstick,
//! and the one-thread reference built without AVX2.

#[path = "baseline/mod.rs"]
mod baseline;
mod common;
#[path = "face_weighing/mod.rs"]
mod face_weighing;

use common::context;
use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use face_tracker::extraction::FaceRect;
use face_tracker::likelihood::gpu::{FaceDispatch, FaceLikelihoodGpu};
use face_tracker::likelihood::{
    MIN_ERROR, MIN_VISIBLE_SHARE, residual_errors_of_baseline, weigh_parallel, weigh_single_thread,
};
use face_tracker::model::FaceModel;
use face_tracker::projection::DIMS;
use face_tracker::synth::{
    FaceSynthConfig, FaceVideoRenderer, face_state, initial_rect, render_frame,
};
use face_tracker::tracker::in_flight::MAX_FRAMES_IN_FLIGHT;
use face_tracker::{FaceBackend, FaceEstimate, FaceTracker, FaceTrackerConfig, GrayImage};
use pf_core::batch::{BatchConfig, BatchShape, gaussian_clouds};
use pf_core::smooth_tracks::{LagSmoother, LaggedTracks, TrackSmoother};
use pf_gpu::stream::DeviceStream;
use pf_gpu::{GpuContext, GpuFilter, GpuLikelihood, GpuResampler, GpuStage};

fn full_size() -> bool {
    std::env::args().any(|a| a == "--bench")
}

/// A 16-face synthetic frame (1024×768 at full size), its rectangles repeated to `faces`.
fn scene(faces: usize) -> (GrayImage, Vec<FaceRect>, FaceModel, FaceSynthConfig) {
    let config = if full_size() {
        FaceSynthConfig {
            faces: 16,
            half_width: 30.0,
            occlusion: false,
            ..FaceSynthConfig::paper(2)
        }
    } else {
        FaceSynthConfig {
            faces: 4,
            width: 256,
            height: 192,
            half_width: 20.0,
            occlusion: false,
            ..FaceSynthConfig::paper(2)
        }
    };
    let model = FaceModel::generic(129).unwrap();
    let frame = render_frame(&config, &model, 0).unwrap();
    let rects = (0..faces)
        .map(|k| initial_rect(&config, k % config.faces))
        .collect();
    (frame, rects, model, config)
}

fn fig6(c: &mut Criterion, ctx: &GpuContext) {
    let mut group = c.benchmark_group("face_weighting_vs_particles");
    group.sample_size(10);
    let (frame, rects, model, config) = scene(1);
    let tracker_config = FaceTrackerConfig::default();
    let template = face_tracker::extraction::extract_template(
        &frame,
        &rects[0],
        &model,
        &tracker_config.extraction,
    )
    .unwrap();
    let sizes: &[usize] = if full_size() {
        &[100, 500, 1000, 2000, 5000, 10_000]
    } else {
        &[10]
    };
    for &m in sizes {
        let shape = BatchShape::new(1, m, DIMS).unwrap();
        let truth = face_state(&config, 0, 1);
        let sigma = [4.0, 4.0, 0.02, 0.05, 0.05, 0.05, 0.02];
        let layout = gaussian_clouds(&shape, 3, &truth, &sigma);
        let states: Vec<[f32; DIMS]> = (0..m)
            .map(|p| std::array::from_fn(|d| layout[shape.state_index(0, d, p)]))
            .collect();
        group.throughput(Throughput::Elements((m * template.len()) as u64));
        group.bench_function(BenchmarkId::new("cpu_one_thread", m), |b| {
            b.iter(|| std::hint::black_box(weigh_single_thread(&states, &template, &frame)))
        });
        // The same lanes built for the baseline x86-64 target (no AVX2), for comparison.
        group.bench_function(BenchmarkId::new("cpu_one_thread_baseline_target", m), |b| {
            b.iter(|| {
                let mut errors = vec![0.0; states.len()];
                residual_errors_of_baseline(&states, &template, &frame, &mut errors);
                std::hint::black_box(errors)
            })
        });
        // The yardstick of the one-thread reference: the same arithmetic as a plain C loop.
        group.bench_function(BenchmarkId::new("plain_c_loop_one_thread", m), |b| {
            b.iter(|| {
                let errors: Vec<f64> = states
                    .iter()
                    .map(|s| baseline::face_residual_c(s, &template, &frame))
                    .collect();
                std::hint::black_box(errors)
            })
        });
        group.bench_function(BenchmarkId::new("cpu_all_cores", m), |b| {
            b.iter(|| std::hint::black_box(weigh_parallel(&states, &template, &frame)))
        });
        let batch = BatchConfig {
            shape,
            seed: 1,
            sigma: sigma.to_vec(),
            bounds: None,
            angular: vec![false, false, false, true, true, true, false],
            ess_threshold: f64::INFINITY,
            best: 0,
            annealing: Default::default(),
            motion: Default::default(),
        };
        let mut filter = GpuFilter::new(ctx, &batch, GpuResampler::Systematic, &layout).unwrap();
        let mut gpu = FaceLikelihoodGpu::new(
            ctx,
            FaceDispatch::PerFace,
            1,
            template.len(),
            frame.width,
            frame.height,
            1.0,
            MIN_ERROR,
            MIN_VISIBLE_SHARE,
            face_tracker::likelihood::Lens::WEAK,
        )
        .unwrap();
        gpu.upload_frame(ctx, &frame.data).unwrap();
        gpu.upload_template(ctx, 0, &template.gpu_layout()).unwrap();
        gpu.prepare(ctx, &filter.likelihood_inputs()).unwrap();
        group.bench_function(BenchmarkId::new("gpu", m), |b| {
            b.iter(|| {
                std::hint::black_box(
                    filter
                        .run_stages(ctx, &[GpuStage::Likelihood], &gpu)
                        .unwrap(),
                )
            })
        });
    }
    group.finish();
}

/// Prints the median GPU time of the step's submission (timestamps where the adapter has them)
/// beside the median host wall time of the whole step: the rest is the host's share (upload,
/// submission, wait, readback, the estimates' ε check).
fn report_gpu_share(tracker: &mut FaceTracker, frame: &GrayImage, faces: usize) {
    let mut gpu = Vec::new();
    let mut wall = Vec::new();
    // The host's two halves of a step: submit (the frame's upload, recording, submission) and
    // finish (the wait, the readback, the estimates).
    let (mut submit, mut finish) = (Vec::new(), Vec::new());
    for _ in 0..50 {
        let started = std::time::Instant::now();
        tracker.submit(frame).unwrap();
        let submitted = started.elapsed();
        tracker.finish().unwrap();
        let finished = started.elapsed();
        submit.push(submitted.as_secs_f64() * 1e6);
        finish.push((finished - submitted).as_secs_f64() * 1e6);
        wall.push(finished.as_secs_f64() * 1e6);
        if let Some(time) = tracker.last_gpu_time() {
            gpu.push((time.duration().as_secs_f64() * 1e6, time.source()));
        }
    }
    // Two frames in flight, as `face track` streams them: a frame's share of the stream.
    let streamed = 50;
    let started = std::time::Instant::now();
    tracker.submit(frame).unwrap();
    for _ in 1..streamed {
        tracker.submit(frame).unwrap();
        tracker.finish().unwrap();
    }
    tracker.finish().unwrap();
    let per_streamed = started.elapsed().as_secs_f64() * 1e6 / streamed as f64;
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let source = gpu.first().map_or("none", |g| g.1);
    let mut gpu: Vec<f64> = gpu.into_iter().map(|g| g.0).collect();
    eprintln!(
        "face step, {faces} faces: median {:.1} us per step, of which the submission took {:.1} us on the GPU ({source}); the host's submit {:.1} us and finish {:.1} us (medians); two frames in flight {per_streamed:.1} us a frame",
        median(&mut wall),
        median(&mut gpu),
        median(&mut submit),
        median(&mut finish),
    );
}

/// The median GPU time of `tracker`'s whole step over 50 steps, one at a time (timestamps
/// around the submission where the adapter has them), named `what`: the measure of what a
/// step's extra work costs the GPU, steadier between processes than the whole step's wall time.
fn report_step_gpu_time(tracker: &mut FaceTracker, frame: &GrayImage, what: &str) {
    let mut times: Vec<f64> = (0..50)
        .filter_map(|_| {
            tracker.step(frame).ok()?;
            Some(tracker.last_gpu_time()?.duration().as_secs_f64() * 1e6)
        })
        .collect();
    if times.is_empty() {
        eprintln!("{what}: no GPU times (the adapter has no timestamps)");
        return;
    }
    times.sort_by(f64::total_cmp);
    eprintln!(
        "{what}: the step's GPU time, median of {} steps: {:.1} us",
        times.len(),
        times[times.len() / 2]
    );
}

/// Where the face step's GPU time goes, dispatch by dispatch (`FaceTracker::profile_dispatches`).
fn report_face_dispatches(tracker: &mut FaceTracker, frame: &GrayImage, faces: usize) {
    report_dispatches(tracker, frame, &format!("face step, {faces} faces"));
}

/// [`report_face_dispatches`] under the name `what`.
fn report_dispatches(tracker: &mut FaceTracker, frame: &GrayImage, what: &str) {
    if let Err(e) = tracker.profile_dispatches(true) {
        eprintln!("{what}: dispatch profile: {e}");
        return;
    }
    common::report_dispatch_profile(what, || {
        tracker.step(frame).ok()?;
        tracker.dispatch_times().ok()
    });
    tracker.profile_dispatches(false).unwrap();
}

/// The whole step with the faces split over every hardware GPU (`FaceBackend::Gpus`) against
/// one of them, at loads that fill one GPU, each one frame at a time and with two frames in
/// flight. With one hardware GPU only the one-GPU variants run.
fn over_gpus(c: &mut Criterion) {
    let Ok(all) = GpuContext::all(&pf_gpu::ContextOptions::default()) else {
        eprintln!("face_step_over_gpus: no hardware GPUs; skipped");
        return;
    };
    let several = all.len() >= 2;
    let names: Vec<String> = all.iter().map(|c| c.adapter().name.clone()).collect();
    eprintln!(
        "face_step_over_gpus: {} GPUs: {}",
        all.len(),
        names.join(", ")
    );
    drop(all);
    let mut group = c.benchmark_group("face_step_over_gpus");
    group.sample_size(10);
    let counts: &[usize] = if full_size() { &[64, 256, 1024] } else { &[2] };
    let particles = if full_size() { 1000 } else { 50 };
    // The GPU's own time for a step (timestamps, the slowest GPU's), beside criterion's wall
    // time: what part of a step is the GPUs' work, which splits, and what is the round trip.
    let gpu_ms = |t: Option<pf_gpu::GpuTime>| {
        t.map_or("-".to_string(), |t| {
            format!("{:.3} ms ({t:?})", t.duration().as_secs_f64() * 1e3)
        })
    };
    for &faces in counts {
        let (frame, rects, model, _) = scene(faces);
        let config = FaceTrackerConfig {
            particles,
            best: particles / 10,
            ..FaceTrackerConfig::default()
        };
        group.throughput(Throughput::Elements((faces * particles) as u64));
        let mut one = FaceTracker::new(
            &frame,
            &rects,
            &model,
            config.clone(),
            FaceBackend::Gpu(Box::new(context())),
        )
        .unwrap();
        group.bench_function(BenchmarkId::new("one_gpu", faces), |b| {
            b.iter(|| std::hint::black_box(one.step(&frame).unwrap()))
        });
        eprintln!(
            "face_step_over_gpus/{faces}: one GPU's own time for the last step: {}",
            gpu_ms(one.last_gpu_time())
        );
        group.bench_function(BenchmarkId::new("one_gpu_two_in_flight", faces), |b| {
            b.iter(|| std::hint::black_box(step_in_flight(&mut one, &frame)))
        });
        drop(one);
        if !several {
            eprintln!("face_step_over_gpus: one GPU; the split over GPUs skipped");
            continue;
        }
        let contexts = GpuContext::all(&pf_gpu::ContextOptions::default()).unwrap();
        let mut split =
            FaceTracker::new(&frame, &rects, &model, config, FaceBackend::Gpus(contexts)).unwrap();
        group.bench_function(BenchmarkId::new("all_gpus", faces), |b| {
            b.iter(|| std::hint::black_box(split.step(&frame).unwrap()))
        });
        eprintln!(
            "face_step_over_gpus/{faces}: the slowest GPU's own time for the last step: {}",
            gpu_ms(split.last_gpu_time())
        );
        group.bench_function(BenchmarkId::new("all_gpus_two_in_flight", faces), |b| {
            b.iter(|| std::hint::black_box(step_in_flight(&mut split, &frame)))
        });
    }
    group.finish();
}

/// One frame of a stream with two frames in flight: submits `frame` and, once two are in
/// flight, finishes the oldest (a frame's time in the steady state).
fn step_in_flight(tracker: &mut FaceTracker, frame: &GrayImage) -> Option<Vec<FaceEstimate>> {
    tracker.submit(frame).unwrap();
    if tracker.frames_in_flight() < MAX_FRAMES_IN_FLIGHT {
        return None;
    }
    tracker.finish().unwrap()
}

/// The synthetic video's renderer (the README's main job renders every frame): frame after
/// frame of the paper's 1024×768 four-face video, as `face track --synthetic` reads them.
fn render(c: &mut Criterion) {
    let mut group = c.benchmark_group("synthetic_face_video");
    group.sample_size(10);
    let frames = if full_size() { 100 } else { 3 };
    let config = FaceSynthConfig::paper(frames);
    let model = FaceModel::generic(129).unwrap();
    let renderer = FaceVideoRenderer::new(&config, &model).unwrap();
    let mut frame = 0;
    group.bench_function("render_frame", |b| {
        b.iter(|| {
            frame = (frame + 1) % frames;
            std::hint::black_box(renderer.render(frame).unwrap())
        })
    });
    // As `face track --synthetic` reads them: a frame per core at once. Criterion's time is
    // per batch; its throughput line gives frames per second.
    let batch = rayon::current_num_threads().min(frames);
    group.throughput(Throughput::Elements(batch as u64));
    let mut first = 0;
    group.bench_function(format!("render_{batch}_frames_at_once"), |b| {
        b.iter(|| {
            first = (first + batch) % (frames - batch + 1);
            std::hint::black_box(renderer.render_frames(first..first + batch))
        })
    });
    group.finish();
}

fn fig7(c: &mut Criterion) {
    let mut group = c.benchmark_group("face_step_vs_faces");
    group.sample_size(10);
    let counts: &[usize] = if full_size() { &[1, 4, 16, 64] } else { &[2] };
    let particles = if full_size() { 1000 } else { 50 };
    for &faces in counts {
        let (frame, rects, model, _) = scene(faces);
        let config = FaceTrackerConfig {
            particles,
            best: particles / 10,
            ..FaceTrackerConfig::default()
        };
        group.throughput(Throughput::Elements((faces * particles) as u64));
        let mut gpu = FaceTracker::new(
            &frame,
            &rects,
            &model,
            config.clone(),
            FaceBackend::Gpu(Box::new(context())),
        )
        .unwrap();
        // Reported once, and only when this benchmark is selected.
        let mut reported = false;
        group.bench_function(BenchmarkId::new("gpu", faces), |b| {
            b.iter(|| std::hint::black_box(gpu.step(&frame).unwrap()));
            if !reported {
                report_gpu_share(&mut gpu, &frame, faces);
                if full_size() {
                    report_face_dispatches(&mut gpu, &frame, faces);
                }
                reported = true;
            }
        });
        drop(gpu);
        // The packed kernel with other lanes a particle than the tracker's (docs/BENCHMARKS.md,
        // "Lanes a particle").
        let lanes: &[u32] = if full_size() {
            &[4, 8, 16, 32, 128]
        } else {
            &[16]
        };
        for &lanes in lanes {
            let config = FaceTrackerConfig {
                gpu_dispatch: FaceDispatch::Packed { lanes },
                ..config.clone()
            };
            let backend = FaceBackend::Gpu(Box::new(context()));
            let mut gpu = FaceTracker::new(&frame, &rects, &model, config, backend).unwrap();
            let name = format!("gpu_{lanes}_lanes");
            let mut reported = false;
            group.bench_function(BenchmarkId::new(name, faces), |b| {
                b.iter(|| std::hint::black_box(gpu.step(&frame).unwrap()));
                if !reported && full_size() {
                    eprintln!("{lanes} lanes a particle:");
                    report_face_dispatches(&mut gpu, &frame, faces);
                    reported = true;
                }
            });
        }
        let mut cpu =
            FaceTracker::new(&frame, &rects, &model, config.clone(), FaceBackend::Cpu).unwrap();
        group.bench_function(BenchmarkId::new("cpu_all_cores", faces), |b| {
            b.iter(|| std::hint::black_box(cpu.step(&frame).unwrap()))
        });
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        let mut single =
            FaceTracker::new(&frame, &rects, &model, config, FaceBackend::Cpu).unwrap();
        group.bench_function(BenchmarkId::new("cpu_one_thread", faces), |b| {
            b.iter(|| one.install(|| std::hint::black_box(single.step(&frame).unwrap())))
        });
    }
    group.finish();
}

/// The frame's share of a step: the face likelihood's upload of an 8-bit frame (split over the
/// cores) then an empty submission and the wait, against one upload of the frame as f32 levels,
/// and the empty submission alone.
fn frame_upload(c: &mut Criterion, ctx: &GpuContext) {
    let mut group = c.benchmark_group("face_frame_upload");
    group.sample_size(10);
    let (frame, ..) = scene(1);
    let likelihood = FaceLikelihoodGpu::new(
        ctx,
        FaceDispatch::PackedByLoad,
        1,
        1,
        frame.width,
        frame.height,
        1.0,
        MIN_ERROR,
        MIN_VISIBLE_SHARE,
        face_tracker::likelihood::Lens::WEAK,
    )
    .unwrap();
    let floats: Vec<f32> = frame.data.iter().map(|&v| f32::from(v)).collect();
    let float_stream = DeviceStream::<f32>::zeroed(ctx, "f32 frame", floats.len()).unwrap();
    let wait = || {
        let index = ctx.queue.submit([]);
        ctx.wait(Some(index), "the upload").unwrap();
    };
    group.bench_function("upload_8bit", |b| {
        b.iter(|| {
            likelihood.upload_frame(ctx, &frame.data).unwrap();
            wait();
        })
    });
    group.bench_function("upload_f32", |b| {
        b.iter(|| {
            float_stream.upload(ctx, &floats).unwrap();
            wait();
        })
    });
    group.bench_function("empty_submit_wait", |b| b.iter(wait));
    group.finish();
}

/// What smoothing with a lag of 8 adds to the face step on the GPU (1 000 particles a face,
/// 1024×768): the step alone; with the lineage kept (composed in each layer's select where the
/// adapter allows, else a dispatch more per layer); with every
/// tracked face's particles and lineage read back each frame (what a host smoother needs); with
/// the ancestry smoother, or the marginal smoother on the same GPU, writing the frame eight
/// back; and with the ancestry's lag window kept on the GPU (no particles read back).
fn lag_smoothing(c: &mut Criterion) {
    let mut group = c.benchmark_group("face_step_lag_smoothing");
    group.sample_size(10);
    let counts: &[usize] = if full_size() { &[4, 64] } else { &[2] };
    let particles = if full_size() { 1000 } else { 50 };
    const LAG: usize = 8;
    for &faces in counts {
        let (frame, rects, model, _) = scene(faces);
        let config = FaceTrackerConfig {
            particles,
            best: particles / 10,
            ..FaceTrackerConfig::default()
        };
        let tracker = |keep: bool| {
            let backend = FaceBackend::Gpu(Box::new(context()));
            let mut t = FaceTracker::new(&frame, &rects, &model, config.clone(), backend).unwrap();
            if keep {
                t.keep_lineage().unwrap();
            }
            t
        };
        let mut plain = tracker(false);
        group.bench_function(BenchmarkId::new("step", faces), |b| {
            b.iter(|| std::hint::black_box(plain.step(&frame).unwrap()))
        });
        report_step_gpu_time(&mut plain, &frame, &format!("face step, {faces} faces"));
        drop(plain);
        let mut kept = tracker(true);
        group.bench_function(BenchmarkId::new("step_keeping_lineage", faces), |b| {
            b.iter(|| std::hint::black_box(kept.step(&frame).unwrap()))
        });
        group.bench_function(BenchmarkId::new("step_reading_particles", faces), |b| {
            b.iter(|| {
                let estimates = kept.step(&frame).unwrap();
                std::hint::black_box(kept.track_clouds(&estimates).unwrap())
            })
        });
        for how in [LagSmoother::Ancestry, LagSmoother::Marginal] {
            let mut smoother = TrackSmoother::new(Some(LAG), kept.transition(), kept.motion_gain())
                .lagging_by(how);
            if how == LagSmoother::Marginal {
                let ctx = kept.gpu_context().unwrap();
                let on_gpu = pf_gpu::smooth::OnGpu::new(ctx).unwrap();
                smoother = smoother.on(std::sync::Arc::new(on_gpu));
            }
            let mut frame_index = 0;
            let name = format!("step_smoothing_lag_8_{how:?}").to_lowercase();
            group.bench_function(BenchmarkId::new(name, faces), |b| {
                b.iter(|| {
                    let estimates = kept.step(&frame).unwrap();
                    let clouds = kept.track_clouds(&estimates).unwrap();
                    frame_index += 1;
                    std::hint::black_box(smoother.add_frame(frame_index, clouds).unwrap())
                })
            });
        }
        drop(kept);
        // The lag window kept on the GPU: only the summaries come back with the step.
        let mut on_gpu = tracker(true);
        on_gpu.keep_lag_window(LAG, false).unwrap();
        let angular = on_gpu.transition().angular;
        let mut rows = LaggedTracks::new(LAG, angular.len(), angular, false);
        let mut frame_index = 0;
        group.bench_function(
            BenchmarkId::new("step_smoothing_lag_8_on_gpu", faces),
            |b| {
                b.iter(|| {
                    let estimates = on_gpu.step(&frame).unwrap();
                    let tracking = on_gpu.slot_tracks(&estimates);
                    frame_index += 1;
                    let mut read = |slot: usize, first: u64, n: usize| {
                        (on_gpu.lag_frames(slot, first, n))
                            .map_err(|e| pf_core::PfError::InvalidConfig(e.to_string()))
                    };
                    let lagged = on_gpu.lagged();
                    std::hint::black_box(
                        rows.add_frame(frame_index, &tracking, lagged, &mut read)
                            .unwrap(),
                    )
                })
            },
        );
        // The window's cost on the GPU, apart from the whole step's spread between processes:
        // the step's GPU time, and the summary's own.
        let what = format!("face step, {faces} faces, lag 8 window on the GPU");
        report_step_gpu_time(&mut on_gpu, &frame, &what);
        report_dispatches(&mut on_gpu, &frame, &what);
    }
    group.finish();
}

/// Whether the run sets up group `name`: every group, or those named in
/// `STREAMPF_BENCH_GROUPS` (comma-separated function names, e.g. `lag_smoothing,fig7`).
/// Criterion's filter skips a benchmark's measurement but not its group's set-up (scenes,
/// trackers, reports), which takes minutes at full size.
fn wanted(name: &str) -> bool {
    std::env::var("STREAMPF_BENCH_GROUPS")
        .map_or(true, |groups| groups.split(',').any(|g| g.trim() == name))
}

fn bench(c: &mut Criterion) {
    let ctx = context();
    if wanted("fig6") {
        fig6(c, &ctx);
    }
    if wanted("weighing_vs_lanes") {
        face_weighing::weighing_vs_lanes(c, &ctx);
    }
    if wanted("frame_upload") {
        frame_upload(c, &ctx);
    }
    if wanted("fig7") {
        fig7(c);
    }
    if wanted("lag_smoothing") {
        lag_smoothing(c);
    }
    if wanted("over_gpus") {
        over_gpus(c);
    }
    if wanted("render") {
        render(c);
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
