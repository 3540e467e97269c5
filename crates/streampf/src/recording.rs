//! `--rerun FILE.rrd`: a recording of a run for the rerun viewer (`rerun FILE.rrd`), built with
//! the `rerun` cargo feature. The entity paths are documented in docs/OUTPUT.md.
//!
//! Faces (2D, over the frame): `video/frame` (the gray frame), per track
//! `video/faces/TRACK/{points,axes,box,particles}` (the posed template points, the head's axes,
//! the rectangle labelled with the track and confidence, the particles' centres), cleared when
//! the track is lost; time series `metrics/faces/TRACK/{ess,confidence,residual}` and, with the
//! ground truth, `translation_error_px` and `rotation_error_deg`.
//!
//! Body (3D, the camera frame: x right, y up, z forward): `world/points` (the frame's points),
//! `world/estimate` and `world/truth` (the skeletons' capsules), `world/particles` (each sample's
//! root position); time series `metrics/{ess,confidence,joint_error_m}`.
//!
//! Both put every frame on a `frame` sequence timeline and a `time` timeline in seconds.

use std::path::Path;

use body_tracker::Skeleton;
use face_tracker::{FaceEstimate, GrayImage, Template};
use nalgebra::Vector3;

/// One face frame's particle clouds: the batch's states (targets × dims × particles,
/// dimension-major per target) and the particles per target.
#[cfg_attr(not(feature = "rerun"), allow(dead_code))]
pub struct FaceClouds<'a> {
    pub states: &'a [f32],
    pub particles: usize,
}

/// What a face frame shows.
#[cfg_attr(not(feature = "rerun"), allow(dead_code))]
pub struct FaceFrame<'a> {
    pub frame: usize,
    /// The frame's time, seconds.
    pub seconds: f64,
    pub image: &'a GrayImage,
    pub templates: &'a [(usize, &'a Template)],
    pub estimates: &'a [FaceEstimate],
    /// The camera the faces are seen through.
    pub lens: face_tracker::likelihood::Lens,
    pub clouds: Option<FaceClouds<'a>>,
    /// (track, translation error in pixels, rotation error in degrees) against the truth.
    pub errors: &'a [(usize, f32, f32)],
}

/// What a body frame shows.
#[cfg_attr(not(feature = "rerun"), allow(dead_code))]
pub struct BodyFrame<'a> {
    pub frame: usize,
    pub points: &'a [Vector3<f32>],
    pub pose: &'a [f32],
    pub truth: Option<&'a [f32]>,
    pub ess: f64,
    pub confidence: f32,
    pub joint_error: Option<f32>,
    /// The samples' poses: dims × samples, dimension-major (the root's tx, ty, tz first).
    pub samples: Option<(&'a [f32], usize)>,
}

#[cfg(feature = "rerun")]
pub use enabled::Recording;

#[cfg(not(feature = "rerun"))]
pub use disabled::Recording;

#[cfg(not(feature = "rerun"))]
mod disabled {
    use super::*;

    /// Without the `rerun` feature: `--rerun` is refused before anything runs.
    pub struct Recording(std::convert::Infallible);

    impl Recording {
        pub fn create(_path: &Path, _application: &'static str) -> anyhow::Result<Self> {
            anyhow::bail!(
                "--rerun needs streampf built with the rerun feature: cargo build --release -p \
                 streampf --features rerun"
            )
        }

        pub fn face_frame(&self, _frame: FaceFrame<'_>) -> anyhow::Result<()> {
            match self.0 {}
        }

        pub fn body_frame(
            &self,
            _skeleton: &Skeleton,
            _frame: BodyFrame<'_>,
        ) -> anyhow::Result<()> {
            match self.0 {}
        }

        pub fn finish(self) -> anyhow::Result<()> {
            match self.0 {}
        }
    }
}

#[cfg(feature = "rerun")]
mod enabled {
    use super::*;
    use anyhow::Context;
    use face_tracker::TrackStatus;

    /// The tracks' colours, points and axes, as the overlay draws them.
    use crate::face_overlay::{AXIS_COLOURS, TRACK_COLOURS, head_axes, posed_points};

    pub struct Recording {
        stream: rerun::RecordingStream,
    }

    impl Recording {
        /// A recording written to `path` as the run goes.
        pub fn create(path: &Path, application: &'static str) -> anyhow::Result<Self> {
            if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
                std::fs::create_dir_all(parent)
                    .with_context(|| format!("--rerun: creating {}", parent.display()))?;
            }
            let stream = rerun::RecordingStreamBuilder::new(application)
                .save(path)
                .with_context(|| format!("--rerun: cannot write {}", path.display()))?;
            Ok(Self { stream })
        }

        fn at(&self, frame: usize, seconds: f64) {
            self.stream.set_time_sequence("frame", frame as i64);
            self.stream.set_duration_secs("time", seconds);
        }

        fn scalar(&self, path: &str, value: f64) -> anyhow::Result<()> {
            Ok(self.stream.log(path, &rerun::Scalars::single(value))?)
        }

        /// One face frame: the frame, each running track's points, axes, box and particles,
        /// the time series.
        pub fn face_frame(&self, f: FaceFrame<'_>) -> anyhow::Result<()> {
            let FaceFrame {
                frame,
                seconds,
                image,
                templates,
                estimates,
                lens,
                clouds,
                errors,
            } = f;
            self.at(frame, seconds);
            self.stream.log(
                "video/frame",
                &rerun::Image::from_l8(image.data.clone(), [image.width, image.height]),
            )?;
            for e in estimates {
                let template = (templates.iter())
                    .find(|(t, _)| *t == e.track)
                    .map(|(_, template)| *template);
                self.log_face(e, template, &lens, clouds.as_ref())?;
            }
            for &(track, translation, rotation) in errors {
                let metrics = format!("metrics/faces/{track}");
                self.scalar(
                    &format!("{metrics}/translation_error_px"),
                    f64::from(translation),
                )?;
                self.scalar(
                    &format!("{metrics}/rotation_error_deg"),
                    f64::from(rotation),
                )?;
            }
            Ok(())
        }

        /// One face's entities (its points where its template is known, its head axes, its
        /// box and label, its samples' centres) and its time series; a lost track is cleared.
        fn log_face(
            &self,
            e: &FaceEstimate,
            template: Option<&Template>,
            lens: &face_tracker::likelihood::Lens,
            clouds: Option<&FaceClouds<'_>>,
        ) -> anyhow::Result<()> {
            let base = format!("video/faces/{}", e.track);
            if let TrackStatus::Lost { .. } = e.status {
                self.stream.log(base.as_str(), &rerun::Clear::recursive())?;
                return Ok(());
            }
            let colour = TRACK_COLOURS[e.track % TRACK_COLOURS.len()];
            let colour = rerun::Color::from_rgb(colour[0], colour[1], colour[2]);
            if let Some(template) = template {
                let visible: Vec<[f32; 2]> = (posed_points(e, template, lens).into_iter())
                    .map(|(x, y)| [x, y])
                    .collect();
                self.stream.log(
                    format!("{base}/points"),
                    &rerun::Points2D::new(visible)
                        .with_colors([colour])
                        .with_radii([1.0]),
                )?;
            }
            let (origin, ends) = head_axes(e, lens);
            let strips: Vec<Vec<[f32; 2]>> = ends
                .iter()
                .map(|end| vec![[origin.0, origin.1], [end.0, end.1]])
                .collect();
            let axis_colours = AXIS_COLOURS.map(|[r, g, b]| rerun::Color::from_rgb(r, g, b));
            self.stream.log(
                format!("{base}/axes"),
                &rerun::LineStrips2D::new(strips).with_colors(axis_colours),
            )?;
            self.stream.log(
                format!("{base}/box"),
                &rerun::Boxes2D::from_mins_and_sizes(
                    [(e.rect.x, e.rect.y)],
                    [(e.rect.width, e.rect.height)],
                )
                .with_colors([colour])
                .with_labels([crate::face_overlay::face_label(e)]),
            )?;
            if let Some(clouds) = clouds {
                self.log_samples(&base, e.slot, clouds, colour)?;
            }
            let metrics = format!("metrics/faces/{}", e.track);
            self.scalar(&format!("{metrics}/ess"), e.ess)?;
            self.scalar(&format!("{metrics}/confidence"), f64::from(e.confidence))?;
            self.scalar(&format!("{metrics}/residual"), e.error)
        }

        /// The image-plane centres (x, y) of a slot's samples.
        fn log_samples(
            &self,
            base: &str,
            slot: usize,
            clouds: &FaceClouds<'_>,
            colour: rerun::Color,
        ) -> anyhow::Result<()> {
            let m = clouds.particles;
            let start = slot * face_tracker::projection::DIMS * m;
            if let Some(target) = clouds.states.get(start..start + 2 * m) {
                let centres: Vec<[f32; 2]> = (0..m).map(|k| [target[k], target[m + k]]).collect();
                self.stream.log(
                    format!("{base}/particles"),
                    &rerun::Points2D::new(centres)
                        .with_colors([colour])
                        .with_radii([0.5]),
                )?;
            }
            Ok(())
        }

        /// One body frame: points, the estimated (and true) capsules, the samples' roots, the
        /// time series.
        pub fn body_frame(&self, skeleton: &Skeleton, f: BodyFrame<'_>) -> anyhow::Result<()> {
            if f.frame == 0 {
                self.stream
                    .log_static("world", &rerun::ViewCoordinates::RUF())?;
            }
            // The body sequences carry no frame rate: 30 frames/s, a depth camera's.
            self.at(f.frame, f.frame as f64 / 30.0);
            let points: Vec<[f32; 3]> = f.points.iter().map(|p| [p.x, p.y, p.z]).collect();
            self.stream.log(
                "world/points",
                &rerun::Points3D::new(points)
                    .with_radii([0.004])
                    .with_colors([rerun::Color::from_rgb(170, 170, 170)]),
            )?;
            self.stream.log(
                "world/estimate",
                &capsules(&skeleton.capsules(f.pose)?, [255, 140, 0]),
            )?;
            if let Some(truth) = f.truth {
                self.stream.log(
                    "world/truth",
                    &capsules(&skeleton.capsules(truth)?, [0, 230, 80]),
                )?;
            }
            if let Some((states, samples)) = f.samples {
                let roots: Vec<[f32; 3]> = (0..samples)
                    .filter_map(|k| {
                        Some([
                            *states.get(k)?,
                            *states.get(samples + k)?,
                            *states.get(2 * samples + k)?,
                        ])
                    })
                    .collect();
                self.stream.log(
                    "world/particles",
                    &rerun::Points3D::new(roots)
                        .with_radii([0.006])
                        .with_colors([rerun::Color::from_rgb(80, 160, 255)]),
                )?;
            }
            self.scalar("metrics/ess", f.ess)?;
            self.scalar("metrics/confidence", f64::from(f.confidence))?;
            if let Some(error) = f.joint_error {
                self.scalar("metrics/joint_error_m", f64::from(error))?;
            }
            Ok(())
        }

        /// Flushes the file: everything logged is on disk.
        pub fn finish(self) -> anyhow::Result<()> {
            self.stream
                .flush_blocking()
                .context("--rerun: writing the recording")
        }
    }

    fn capsules(capsules: &[body_tracker::capsule::Capsule], colour: [u8; 3]) -> rerun::Capsules3D {
        let starts: Vec<[f32; 3]> = capsules.iter().map(|c| [c.a.x, c.a.y, c.a.z]).collect();
        let ends: Vec<[f32; 3]> = capsules.iter().map(|c| [c.b.x, c.b.y, c.b.z]).collect();
        rerun::Capsules3D::from_endpoints_and_radii(starts, ends, capsules.iter().map(|c| c.radius))
            .with_colors([rerun::Color::from_rgb(colour[0], colour[1], colour[2])])
    }
}
