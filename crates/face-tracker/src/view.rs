//! How a face is seen when its template is taken.
//!
//! A new track's template is taken as if the face looked straight at the camera: a pixel at
//! (x, y) from the face rectangle's centre lies on the model at u = x / half-width,
//! v = y / half-height. A track that restarts on a new template goes on from its pose, so the
//! face is seen turned by the track's rotation R and scaled by its S: each pixel then lies where
//! the model turned by R shows it, found by casting the pixel's ray (weak perspective: along the
//! viewing axis) onto the turned model surface.

use nalgebra::{Matrix3, Vector3};

use crate::lens::Lens;
use crate::model::FaceModel;

/// The scale and rotation a face is seen with: S maps the model's units to pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct View {
    pub scale: f32,
    pub rotation: Matrix3<f32>,
}

/// A ray is marched from this many of the face's half-sizes in front of the head's centre to as
/// far behind it (the models' heights lie within ±1.5 half-widths)...
const MARCH_REACH: f32 = 3.0;
/// ... in this many steps (each under a tenth of the face's half-width, finer than a nose's
/// side), and the first crossing of the surface then bisected this many times.
const MARCH_STEPS: usize = 256;
const BISECTION_STEPS: usize = 24;

impl View {
    /// The face looking straight at the camera at the size of its rectangle.
    pub fn frontal() -> Self {
        Self {
            scale: 1.0,
            rotation: Matrix3::identity(),
        }
    }

    /// The model's point and normal seen at `offset` (pixels from the face rectangle's centre),
    /// in model units, if the pixel's ray meets the model facing the camera
    /// ([`Self::unproject`]). Seen frontally the point is the offset itself with the model's
    /// height there, exactly.
    pub fn cast(
        &self,
        model: &FaceModel,
        half: (f32, f32),
        offset: [f32; 2],
    ) -> Option<([f32; 3], [f32; 3])> {
        let (u, v) = self.unproject(model, half, offset)?;
        let (height, normal) = model.sample(u, v);
        let point = if self.is_frontal() {
            [offset[0], offset[1], height * half.0]
        } else {
            self.surface_point(model, half, u, v)
        };
        Some((point, normal))
    }

    /// [`Self::cast`] for a face seen through `lens`, its centre at `centre` in the frame: the
    /// first point of the model on the ray from the camera's centre through the pixel at
    /// `offset` from the face's centre ([`Self::unproject_through`]). Weak perspective is
    /// [`Self::cast`] itself.
    pub fn cast_through(
        &self,
        lens: &Lens,
        centre: [f32; 2],
        model: &FaceModel,
        half: (f32, f32),
        offset: [f32; 2],
    ) -> Option<([f32; 3], [f32; 3])> {
        if lens.is_weak() {
            return self.cast(model, half, offset);
        }
        let (u, v) = self.unproject_through(lens, centre, model, half, offset)?;
        Some((self.surface_point(model, half, u, v), model.sample(u, v).1))
    }

    /// [`Self::unproject`] for a face seen through `lens`, its centre at `centre` in the frame:
    /// through a pinhole the pixel's ray is not the viewing axis but the line from the camera's
    /// centre, so the ray's point at depth d (pixels nearer the camera than the face's centre)
    /// lies where weak perspective would show it at the pixel moved towards the principal
    /// point by d/f ([`Lens::unapply`]).
    pub fn unproject_through(
        &self,
        lens: &Lens,
        centre: [f32; 2],
        model: &FaceModel,
        half: (f32, f32),
        offset: [f32; 2],
    ) -> Option<(f32, f32)> {
        if lens.is_weak() {
            return self.unproject(model, half, offset);
        }
        let image = [centre[0] + offset[0], centre[1] + offset[1]];
        let weak_offset = |depth: f32| {
            // At or behind the camera the ray has no point (NaN is off the model).
            if lens.apply([0.0; 2], depth).is_none() {
                return [f32::NAN; 2];
            }
            let weak = lens.unapply(image, depth);
            [weak[0] - centre[0], weak[1] - centre[1]]
        };
        self.march(model, half, &weak_offset)
    }

    /// Whether this is [`Self::frontal`].
    pub fn is_frontal(&self) -> bool {
        self.scale == 1.0 && self.rotation == Matrix3::identity()
    }

    /// The model's point at (u, v) in model units, for a face whose rectangle has half-sizes
    /// `half` (pixels): x and y from u and v, the height from the model, all divided by S.
    pub fn surface_point(&self, model: &FaceModel, half: (f32, f32), u: f32, v: f32) -> [f32; 3] {
        let (hw, hh) = half;
        let height = model.sample(u, v).0;
        [u * hw, v * hh, height * hw].map(|c| c / self.scale)
    }

    /// The model coordinates (u, v) of the surface point seen at `offset` (pixels from the face
    /// rectangle's centre): the first point of the model's surface on the pixel's ray, coming
    /// from the camera, or `None` where the ray misses the model (beyond u, v = ±1) or grazes it
    /// facing away.
    pub fn unproject(
        &self,
        model: &FaceModel,
        half: (f32, f32),
        offset: [f32; 2],
    ) -> Option<(f32, f32)> {
        let (hw, hh) = half;
        if self.is_frontal() {
            let uv = [offset[0] / hw, offset[1] / hh];
            return inside_model(uv).then_some((uv[0], uv[1]));
        }
        self.march(model, half, &|_| offset)
    }

    /// The first surface point on a ray, coming from the camera: the ray's point at depth d
    /// (pixels nearer the camera than the face's centre) is the one weak perspective shows at
    /// `offset_at(d)` from the face's centre (the same offset for every depth: the viewing
    /// axis).
    fn march(
        &self,
        model: &FaceModel,
        half: (f32, f32),
        offset_at: &dyn Fn(f32) -> [f32; 2],
    ) -> Option<(f32, f32)> {
        let (hw, hh) = half;
        // In model units: the ray's point at depth t (towards the camera) turned back into the
        // model's frame, and how far it lies above the surface there (None off the model).
        let (a, b) = (hw / self.scale, hh / self.scale);
        let back = self.rotation.transpose();
        let ray = |t: f32| {
            let offset = offset_at(t * self.scale);
            back * Vector3::new(offset[0] / self.scale, offset[1] / self.scale, t)
        };
        let above = |t: f32| {
            let p = ray(t);
            let uv = [p.x / a, p.y / b];
            inside_model(uv).then(|| (p.z - model.sample(uv[0], uv[1]).0 * a, uv))
        };
        // March from in front of the whole head to behind it; the first step from above the
        // surface to below it brackets the visible point, which bisection then finds. A ray
        // that comes onto the model's square already below the surface passes under the face
        // (through the side of the head, which the model does not describe): a miss.
        let reach = MARCH_REACH * a.max(b);
        let step = 2.0 * reach / MARCH_STEPS as f32;
        let mut front = reach;
        let mut was_above = false;
        for k in 1..=MARCH_STEPS {
            let t = reach - k as f32 * step;
            match above(t) {
                Some((gap, _)) if gap <= 0.0 && !was_above => return None,
                Some((gap, _)) if gap <= 0.0 => {
                    let (mut lo, mut hi) = (t, front);
                    for _ in 0..BISECTION_STEPS {
                        let mid = 0.5 * (lo + hi);
                        match above(mid) {
                            Some((gap, _)) if gap <= 0.0 => lo = mid,
                            _ => hi = mid,
                        }
                    }
                    let (_, uv) = above(lo)?;
                    let facing = self.rotation * Vector3::from(model.sample(uv[0], uv[1]).1);
                    return (facing.z >= 0.0).then_some((uv[0], uv[1]));
                }
                sample => {
                    front = t;
                    was_above = sample.is_some();
                }
            }
        }
        None
    }
}

fn inside_model(uv: [f32; 2]) -> bool {
    uv[0].abs() <= 1.0 && uv[1].abs() <= 1.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::projection::{Pose, rotation};
    use proptest::prelude::*;

    /// Where a model point appears, in pixels from the rectangle's centre (the tracker's own
    /// projection, `Pose::project`), and how near the camera it lies.
    fn project(view: &View, p: [f32; 3]) -> ([f32; 2], f32) {
        let pose = Pose {
            translation: nalgebra::Vector2::zeros(),
            scale: view.scale,
            rotation: view.rotation,
            alpha: 1.0,
        };
        let at = pose.project(&Vector3::from(p));
        ([at.x, at.y], (view.rotation * Vector3::from(p)).z)
    }

    proptest! {
        /// A pixel showing a model point casts onto the first surface point on its ray: the
        /// point itself, or one nearer the camera that hides it (the nose hides a cheek), for
        /// turns up to 40° and the middle of the face.
        #[test]
        fn a_pixel_casts_onto_the_point_it_shows(
            u in -0.6f32..0.6, v in -0.7f32..0.7,
            angles in prop::array::uniform3(-0.7f32..0.7),
            scale in 0.3f32..3.0,
            half_width in 20.0f32..200.0,
        ) {
            let model = FaceModel::generic(65).unwrap();
            let view = View { scale, rotation: rotation(angles[0], angles[1], angles[2]) };
            let half = (half_width, half_width * 1.25);
            let facing = view.rotation * Vector3::from(model.sample(u, v).1);
            prop_assume!(facing.z > 0.3);
            let (seen, depth) = project(&view, view.surface_point(&model, half, u, v));
            let (cu, cv) = view.unproject(&model, half, seen).expect("the ray meets the model");
            let (back, cast_depth) = project(&view, view.surface_point(&model, half, cu, cv));
            prop_assert!((back[0] - seen[0]).hypot(back[1] - seen[1]) < 0.05, "{back:?} vs {seen:?}");
            let tolerance = 1e-3 * half_width / scale;
            prop_assert!(cast_depth >= depth - tolerance, "{cast_depth} behind {depth}");
            if cast_depth <= depth + tolerance {
                prop_assert!((cu - u).abs() < 1e-2 && (cv - v).abs() < 1e-2, "({cu}, {cv}) vs ({u}, {v})");
            }
        }
    }

    #[test]
    fn the_frontal_view_is_the_rectangle_s_coordinates() {
        let model = FaceModel::generic(65).unwrap();
        let view = View::frontal();
        assert_eq!(
            view.unproject(&model, (50.0, 62.5), [25.0, -31.25]),
            Some((0.5, -0.5))
        );
        assert_eq!(view.unproject(&model, (50.0, 62.5), [60.0, 0.0]), None);
        let p = view.surface_point(&model, (50.0, 62.5), 0.5, -0.5);
        assert_eq!(p, [25.0, -31.25, model.sample(0.5, -0.5).0 * 50.0]);
    }

    #[test]
    fn a_ray_past_a_face_turned_away_misses() {
        let model = FaceModel::generic(65).unwrap();
        // Turned 60° to the side: the far cheek's edge is out of sight, and far past the face's
        // side the ray meets nothing.
        let view = View {
            scale: 1.0,
            rotation: rotation(0.0, 1.05, 0.0),
        };
        assert_eq!(view.unproject(&model, (50.0, 62.5), [80.0, 0.0]), None);
        assert_eq!(view.unproject(&model, (50.0, 62.5), [-80.0, 0.0]), None);
    }
}
