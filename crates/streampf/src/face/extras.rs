//! What a run writes beside its CSV files, frame by frame: the rerun recording's frame, the
//! overlay's colour frames and the particles as numpy files.

use super::args::TrackArgs;
use super::runner::Runner;
use crate::face_io::Source;
use crate::face_overlay::ColourFrames;
use crate::recording::{FaceClouds, FaceFrame, Recording};
use face_tracker::projection::DIMS;
use face_tracker::tracker::pose_errors;
use face_tracker::{FaceEstimate, FaceTracker, GrayImage, TrackStatus};
use std::path::Path;

/// Logs a tracked frame to the rerun recording: the frame, the tracks, their particle clouds
/// (read back from the filter) and, with the ground truth, their errors.
pub(super) fn record_face_frame(
    recording: &Recording,
    frame: usize,
    seconds: f64,
    image: &GrayImage,
    runner: &Runner,
    estimates: &[FaceEstimate],
    truth: Option<&Vec<[f32; DIMS]>>,
) -> anyhow::Result<()> {
    let tracker = runner.tracker();
    let (shape, states, _) = tracker.particles()?;
    let clouds = FaceClouds {
        states: &states,
        particles: shape.particles,
    };
    let errors: Vec<(usize, f32, f32)> = estimates
        .iter()
        .filter(|e| e.status == TrackStatus::Tracking)
        .filter_map(|e| {
            let t = truth?.get(e.track)?;
            let (translation, rotation) = pose_errors(&e.state, t);
            Some((e.track, translation, rotation))
        })
        .collect();
    recording.face_frame(FaceFrame {
        frame,
        seconds,
        image,
        templates: &tracker.templates(),
        estimates,
        lens: tracker.lens(),
        clouds: Some(clouds),
        errors: &errors,
    })
}

/// The overlay's colour frames: the image files again, or the video decoded a second time; none
/// for a generated video or a camera (drawn in gray).
pub(super) fn colour_frames(
    args: &TrackArgs,
    source: &Source,
    size: (u32, u32),
) -> anyhow::Result<Option<ColourFrames>> {
    Ok(match (source, args.input.as_deref()) {
        (Source::Images { files, .. }, _) => Some(ColourFrames::images(files.clone())),
        (Source::Video(_), Some(path)) if args.webcam.is_none() => {
            Some(ColourFrames::video(path, size)?)
        }
        _ => None,
    })
}

/// One frame's clouds as numpy files, with the track that runs in each slot (-1: free).
pub(super) fn save_particles(
    dir: &Path,
    frame: usize,
    tracker: &FaceTracker,
    estimates: &[face_tracker::FaceEstimate],
) -> anyhow::Result<()> {
    let (shape, states, log_weights) = tracker.particles()?;
    pf_numpy::write_particles(dir, frame, &shape, &states, &log_weights)?;
    let mut tracks = vec![-1.0f32; shape.targets];
    for e in estimates
        .iter()
        .filter(|e| e.status == TrackStatus::Tracking)
    {
        if let Some(slot) = tracks.get_mut(e.slot) {
            *slot = e.track as f32;
        }
    }
    pf_numpy::write_f32(
        &dir.join(format!("tracks_{frame:06}.npy")),
        &[shape.targets],
        &tracks,
    )?;
    Ok(())
}
