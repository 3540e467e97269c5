//! What the filter's posterior gives beyond a point estimate (docs/POSTERIOR.md): smoothed
//! trajectories with 95 % intervals. Top: a random walk observed in noise, where the exact
//! answer is known, the particle smoother (`pf_core::smooth`) against the Rauch–Tung–Striebel
//! smoother (`pf_core::kalman`). Bottom: the synthetic face video tracked with the defaults, one
//! face's yaw as filtered and as smoothed over the whole run (`pf_core::smooth_tracks`, as
//! `face track --smooth full`), with its interval, against the truth.

use face_tracker::model::FaceModel;
use face_tracker::projection::RY;
use face_tracker::synth::{FaceVideoRenderer, face_state, initial_rect};
use face_tracker::{FaceBackend, FaceTracker, FaceTrackerConfig};
use pf_core::batch::{BatchConfig, BatchFilter, BatchShape, gaussian_clouds};
use pf_core::kalman::RandomWalk;
use pf_core::resample::Systematic;
use pf_core::smooth::{Cloud, GaussianTransition, Summary, smooth_all, summarise};
use pf_core::smooth_tracks::{Coverage, SmoothedRow, TrackSmoother};
use pf_core::{RandomStreams, Stage};

use super::Run;
use super::accuracy::face_video;
use super::face_speed::reopen;
use crate::record::{Figure, Panel, Point};

const WALK: RandomWalk = RandomWalk {
    step: 0.3,
    noise: 0.5,
    prior: (0.0, 1.0),
};
const WALK_FRAMES: usize = 40;
const WALK_PARTICLES: usize = 1000;

pub fn steps(quick: bool) -> u64 {
    1 + face_video(quick).0.frames as u64
}

pub fn run(run: &mut Run) -> anyhow::Result<Figure> {
    run.step("posterior: the random walk against Rauch–Tung–Striebel");
    let walk = walk_panel()?;
    let (face, coverage) = face_panel(run)?;
    let (video, particles) = face_video(run.quick);
    Ok(Figure {
        name: "posterior",
        title: "Smoothed trajectories and their 95 % intervals".into(),
        description: format!(
            "Top: a random walk (step {}, prior N(0, 1)) observed in noise (sd {}), {WALK_FRAMES} \
             frames: the particle filter's cloud ({WALK_PARTICLES} particles) smoothed by the \
             marginal backward pass, its mean and 95 % interval, against the exact \
             Rauch–Tung–Striebel smoother's mean ± 1.96 sd (drawn a quarter frame to the right). Bottom: the synthetic {}×{} video, \
             {particles} particles a face with the tracker's defaults on {}; face 0's yaw as the \
             filter's weighted mean and as smoothed over the whole run with its 95 % interval, \
             against the truth. Over every face and frame the smoothed intervals held the true \
             value {}.",
            WALK.step,
            WALK.noise,
            video.width,
            video.height,
            engine(run),
            coverage
        ),
        panels: vec![walk, face],
    })
}

fn engine(run: &Run) -> String {
    match run.hardware_gpu() {
        Some(ctx) => format!("the GPU ({})", ctx.adapter().name),
        None => format!("the CPU ({} threads)", super::cores()),
    }
}

/// A summary as a point with its interval.
fn with_interval(x: f64, s: &Summary, scale: f64) -> Point {
    Point {
        x,
        y: f64::from(s.mean) * scale,
        low: f64::from(s.lower) * scale,
        high: f64::from(s.upper) * scale,
        repeats: 1,
    }
}

/// The random walk's panel: truth, observations, RTS and the particle smoother.
fn walk_panel() -> anyhow::Result<Panel> {
    let mut rng = RandomStreams::new(4).stream(0, Stage::Model(0));
    let mut x = 0.0;
    let (truth, ys): (Vec<f64>, Vec<f64>) = (0..WALK_FRAMES)
        .map(|_| {
            x += WALK.step * rng.gaussian();
            (x, x + WALK.noise * rng.gaussian())
        })
        .unzip();
    let shape = BatchShape::new(1, WALK_PARTICLES, 1)?;
    let config = BatchConfig::new(shape, 17, vec![WALK.step as f32]);
    let start = gaussian_clouds(&shape, 17, &[0.0], &[WALK.prior.1.sqrt() as f32]);
    let mut filter = BatchFilter::new(&config, Systematic, start)?;
    let mut clouds = Vec::with_capacity(ys.len());
    for &y in &ys {
        let sd = WALK.noise as f32;
        filter.step(|_, _, x| -0.5 * ((x[0] - y as f32) / sd).powi(2))?;
        let (states, lw) = (&filter.states, &filter.log_weights);
        clouds.push(Cloud::of_target(
            1,
            WALK_PARTICLES,
            0,
            states,
            lw,
            vec![0.0],
        )?);
    }
    let transition = GaussianTransition {
        sigma: vec![WALK.step as f32],
        angular: vec![false],
    };
    let weights = smooth_all(&clouds, &transition)?;
    let mut panel = Panel::new(
        "a random walk in noise: particle smoother against RTS",
        ("frame", "frame"),
        ("x", "units"),
    );
    for (t, ((cloud, w), (&x, &y))) in clouds
        .iter()
        .zip(&weights)
        .zip(truth.iter().zip(&ys))
        .enumerate()
    {
        let t = t as f64;
        panel
            .series_mut("truth", "truth")
            .points
            .push(Point::exact(t, x));
        panel
            .series_mut("observation", "observation")
            .points
            .push(Point::exact(t, y));
        let summary = summarise(cloud, w, &[false])?[0];
        (panel
            .series_mut("particle smoother, 95 %", "smoothed")
            .points)
            .push(with_interval(t, &summary, 1.0));
    }
    for (t, (m, v)) in WALK.smooth(&ys).into_iter().enumerate() {
        let half = 1.96 * v.sqrt();
        panel
            .series_mut("Rauch–Tung–Striebel, 95 %", "exact")
            .points
            .push(Point {
                x: t as f64 + 0.25,
                y: m,
                low: m - half,
                high: m + half,
                repeats: 1,
            });
    }
    Ok(panel)
}

/// The face video's panel (face 0's yaw, degrees) and the smoothed intervals' coverage over
/// every face, frame and value.
fn face_panel(run: &mut Run) -> anyhow::Result<(Panel, String)> {
    let (video, particles) = face_video(run.quick);
    let model = FaceModel::generic(129)?;
    let renderer = FaceVideoRenderer::new(&video, &model)?;
    let first = renderer.render(0)?;
    let rects: Vec<_> = (0..video.faces).map(|k| initial_rect(&video, k)).collect();
    let config = FaceTrackerConfig {
        particles,
        best: particles / 10,
        ..FaceTrackerConfig::default()
    };
    let backend = match run.hardware_gpu() {
        Some(ctx) => FaceBackend::Gpu(Box::new(reopen(ctx)?)),
        None => FaceBackend::Cpu,
    };
    let mut tracker = FaceTracker::new(&first, &rects, &model, config, backend)?;
    let mut smoother =
        TrackSmoother::new(None, tracker.transition(), tracker.motion_gain()).comparing_filtered();
    let mut rows: Vec<SmoothedRow> = Vec::new();
    for frame in 0..video.frames {
        run.step(&format!("posterior: face video frame {frame}"));
        let estimates = tracker.step(&renderer.render(frame)?)?;
        rows.extend(smoother.add_frame(frame, tracker.track_clouds(&estimates)?)?);
    }
    rows.extend(smoother.finish()?);
    rows.sort_by_key(|r| (r.track, r.frame));
    let mut panel = Panel::new(
        "face 0's yaw: filtered and smoothed",
        ("frame", "frame"),
        ("yaw (°)", "deg"),
    );
    let (mut smoothed, mut filtered) = (Coverage::default(), Coverage::default());
    let angular = tracker.transition().angular;
    for row in &rows {
        let truth = face_state(&video, row.track, row.frame);
        smoothed.add(&row.values, &truth, &angular);
        filtered.add(&row.filtered, &truth, &angular);
        if row.track != 0 {
            continue;
        }
        let (x, degrees) = (row.frame as f64, 180.0 / std::f64::consts::PI);
        panel
            .series_mut("truth", "truth")
            .points
            .push(Point::exact(x, f64::from(truth[RY]) * degrees));
        (panel.series_mut("filtered mean", "filtered").points)
            .push(Point::exact(x, f64::from(row.filtered[RY].mean) * degrees));
        (panel.series_mut("smoothed, 95 %", "smoothed").points).push(with_interval(
            x + 0.25,
            &row.values[RY],
            degrees,
        ));
    }
    let share = |c: &Coverage| {
        let p = c.percent();
        p.iter().sum::<f64>() / p.len().max(1) as f64
    };
    let coverage = format!(
        "{:.0} % of the time on average over the seven values ({} face-frames; the filtered intervals {:.0} %)",
        share(&smoothed),
        smoothed.rows,
        share(&filtered)
    );
    Ok((panel, coverage))
}
