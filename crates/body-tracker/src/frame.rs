//! A frame's host preparation, apart from the filter's step: thinning the points, their rays
//! from the camera, and for a GPU tracker the rays padded, in Morton order and with their tile
//! cones (`crate::skeleton::gpu::prepare_body_rays`). It needs nothing of the filter's state, so a
//! reader thread can prepare frame t + 1 while the GPU steps frame t
//! ([`crate::BodyTracker::preparer`], [`crate::BodyTracker::step_prepared`]).

use std::borrow::Cow;

use crate::likelihood::gpu::PreparedRays;
use nalgebra::Vector3;

use crate::error::BodyError;
use crate::likelihood::{CoarseLayers, Rays};

/// Prepares frames for one tracker; cheap to clone and to send to another thread.
#[derive(Debug, Clone, PartialEq)]
pub struct FramePreparer {
    /// The most points a frame keeps (more are thinned).
    pub(crate) max_points: usize,
    /// Whether the tracker's filters weigh on GPUs (which read the prepared rays).
    pub(crate) on_gpu: bool,
    /// The coarse annealing layers' subset of the points, when the tracker has them.
    pub(crate) coarse: Option<CoarseLayers>,
}

/// A frame ready for [`crate::BodyTracker::step_prepared`].
#[derive(Debug, Clone)]
pub struct PreparedFrame {
    pub(crate) rays: Rays,
    /// The coarse layers' subset of `rays` (a CPU tracker with coarse layers).
    pub(crate) coarse_rays: Option<Rays>,
    /// The rays as the GPU likelihood uploads them (every level); `None` for a CPU tracker.
    pub(crate) gpu_rays: Option<PreparedRays>,
    /// The preparer that made it, so that a frame is never stepped by a tracker it does not fit.
    pub(crate) preparer: FramePreparer,
}

impl PreparedFrame {
    /// The points the frame kept (after thinning).
    pub fn points(&self) -> usize {
        self.rays.depths.len()
    }
}

impl FramePreparer {
    /// Thins `points` (camera frame, camera at the origin) to at most the tracker's
    /// `max_points` by taking every k-th one, and makes their rays.
    pub fn prepare(&self, points: &[Vector3<f32>]) -> Result<PreparedFrame, BodyError> {
        let points = self.thinned(points);
        let rays = Rays::through(Vector3::zeros(), &points)?;
        let (gpu_rays, coarse_rays) = if self.on_gpu {
            let prepared = crate::skeleton::gpu::prepare_body_rays(
                &rays.gpu_layout(),
                self.max_points,
                self.coarse.as_ref(),
            )?;
            (Some(prepared), None)
        } else {
            let subset = |c: &CoarseLayers| Rays {
                origin: rays.origin,
                directions: c.subset(&rays.directions),
                depths: c.subset(&rays.depths),
            };
            (None, self.coarse.as_ref().map(subset))
        };
        Ok(PreparedFrame {
            rays,
            coarse_rays,
            gpu_rays,
            preparer: self.clone(),
        })
    }

    /// `points`, or every k-th of them when there are more than `max_points`.
    fn thinned<'a>(&self, points: &'a [Vector3<f32>]) -> Cow<'a, [Vector3<f32>]> {
        if points.len() <= self.max_points {
            return points.into();
        }
        let step = points.len().div_ceil(self.max_points);
        points
            .iter()
            .step_by(step)
            .copied()
            .collect::<Vec<_>>()
            .into()
    }
}
