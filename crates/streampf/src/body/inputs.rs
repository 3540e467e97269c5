//! What `body track` reads before it tracks: the sequence (a directory or a generated one),
//! its starting pose and the engines it steps on.

use super::args::TrackArgs;
use anyhow::bail;
use body_tracker::human::standing_pose;
use body_tracker::sequence::SequenceDir;
use body_tracker::synth::{SynthConfig, pose_at, render};
use body_tracker::{Backend, Skeleton};
use nalgebra::Vector3;
use std::path::Path;

/// Where the frames come from.
pub(super) enum Source {
    Directory(SequenceDir),
    Synthetic(SynthConfig),
}

impl Source {
    pub(super) fn frames(&self) -> usize {
        match self {
            Source::Directory(dir) => dir.frames.len(),
            Source::Synthetic(config) => config.frames,
        }
    }

    pub(super) fn points(
        &self,
        skeleton: &Skeleton,
        frame: usize,
    ) -> anyhow::Result<Vec<Vector3<f32>>> {
        Ok(match self {
            Source::Directory(dir) => dir.read_frame(frame)?,
            Source::Synthetic(config) => {
                let truth = pose_at(skeleton, config, frame)?;
                render(skeleton, &truth, config, frame)?.points
            }
        })
    }
}

/// The backend `--backend` asks for ([`crate::gpu::open`]).
pub(super) fn open_backend(
    args: &TrackArgs,
    pays_for: impl Fn(usize) -> usize,
) -> anyhow::Result<Backend> {
    let (backend, gpus) = (args.backend, args.gpus);
    let mut contexts = crate::gpu::open(backend, args.allow_software, gpus, args.quiet, &pays_for)?;
    Ok(match contexts.len() {
        0 => Backend::Cpu,
        1 => Backend::Gpu(Box::new(contexts.remove(0))),
        _ => Backend::SplitGpus(contexts),
    })
}

/// An upright body facing the camera, its pelvis placed from the points' medians.
pub(super) fn pose_from_points(
    skeleton: &Skeleton,
    points: &[Vector3<f32>],
) -> anyhow::Result<Vec<f32>> {
    if points.is_empty() {
        bail!("the first frame has no points to start from; give --init-pose");
    }
    let median = |axis: usize| {
        let mut values: Vec<f32> = points.iter().map(|p| p[axis]).collect();
        values.sort_by(f32::total_cmp);
        values[values.len() / 2]
    };
    let mut theta = standing_pose(skeleton, median(2) + 0.12);
    theta[0] = median(0);
    // The visible points centre on the torso, about 0.15 m above the pelvis.
    theta[1] = median(1) - 0.15;
    Ok(theta)
}

/// The frames (generated or a sequence directory), the skeleton and the ground truth (one θ
/// per frame) if known.
pub(super) type Sequence = (Source, Skeleton, Option<Vec<Vec<f32>>>);

/// Opens what `args` asks to track.
pub(super) fn open_sequence(args: &TrackArgs) -> anyhow::Result<Sequence> {
    Ok(if args.synthetic {
        let config = args.sequence.config()?;
        let skeleton = args.sequence.skeleton()?;
        let truth = (0..config.frames)
            .map(|f| pose_at(&skeleton, &config, f))
            .collect::<Result<Vec<_>, _>>()?;
        (Source::Synthetic(config), skeleton, Some(truth))
    } else {
        let dir = args.dir.as_deref().unwrap_or(Path::new("."));
        let sequence = SequenceDir::open(dir)?;
        let skeleton = match sequence.skeleton()? {
            Some(s) => s,
            None => args.sequence.skeleton()?,
        };
        let truth = sequence.ground_truth(&skeleton)?;
        if let Some(t) = &truth
            && t.len() < sequence.frames.len()
        {
            bail!(
                "{} has {} rows for {} frames",
                dir.join(body_tracker::sequence::GROUND_TRUTH_FILE)
                    .display(),
                t.len(),
                sequence.frames.len()
            );
        }
        (Source::Directory(sequence), skeleton, truth)
    })
}
