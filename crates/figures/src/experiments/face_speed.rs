//! The face paper's speed figures. Fig. 6: weighting time against particles (one face, one
//! frame). Fig. 7: the tracker's whole step against the number of faces (1 000 particles each
//! in full mode): frame upload, weighting, normalisation, best-M′ estimate, the estimates'
//! failure check, resampling and diffusion, and the readback.

use anyhow::Context;
use face_tracker::extraction::{FaceRect, extract_template};
use face_tracker::likelihood::gpu::{FaceDispatch, FaceLikelihoodGpu};
use face_tracker::likelihood::{MIN_ERROR, MIN_VISIBLE_SHARE, weigh_parallel, weigh_single_thread};
use face_tracker::model::FaceModel;
use face_tracker::projection::DIMS;
use face_tracker::synth::{FaceSynthConfig, face_state, initial_rect, render_frame};
use face_tracker::{FaceBackend, FaceTracker, FaceTrackerConfig, GrayImage};
use pf_core::batch::{BatchConfig, BatchShape, gaussian_clouds};
use pf_gpu::{GpuContext, GpuFilter, GpuLikelihood, GpuResampler, GpuStage};

use super::{Run, cores, one_thread};
use crate::paper;
use crate::record::{Figure, Panel};
use crate::timing::measure;

const MS: f64 = 1e3;

fn fig6_sizes(quick: bool) -> &'static [usize] {
    if quick {
        &[100, 300, 1000]
    } else {
        &[100, 200, 500, 1000, 2000, 5000, 10_000]
    }
}

fn fig7_faces(quick: bool) -> &'static [usize] {
    if quick {
        &[1, 2, 4]
    } else {
        &[1, 2, 4, 8, 16, 32, 64]
    }
}

fn fig7_particles(quick: bool) -> usize {
    if quick { 200 } else { 1000 }
}

/// The paper's frame, four heads at 1024×768 whose templates get the paper's 230 points (full),
/// or four small heads at 320×240 (quick); its rectangles repeated to `faces` (a template per
/// rectangle, so 64 faces weigh 64 templates), and the face model.
type Scene = (GrayImage, Vec<FaceRect>, FaceModel, FaceSynthConfig);

fn scene(quick: bool, faces: usize) -> anyhow::Result<Scene> {
    let config = if quick {
        FaceSynthConfig {
            faces: 4,
            width: 320,
            height: 240,
            half_width: 24.0,
            occlusion: false,
            ..FaceSynthConfig::paper(2)
        }
    } else {
        FaceSynthConfig {
            occlusion: false,
            ..FaceSynthConfig::paper(2)
        }
    };
    let model = FaceModel::generic(129)?;
    let frame = render_frame(&config, &model, 0)?;
    let rects = (0..faces)
        .map(|k| initial_rect(&config, k % config.faces))
        .collect();
    Ok((frame, rects, model, config))
}

pub fn fig6_steps(quick: bool) -> u64 {
    3 * fig6_sizes(quick).len() as u64
}

pub fn fig6(run: &mut Run) -> anyhow::Result<Figure> {
    let (frame, rects, model, video) = scene(run.quick, 1)?;
    let template = extract_template(
        &frame,
        &rects[0],
        &model,
        &FaceTrackerConfig::default().extraction,
    )?;
    let one = one_thread()?;
    let cores_name = format!("CPU, {} threads", cores());
    let mut panel = Panel::new(
        format!("one face, {} feature points", template.len()),
        ("particles", "particles"),
        ("weighting time per frame (ms)", "ms"),
    )
    .log_axes(true, true)
    .timings();
    panel.paper = paper::face_fig6_points("CPU, one thread");
    // Particles around face 0's true pose at the next frame, as a tracker's would be.
    let truth = face_state(&video, 0, 1);
    for &m in fig6_sizes(run.quick) {
        let shape = BatchShape::new(1, m, DIMS)?;
        let sigma = [4.0, 4.0, 0.02, 0.05, 0.05, 0.05, 0.02];
        let layout = gaussian_clouds(&shape, 3, &truth, &sigma);
        let states: Vec<[f32; DIMS]> = (0..m)
            .map(|p| std::array::from_fn(|d| layout[shape.state_index(0, d, p)]))
            .collect();
        let x = m as f64;
        run.step(&format!("face Fig. 6: {m} particles, one thread"));
        let p = measure(run.plan, x, || {
            one.install(|| std::hint::black_box(weigh_single_thread(&states, &template, &frame)));
            Ok::<_, anyhow::Error>(())
        })?;
        panel.series_mut("CPU, one thread", "cpu-1").points.push(p);
        run.step(&format!("face Fig. 6: {m} particles, all cores"));
        let p = measure(run.plan, x, || {
            std::hint::black_box(weigh_parallel(&states, &template, &frame));
            Ok::<_, anyhow::Error>(())
        })?;
        panel.series_mut(&cores_name, "cpu-all").points.push(p);
        run.step(&format!("face Fig. 6: {m} particles, GPU"));
        if let Some(ctx) = run.gpu {
            let p = gpu_weighting(ctx, run, &shape, &layout, &template, &frame, x)?;
            panel
                .series_mut("GPU (paper's layout)", "gpu")
                .points
                .push(p);
        }
    }
    panel.scale_values(MS);
    Ok(Figure {
        name: "face-fig6",
        title: "Face paper Fig. 6: weighting time against particles".into(),
        description: format!(
            "The face likelihood (ε over the template's points, robust relative residual) for one face \
             on one {}×{} frame, particles drawn around the face's pose. CPU: `weigh_single_thread` on \
             one thread and `weigh_parallel` on all cores. GPU: the likelihood stage alone in the \
             paper's layout (a workgroup per particle, an invocation per point) with its \
             submission, wait and the filter's small readback.",
            frame.width, frame.height
        ),
        panels: vec![panel],
    })
}

fn gpu_weighting(
    ctx: &GpuContext,
    run: &Run,
    shape: &BatchShape,
    layout: &[f32],
    template: &face_tracker::Template,
    frame: &GrayImage,
    x: f64,
) -> anyhow::Result<crate::record::Point> {
    let batch = BatchConfig {
        shape: *shape,
        seed: 1,
        sigma: vec![4.0, 4.0, 0.02, 0.05, 0.05, 0.05, 0.02],
        bounds: None,
        angular: vec![false, false, false, true, true, true, false],
        ess_threshold: f64::INFINITY,
        best: 0,
        annealing: Default::default(),
        motion: Default::default(),
    };
    let mut filter = GpuFilter::new(ctx, &batch, GpuResampler::Systematic, layout)?;
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
    )?;
    gpu.upload_frame(ctx, &frame.data)?;
    gpu.upload_template(ctx, 0, &template.gpu_layout())?;
    gpu.prepare(ctx, &filter.likelihood_inputs())?;
    measure(run.plan, x, || {
        filter
            .run_stages(ctx, &[GpuStage::Likelihood], &gpu)
            .map(|_| ())
            .context("the GPU weighting")
    })
}

pub fn fig7_steps(quick: bool) -> u64 {
    3 * fig7_faces(quick).len() as u64
}

pub fn fig7(run: &mut Run) -> anyhow::Result<Figure> {
    let particles = fig7_particles(run.quick);
    let one = one_thread()?;
    let cores_name = format!("CPU, {} threads", cores());
    let mut panel = Panel::new(
        format!("{particles} particles per face"),
        ("faces", "faces"),
        ("whole step per frame (ms)", "ms"),
    )
    .log_axes(true, true)
    .timings();
    let mut size = (0, 0);
    let mut points = 0;
    for &faces in fig7_faces(run.quick) {
        let (frame, rects, model, _) = scene(run.quick, faces)?;
        size = (frame.width, frame.height);
        let config = FaceTrackerConfig {
            particles,
            best: particles / 10,
            ..FaceTrackerConfig::default()
        };
        let x = faces as f64;
        let tracker = |backend| FaceTracker::new(&frame, &rects, &model, config.clone(), backend);
        run.step(&format!("face Fig. 7: {faces} faces, one thread"));
        let mut single = tracker(FaceBackend::Cpu)?;
        points = single
            .templates()
            .iter()
            .map(|(_, t)| t.len())
            .max()
            .unwrap_or(0);
        let plan = if faces >= 16 {
            run.plan.slow()
        } else {
            run.plan
        };
        let p = measure(plan, x, || one.install(|| single.step(&frame)).map(|_| ()))?;
        panel.series_mut("CPU, one thread", "cpu-1").points.push(p);
        run.step(&format!("face Fig. 7: {faces} faces, all cores"));
        let mut all = tracker(FaceBackend::Cpu)?;
        let p = measure(run.plan, x, || all.step(&frame).map(|_| ()))?;
        panel.series_mut(&cores_name, "cpu-all").points.push(p);
        run.step(&format!("face Fig. 7: {faces} faces, GPU"));
        if let Some(ctx) = run.gpu {
            // The tracker owns its context; open a second one on the same adapter.
            let own = reopen(ctx)?;
            let mut gpu = tracker(FaceBackend::Gpu(Box::new(own)))?;
            let p = measure(run.plan, x, || gpu.step(&frame).map(|_| ()))?;
            panel
                .series_mut("GPU (packed kernel)", "gpu")
                .points
                .push(p);
        }
    }
    panel.scale_values(MS);
    panel.title = format!("{particles} particles per face, templates of up to {points} points");
    Ok(Figure {
        name: "face-fig7",
        title: "Face paper Fig. 7: the whole step against the number of faces".into(),
        description: format!(
            "`FaceTracker::step` on one {}×{} 8-bit frame: frame upload, weighting of every face \
             (the GPU's packed kernel, its lanes a particle chosen by the load, all faces in one dispatch), \
             normalisation, best-M′ estimate (M′ = particles/10), the estimates' ε for failure \
             detection, resampling and diffusion, and the readback. The CPU columns run the same \
             step with `FaceBackend::Cpu` on one thread and on all cores.",
            size.0, size.1
        ),
        panels: vec![panel],
    })
}

/// A second context on the adapter of `ctx` (trackers own their context).
pub(crate) fn reopen(ctx: &GpuContext) -> anyhow::Result<GpuContext> {
    let options = pf_gpu::ContextOptions {
        adapter_name: Some(ctx.adapter().name.clone()),
        allow_software: ctx.adapter().is_software(),
        prefer_software: ctx.adapter().is_software(),
        poll_timeout: std::time::Duration::from_secs(600),
        ..pf_gpu::ContextOptions::default()
    };
    Ok(GpuContext::new(&options)?)
}
