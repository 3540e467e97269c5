//! The body paper's speed figures. Fig. 5: the capsule likelihood's time against points (J
//! fixed) and against samples (I fixed), K = 48 capsules, on the GPU in the paper's layout and
//! with the fast kernel, and on all CPU cores. Fig. 6: the speed-up of each over one CPU thread
//! running Listing 1.2, against points.
//!
//! GPU times include the submission, the wait and the readback of the J sums (the capsules and
//! rays are on the device). The CPU runs are per-sample loops over a sub-sample of J (two
//! samples on one thread, J/50 but at least 16 on all cores), so their time is scaled to the
//! full J: a sample costs the same whichever sample it is.

use anyhow::Context;
use body_tracker::Capsule;
use body_tracker::benchmark_scene::{perturbed_samples, raster_cloud};
use body_tracker::likelihood::gpu::{CapsuleKernel, CapsuleLikelihoodGpu};
use body_tracker::likelihood::{Rays, capsules_gpu_layout, listing_1_2, parallel_over_samples};
use pf_gpu::GpuContext;

use super::{Run, cores};
use crate::paper;
use crate::record::{Figure, Panel, Point};
use crate::timing::measure;

const K: usize = 48;
const TAU: f32 = 0.1;

struct Sizes {
    /// J for the points axis, and the points.
    points_j: usize,
    points: &'static [usize],
    /// I for the samples axis, and the samples.
    samples_i: usize,
    samples: &'static [usize],
}

fn sizes(quick: bool) -> Sizes {
    if quick {
        Sizes {
            points_j: 50,
            points: &[500, 1000, 2000],
            samples_i: 1000,
            samples: &[20, 50, 100],
        }
    } else {
        Sizes {
            points_j: 3500,
            points: &[1000, 5000, 10_000, 20_000, 30_000, 43_000],
            samples_i: 43_000,
            samples: &[100, 500, 1000, 2000, 3500],
        }
    }
}

/// One size's measurements, all for the full J (seconds).
#[derive(Debug, Clone, Copy)]
struct Row {
    gpu_paper: Option<Point>,
    gpu_fast: Option<Point>,
    all_cores: Point,
    /// Only measured on the points axis (Fig. 6's baseline).
    one_thread: Option<Point>,
}

/// The points axis, measured once for both figures.
#[derive(Debug, Clone)]
pub(crate) struct PointsAxis {
    j: usize,
    rows: Vec<(usize, Row)>,
}

const ROW_STEPS: u64 = 3;

pub fn fig5_steps(quick: bool) -> u64 {
    let s = sizes(quick);
    // The points axis also times one thread; the samples axis does not.
    (ROW_STEPS + 1) * s.points.len() as u64 + ROW_STEPS * s.samples.len() as u64
}

pub fn fig6_steps(quick: bool) -> u64 {
    // Nothing new when Fig. 5 ran first; the progress bar may finish early.
    (ROW_STEPS + 1) * sizes(quick).points.len() as u64
}

fn points_axis(run: &mut Run) -> anyhow::Result<PointsAxis> {
    if let Some(axis) = &run.body_points {
        return Ok(axis.clone());
    }
    let s = sizes(run.quick);
    let all = perturbed_samples(K, s.points_j)?;
    let mut rows = Vec::new();
    for &i in s.points {
        let rays = raster_cloud(K, i)?;
        rows.push((i, measure_row(run, &rays, &all, i as f64, true)?));
    }
    let axis = PointsAxis {
        j: s.points_j,
        rows,
    };
    run.body_points = Some(axis.clone());
    Ok(axis)
}

fn measure_row(
    run: &Run,
    rays: &Rays,
    samples: &[Vec<Capsule>],
    x: f64,
    with_one_thread: bool,
) -> anyhow::Result<Row> {
    let j = samples.len();
    let i = rays.len();
    let mut row = Row {
        gpu_paper: None,
        gpu_fast: None,
        all_cores: Point::exact(x, 0.0),
        one_thread: None,
    };
    run.step(&format!("body: J = {j}, I = {i}, GPU paper's layout"));
    if let Some(ctx) = run.gpu {
        row.gpu_paper = Some(gpu_time(
            ctx,
            run,
            CapsuleKernel::PaperLayout,
            rays,
            samples,
            x,
        )?);
    }
    run.step(&format!("body: J = {j}, I = {i}, GPU fast kernel"));
    if let Some(ctx) = run.gpu {
        row.gpu_fast = Some(gpu_time(ctx, run, CapsuleKernel::Fast, rays, samples, x)?);
    }
    run.step(&format!("body: J = {j}, I = {i}, all cores"));
    let sub = (j / 50).max(16).min(j);
    let p = measure(run.plan, x, || {
        std::hint::black_box(parallel_over_samples(&samples[..sub], rays, TAU));
        Ok::<_, anyhow::Error>(())
    })?;
    row.all_cores = per_sample_to_full(p, sub, j);
    if with_one_thread {
        run.step(&format!("body: J = {j}, I = {i}, one thread (Listing 1.2)"));
        let sub = 2.min(j);
        let plan = if i >= 10_000 {
            run.plan.slow()
        } else {
            run.plan
        };
        let p = measure(plan, x, || {
            std::hint::black_box(listing_1_2(&samples[..sub], rays, TAU));
            Ok::<_, anyhow::Error>(())
        })?;
        row.one_thread = Some(per_sample_to_full(p, sub, j));
    }
    Ok(row)
}

/// A time for `measured` samples scaled to `full` samples.
fn per_sample_to_full(p: Point, measured: usize, full: usize) -> Point {
    p.scaled(full as f64 / measured as f64)
}

fn gpu_time(
    ctx: &GpuContext,
    run: &Run,
    kind: CapsuleKernel,
    rays: &Rays,
    samples: &[Vec<Capsule>],
    x: f64,
) -> anyhow::Result<Point> {
    let g = CapsuleLikelihoodGpu::new(ctx, kind, samples.len(), rays.len(), K, [0.0; 3], TAU)?;
    g.upload_rays(ctx, &rays.gpu_layout())?;
    let mut flat = Vec::new();
    for c in samples {
        capsules_gpu_layout(c, &mut flat);
    }
    g.upload_capsules(ctx, &flat)?;
    measure(run.plan, x, || {
        g.evaluate(ctx)
            .map(|sums| {
                std::hint::black_box(sums);
            })
            .context("the GPU capsule likelihood")
    })
}

/// Log axes: the CPU is thousands of times slower than the GPU, and on log axes linear scaling
/// shows as lines of slope one for every variant.
fn time_panel(title: String, x_label: &str, x_unit: &'static str) -> Panel {
    Panel::new(
        title,
        (x_label, x_unit),
        ("likelihood time per evaluation (ms)", "ms"),
    )
    .log_axes(true, true)
    .timings()
}

fn add_row(panel: &mut Panel, row: &Row, with_one_thread: bool) {
    let ms = |p: Point| p.scaled(1e3);
    if let Some(p) = row.gpu_paper {
        panel
            .series_mut("GPU, paper's layout", "gpu")
            .points
            .push(ms(p));
    }
    if let Some(p) = row.gpu_fast {
        panel
            .series_mut("GPU, fast kernel", "gpu")
            .points
            .push(ms(p));
    }
    let cores_name = format!("CPU, {} threads (scaled to J)", cores());
    panel
        .series_mut(&cores_name, "cpu-all")
        .points
        .push(ms(row.all_cores));
    if with_one_thread && let Some(p) = row.one_thread {
        panel
            .series_mut("CPU, one thread, Listing 1.2 (scaled to J)", "cpu-1")
            .points
            .push(ms(p));
    }
}

pub fn fig5(run: &mut Run) -> anyhow::Result<Figure> {
    let s = sizes(run.quick);
    let points = points_axis(run)?;
    let mut by_points = time_panel(
        format!("against points, J = {} samples", points.j),
        "points I",
        "points",
    );
    for (_, row) in &points.rows {
        add_row(&mut by_points, row, false);
    }
    let mut by_samples = time_panel(
        format!("against samples, I = {} points", s.samples_i),
        "samples J",
        "samples",
    );
    let rays = raster_cloud(K, s.samples_i)?;
    let largest = s.samples.iter().copied().max().unwrap_or(1);
    let all = perturbed_samples(K, largest)?;
    for &j in s.samples {
        let row = measure_row(run, &rays, &all[..j], j as f64, false)?;
        add_row(&mut by_samples, &row, false);
    }
    Ok(Figure {
        name: "body-fig5",
        title: format!(
            "Body paper Fig. 5: the likelihood is linear in points and samples (K = {K})"
        ),
        description: description(),
        panels: vec![by_points, by_samples],
    })
}

pub fn fig6(run: &mut Run) -> anyhow::Result<Figure> {
    let points = points_axis(run)?;
    let mut panel = Panel::new(
        format!("J = {} samples, K = {K} capsules", points.j),
        ("points I", "points"),
        ("speed-up over one CPU thread (Listing 1.2)", "x"),
    )
    .log_axes(false, true);
    let cores_name = format!("CPU, {} threads", cores());
    for &(i, row) in &points.rows {
        let Some(one) = row.one_thread else { continue };
        let x = i as f64;
        let mut add = |name: &str, kind, p: Option<Point>| {
            if let Some(p) = p {
                // The ratio's spread: the extremes of the two quartile ranges.
                panel.series_mut(name, kind).points.push(Point {
                    x,
                    y: one.y / p.y,
                    low: one.low / p.high,
                    high: one.high / p.low,
                    repeats: p.repeats.min(one.repeats),
                });
            }
        };
        add("GPU, paper's layout", "", row.gpu_paper);
        add("GPU, fast kernel", "", row.gpu_fast);
        add(&cores_name, "", Some(row.all_cores));
    }
    Ok(Figure {
        name: "body-fig6",
        title: "Body paper Fig. 6: speed-up over one CPU thread against points".into(),
        description: format!(
            "{} The speed-up is one thread's time for all J samples (Listing 1.2, measured on two \
             samples and scaled) over each variant's time. The paper's claim: \"{}\" ({}).",
            description(),
            paper::body_speedup_claim().quote,
            paper::body_speedup_claim().source
        ),
        panels: vec![panel],
    })
}

fn description() -> String {
    format!(
        "M_j = Σ_i (min_k d_ik)² for J samples of the default human with K = {K} capsules (the \
         standing pose, every value perturbed by 0.05) against I points ray-cast onto it (1 cm \
         depth noise, raster order as a camera delivers them). GPU: `CapsuleLikelihoodGpu` in the \
         paper's layout (point tile × sample grid, workgroup staging, partial sums and a \
         reduction) and the fast kernel, with submission, wait and readback. CPU: per-sample \
         loops on a sub-sample of J (two samples on one thread, J/50 but at least 16 on all \
         cores), scaled to J."
    )
}
