//! Tracking accuracy over time against the ground truth of the synthetic sequences: each tracker
//! with its defaults (annealed), the same tracker as a plain one-layer random-walk filter
//! (Condensation as the papers ran it), and the filter with a flat likelihood (every particle
//! weighs the same, so it only diffuses): the baseline a likelihood must beat. Faces: per-frame translation (px) and rotation (°) error
//! of each face on the four-face video. Body: per-frame mean joint error and each joint's mean
//! error on the walk-wave sequence. Runs on a hardware GPU when there is one, else on the CPU.

use body_tracker::human::human_skeleton;
use body_tracker::synth::{SynthConfig, pose_at, render};
use body_tracker::{Backend, BodyTracker, TrackerConfig, Weighing};
use face_tracker::model::FaceModel;
use face_tracker::synth::{FaceSynthConfig, FaceVideoRenderer, face_state, initial_rect};
use face_tracker::tracker::pose_errors;
use face_tracker::{FaceBackend, FaceTracker, FaceTrackerConfig, TrackStatus};
use pf_core::anneal::Annealing;
use pf_core::batch::Motion;
use pf_gpu::GpuContext;

use super::Run;
use super::face_speed::reopen;
use crate::record::{Figure, Panel, Point};

const TRACKER: &str = "tracker";
const PLAIN: &str = "plain filter";
const FLAT: &str = "flat likelihood";

/// The three filters of each figure: (label, series kind, plain one-layer random walk, flat).
const VARIANTS: [(&str, &str, bool, bool); 3] = [
    (TRACKER, "tracked", false, false),
    (PLAIN, "plain", true, false),
    (FLAT, "flat", true, true),
];

/// The face video and particles of the accuracy and posterior figures (quick: small).
pub(super) fn face_video(quick: bool) -> (FaceSynthConfig, usize) {
    if quick {
        let video = FaceSynthConfig {
            width: 320,
            height: 240,
            frames: 12,
            faces: 2,
            half_width: 30.0,
            ..FaceSynthConfig::paper(12)
        };
        (video, 200)
    } else {
        (FaceSynthConfig::paper(100), 1000)
    }
}

pub fn face_steps(quick: bool) -> u64 {
    VARIANTS.len() as u64 * face_video(quick).0.frames as u64
}

fn face_backend(gpu: Option<&GpuContext>) -> anyhow::Result<FaceBackend> {
    Ok(match gpu {
        Some(ctx) => FaceBackend::Gpu(Box::new(reopen(ctx)?)),
        None => FaceBackend::Cpu,
    })
}

pub fn face(run: &mut Run) -> anyhow::Result<Figure> {
    let (video, particles) = face_video(run.quick);
    let model = FaceModel::generic(129)?;
    let mut translation = error_panel("translation error", "error (px)", "px");
    let mut rotation = error_panel(
        "rotation error (angle of R_est⁻¹·R_true)",
        "error (°)",
        "deg",
    );
    let gpu = run.hardware_gpu();
    for (label, kind, plain, flat) in VARIANTS {
        let defaults = FaceTrackerConfig::default();
        let config = FaceTrackerConfig {
            particles,
            best: particles / 10,
            // γ = 0 weighs every particle the same; an ε threshold of 1 never ends a track
            // (ε < 1 always).
            sharpness: if flat { 0.0 } else { 8.0 },
            failure_error: if flat { 1.0 } else { 0.12 },
            annealing: if plain {
                Annealing::none()
            } else {
                defaults.annealing.clone()
            },
            motion: if plain {
                Motion::RandomWalk
            } else {
                defaults.motion
            },
            ..defaults
        };
        let renderer = FaceVideoRenderer::new(&video, &model)?;
        let first = renderer.render(0)?;
        let rects: Vec<_> = (0..video.faces).map(|k| initial_rect(&video, k)).collect();
        let mut tracker = FaceTracker::new(&first, &rects, &model, config, face_backend(gpu)?)?;
        for frame in 0..video.frames {
            run.step(&format!("face accuracy ({label}): frame {frame}"));
            let image = renderer.render(frame)?;
            for e in tracker.step(&image)? {
                if e.status != TrackStatus::Tracking {
                    continue;
                }
                // Tracks are numbered in the rectangles' order.
                let (t, r) = pose_errors(&e.state, &face_state(&video, e.track, frame));
                let name = format!("face {}, {label}", e.track);
                let x = frame as f64;
                translation
                    .series_mut(&name, kind)
                    .points
                    .push(Point::exact(x, f64::from(t)));
                rotation
                    .series_mut(&name, kind)
                    .points
                    .push(Point::exact(x, f64::from(r)));
            }
        }
    }
    Ok(Figure {
        name: "accuracy-face",
        title: format!(
            "Face tracking accuracy: {} faces, {particles} particles each, {}",
            video.faces,
            engine(gpu)
        ),
        description: format!(
            "The synthetic {}×{} video of {} textured heads ({} frames; yaw up to ±{:.0}°, changing \
             light{}), each tracked from its rectangle in frame 0 with the tracker's defaults \
             (five annealing layers, a constant-velocity drift), as a plain filter (one layer, the \
             random walk: Condensation as the paper ran it; paler lines) and with γ = 0 (a flat \
             likelihood: diffusion only; palest). A track that is lost has no points after it.",
            video.width,
            video.height,
            video.faces,
            video.frames,
            video.max_yaw.to_degrees(),
            if video.occlusion { ", an occluder" } else { "" }
        ),
        panels: vec![translation, rotation],
    })
}

fn error_panel(title: &str, y_label: &str, y_unit: &'static str) -> Panel {
    Panel::new(title, ("frame", "frame"), (y_label, y_unit))
}

fn engine(gpu: Option<&GpuContext>) -> String {
    match gpu {
        Some(ctx) => format!("GPU ({})", ctx.adapter().name),
        None => format!("CPU ({} threads)", super::cores()),
    }
}

fn body_sequence(quick: bool) -> anyhow::Result<(SynthConfig, usize, usize)> {
    Ok(if quick {
        (SynthConfig::small(10)?, 200, 19)
    } else {
        (
            SynthConfig::small(40)?,
            TrackerConfig::default().particles,
            48,
        )
    })
}

pub fn body_steps(quick: bool) -> u64 {
    body_sequence(quick).map_or(0, |(s, ..)| VARIANTS.len() as u64 * s.frames as u64)
}

/// The tracker's defaults, as a plain filter (`plain`: one layer) or with a flat likelihood.
fn variant_config(particles: usize, plain: bool, flat: bool) -> TrackerConfig {
    TrackerConfig {
        particles,
        weighing: if flat {
            Weighing::Flat
        } else {
            Weighing::Capsules
        },
        annealing: if plain {
            Annealing::none()
        } else {
            TrackerConfig::default().annealing
        },
        ..TrackerConfig::default()
    }
}

/// Steps `tracker` on `frame` of the sequence: each tracked joint's position error (cm).
fn joint_errors(
    skeleton: &body_tracker::skeleton::Skeleton,
    synth: &SynthConfig,
    tracker: &mut BodyTracker,
    frame: usize,
) -> anyhow::Result<Vec<f64>> {
    let truth = pose_at(skeleton, synth, frame)?;
    let points = render(skeleton, &truth, synth, frame)?.points;
    let result = tracker.step(&points)?;
    let estimated = skeleton.tracked_joint_positions(&result.pose)?;
    let expected = skeleton.tracked_joint_positions(&truth)?;
    Ok(estimated
        .iter()
        .zip(&expected)
        .map(|(a, b)| 100.0 * f64::from((a - b).norm()))
        .collect())
}

pub fn body(run: &mut Run) -> anyhow::Result<Figure> {
    let (synth, particles, capsules) = body_sequence(run.quick)?;
    let skeleton = human_skeleton(capsules)?;
    let joints = skeleton.joint_bones();
    let joint_names: Vec<&str> = joints
        .iter()
        .map(|&b| skeleton.bones()[b].name.as_str())
        .collect();
    let mut over_time = error_panel("mean joint position error per frame", "error (cm)", "cm");
    let mut per_joint = Panel::new(
        "each joint's mean error over the sequence",
        ("joint (index into the list in the description)", "joint"),
        ("error (cm)", "cm"),
    );
    let gpu = run.hardware_gpu();
    let start = pose_at(&skeleton, &synth, 0)?;
    for (label, kind, plain, flat) in VARIANTS {
        let config = variant_config(particles, plain, flat);
        let backend = match gpu {
            Some(ctx) => Backend::Gpu(Box::new(reopen(ctx)?)),
            None => Backend::Cpu,
        };
        let mut tracker = BodyTracker::new(skeleton.clone(), &start, config, backend)?;
        let mut sums = vec![0.0f64; joints.len()];
        for frame in 0..synth.frames {
            run.step(&format!("body accuracy ({label}): frame {frame}"));
            let errors = joint_errors(&skeleton, &synth, &mut tracker, frame)?;
            for (s, e) in sums.iter_mut().zip(&errors) {
                *s += e;
            }
            let mean = errors.iter().sum::<f64>() / errors.len() as f64;
            over_time
                .series_mut(label, kind)
                .points
                .push(Point::exact(frame as f64, mean));
        }
        let series = per_joint.series_mut(label, kind);
        for (j, s) in sums.iter().enumerate() {
            series
                .points
                .push(Point::exact(j as f64, s / synth.frames as f64));
        }
    }
    let listed: Vec<String> = joint_names
        .iter()
        .enumerate()
        .map(|(i, n)| format!("{i} {n}"))
        .collect();
    Ok(Figure {
        name: "accuracy-body",
        title: format!(
            "Body tracking accuracy: walk-wave, {capsules} capsules, {particles} samples, {}",
            engine(gpu)
        ),
        description: format!(
            "The synthetic walk-and-wave depth sequence ({} frames, {}×{} camera, depth noise, \
             dropout, outliers and self-occlusion), tracked from the true first pose with the \
             tracker's defaults (eight annealing layers, partitioned: the trunk's four, then the \
             limbs'), as a plain filter (one layer: \
             Condensation as the paper ran it; paler) and with a flat likelihood (diffusion only; \
             palest). Joints: {}.",
            synth.frames,
            synth.camera.width,
            synth.camera.height,
            listed.join(", ")
        ),
        panels: vec![over_time, per_joint],
    })
}
