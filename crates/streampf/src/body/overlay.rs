//! `body track --overlay`: each frame's points from the camera with the estimate's capsules.

use super::inputs::Source;
use crate::annotated::Annotated;
use anyhow::Context;
use body_tracker::Skeleton;
use body_tracker::camera::Intrinsics;
use nalgebra::Vector3;
use std::path::Path;

/// `--overlay`: each frame's depth view with the estimate's capsules and the truth's outlines.
pub(super) struct BodyOverlay {
    pub(super) camera: Intrinsics,
    pub(super) out: Annotated,
    /// The last frame drawn, repeated in a video for a frame that could not be read.
    pub(super) last: Option<image::RgbImage>,
}

impl BodyOverlay {
    /// A video's frame rate: the sequences carry none, and 30 frames/s is the depth cameras'.
    const VIDEO_FPS: f64 = 30.0;

    pub(super) fn create(path: &Path, camera: Intrinsics) -> anyhow::Result<Self> {
        let out = Annotated::create(path, camera.width, camera.height, Self::VIDEO_FPS)
            .context("--overlay")?;
        Ok(Self {
            camera,
            out,
            last: None,
        })
    }

    pub(super) fn draw(
        &mut self,
        frame: usize,
        skeleton: &Skeleton,
        points: &[Vector3<f32>],
        pose: &[f32],
        truth: Option<&[f32]>,
    ) -> anyhow::Result<()> {
        let estimate = skeleton.capsules(pose)?;
        let truth = truth.map(|t| skeleton.capsules(t)).transpose()?;
        let image =
            body_tracker::overlay::overlay(&self.camera, points, &estimate, truth.as_deref());
        self.out.write(frame, &image).context("--overlay")?;
        self.last = Some(image);
        Ok(())
    }

    /// A frame that could not be read: a video repeats the last picture to keep its timing.
    pub(super) fn skip(&mut self, frame: usize) -> anyhow::Result<()> {
        match (&mut self.out, &self.last) {
            (Annotated::Video(_), Some(last)) => self.out.write(frame, last).context("--overlay"),
            _ => Ok(()),
        }
    }
}

/// The camera an overlay draws with: the sequence's, or (a PLY sequence without camera.json) a
/// 640×480 camera with a 60° horizontal field of view.
pub(super) fn overlay_camera(source: &Source) -> anyhow::Result<Intrinsics> {
    Ok(match source {
        Source::Synthetic(config) => config.camera,
        Source::Directory(dir) => match dir.camera {
            Some(camera) => camera,
            None => Intrinsics::with_fov(640, 480, 60.0)?,
        },
    })
}
