//! Pictures of a body frame: the measured points seen from the depth camera, shaded by depth
//! (near bright), with the estimated skeleton's capsules filled over them and the ground truth's
//! outlined.
//!
//! A capsule is drawn as its perspective silhouette's usual approximation: the image segment
//! between its two end centres, swept by a disc whose radius goes linearly from f·r/z_a to
//! f·r/z_b. The estimate is the union of its capsules' silhouettes (filled, edged) with each
//! capsule's axis drawn as a line; the truth is its union's outline.

use image::{Rgb, RgbImage};
use nalgebra::Vector3;
use rayon::prelude::*;

use crate::camera::Intrinsics;
use crate::capsule::Capsule;

/// The estimate's fill, its outline and the ground truth's outline.
pub const ESTIMATE_FILL: [u8; 3] = [255, 140, 0];
pub const ESTIMATE_EDGE: [u8; 3] = [255, 220, 120];
pub const TRUTH_EDGE: [u8; 3] = [0, 230, 80];
/// Each estimated capsule's axis.
pub const BONE: [u8; 3] = [150, 30, 0];
/// How much of the estimate's fill covers the points under it.
const FILL_OPACITY: f32 = 0.55;

/// A capsule as the image sees it: end centres and radii in pixels.
#[derive(Debug, Clone, Copy)]
struct ImageCapsule {
    a: (f32, f32),
    b: (f32, f32),
    radius_a: f32,
    radius_b: f32,
}

impl ImageCapsule {
    /// None when an end is behind the camera.
    fn project(camera: &Intrinsics, capsule: &Capsule) -> Option<Self> {
        let a = camera.project(&capsule.a)?;
        let b = camera.project(&capsule.b)?;
        Some(Self {
            a,
            b,
            radius_a: camera.fx * capsule.radius / capsule.a.z,
            radius_b: camera.fx * capsule.radius / capsule.b.z,
        })
    }

    /// How far inside the silhouette pixel centre (x, y) lies, in pixels (negative: outside).
    fn inside_by(&self, x: f32, y: f32) -> f32 {
        let (dx, dy) = (self.b.0 - self.a.0, self.b.1 - self.a.1);
        let length2 = dx * dx + dy * dy;
        let t = if length2 > 0.0 {
            (((x - self.a.0) * dx + (y - self.a.1) * dy) / length2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let (px, py) = (self.a.0 + t * dx - x, self.a.1 + t * dy - y);
        let radius = self.radius_a + t * (self.radius_b - self.radius_a);
        radius - (px * px + py * py).sqrt()
    }

    /// The pixel rows and columns the silhouette can touch, clipped to the image.
    fn bounds(&self, width: u32, height: u32) -> Option<(u32, u32, u32, u32)> {
        let r = self.radius_a.max(self.radius_b) + 1.0;
        let x0 = (self.a.0.min(self.b.0) - r).floor().max(0.0);
        let y0 = (self.a.1.min(self.b.1) - r).floor().max(0.0);
        let x1 = (self.a.0.max(self.b.0) + r).ceil().min(width as f32 - 1.0);
        let y1 = (self.a.1.max(self.b.1) + r).ceil().min(height as f32 - 1.0);
        (x0 <= x1 && y0 <= y1 && x1 >= 0.0 && y1 >= 0.0)
            .then_some((x0 as u32, y0 as u32, x1 as u32, y1 as u32))
    }
}

/// The points as the camera sees them: each point's pixel shaded by its depth (nearest wins;
/// near white, far dark gray), the rest black.
pub fn depth_view(camera: &Intrinsics, points: &[Vector3<f32>]) -> RgbImage {
    let (width, height) = (camera.width, camera.height);
    let mut nearest = vec![f32::INFINITY; width as usize * height as usize];
    for p in points {
        if let Some((u, v)) = camera.project(p) {
            let (u, v) = (u.round(), v.round());
            if u >= 0.0 && v >= 0.0 && u < width as f32 && v < height as f32 {
                let i = v as usize * width as usize + u as usize;
                nearest[i] = nearest[i].min(p.z);
            }
        }
    }
    let finite = nearest.iter().copied().filter(|z| z.is_finite());
    let (near, far) = finite.fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), z| {
        (lo.min(z), hi.max(z))
    });
    let span = (far - near).max(1e-3);
    let mut image = RgbImage::new(width, height);
    for (pixel, z) in image.pixels_mut().zip(&nearest) {
        if z.is_finite() {
            let level = 255.0 - 175.0 * (z - near) / span;
            let level = level.clamp(0.0, 255.0) as u8;
            *pixel = Rgb([level, level, level]);
        }
    }
    image
}

/// `image` with the silhouette of `estimate`'s capsules filled and edged and each capsule's axis
/// drawn (the bones), and the silhouette of `truth`'s outlined.
pub fn draw_capsules(
    image: &mut RgbImage,
    camera: &Intrinsics,
    estimate: &[Capsule],
    truth: Option<&[Capsule]>,
) {
    let (width, height) = image.dimensions();
    let project = |capsules: &[Capsule]| -> Vec<ImageCapsule> {
        capsules
            .iter()
            .filter_map(|c| ImageCapsule::project(camera, c))
            .collect()
    };
    let estimate = project(estimate);
    let body = silhouette(&estimate, width, height);
    for (i, pixel) in image.pixels_mut().enumerate() {
        if body[i] {
            *pixel = if on_edge(&body, i, width, height) {
                Rgb(ESTIMATE_EDGE)
            } else {
                blend(*pixel, ESTIMATE_FILL, FILL_OPACITY)
            };
        }
    }
    for capsule in &estimate {
        line(image, capsule.a, capsule.b, BONE);
    }
    if let Some(truth) = truth {
        let truth = silhouette(&project(truth), width, height);
        for (i, pixel) in image.pixels_mut().enumerate() {
            // Two pixels wide: the silhouette's last pixel inside and first outside.
            let edge = if truth[i] {
                on_edge(&truth, i, width, height)
            } else {
                touches(&truth, i, width, height)
            };
            if edge {
                *pixel = Rgb(TRUTH_EDGE);
            }
        }
    }
}

/// The depth view of `points` with the capsules drawn over it.
pub fn overlay(
    camera: &Intrinsics,
    points: &[Vector3<f32>],
    estimate: &[Capsule],
    truth: Option<&[Capsule]>,
) -> RgbImage {
    let mut image = depth_view(camera, points);
    draw_capsules(&mut image, camera, estimate, truth);
    image
}

/// Which pixels lie inside any of the capsules (row-major, `width × height`), rows in parallel.
fn silhouette(capsules: &[ImageCapsule], width: u32, height: u32) -> Vec<bool> {
    let mut mask = vec![false; width as usize * height as usize];
    let boxes: Vec<_> = capsules
        .iter()
        .filter_map(|c| Some((c, c.bounds(width, height)?)))
        .collect();
    mask.par_chunks_mut(width as usize)
        .enumerate()
        .for_each(|(y, row)| {
            let y = y as u32;
            for (capsule, (x0, y0, x1, y1)) in &boxes {
                if (*y0..=*y1).contains(&y) {
                    for x in *x0..=*x1 {
                        row[x as usize] |= capsule.inside_by(x as f32, y as f32) >= 0.0;
                    }
                }
            }
        });
    mask
}

/// Whether pixel `i` of a mask has a 4-neighbour outside it (or lies on the image's border).
fn on_edge(mask: &[bool], i: usize, width: u32, height: u32) -> bool {
    let (w, h) = (width as usize, height as usize);
    let (x, y) = (i % w, i / w);
    x == 0
        || y == 0
        || x + 1 == w
        || y + 1 == h
        || !mask[i - 1]
        || !mask[i + 1]
        || !mask[i - w]
        || !mask[i + w]
}

/// Whether pixel `i` has a 4-neighbour inside the mask.
fn touches(mask: &[bool], i: usize, width: u32, height: u32) -> bool {
    let (w, h) = (width as usize, height as usize);
    let (x, y) = (i % w, i / w);
    (x > 0 && mask[i - 1])
        || (x + 1 < w && mask[i + 1])
        || (y > 0 && mask[i - w])
        || (y + 1 < h && mask[i + w])
}

/// A one-pixel line from `a` to `b`, clipped to the image.
fn line(image: &mut RgbImage, a: (f32, f32), b: (f32, f32), colour: [u8; 3]) {
    let steps = ((b.0 - a.0).abs().max((b.1 - a.1).abs()).ceil() as usize).max(1);
    for k in 0..=steps {
        let t = k as f32 / steps as f32;
        let (x, y) = (
            (a.0 + (b.0 - a.0) * t).round(),
            (a.1 + (b.1 - a.1) * t).round(),
        );
        if x >= 0.0 && y >= 0.0 && x < image.width() as f32 && y < image.height() as f32 {
            image.put_pixel(x as u32, y as u32, Rgb(colour));
        }
    }
}

fn blend(under: Rgb<u8>, over: [u8; 3], opacity: f32) -> Rgb<u8> {
    Rgb(std::array::from_fn(|c| {
        (f32::from(under.0[c]) * (1.0 - opacity) + f32::from(over[c]) * opacity).round() as u8
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera() -> Intrinsics {
        Intrinsics::with_fov(160, 120, 60.0).unwrap()
    }

    #[test]
    fn a_capsule_covers_the_pixels_of_its_axis_and_not_those_far_from_it() {
        let camera = camera();
        let capsule = Capsule {
            a: Vector3::new(-0.3, 0.0, 2.0),
            b: Vector3::new(0.3, 0.0, 2.0),
            radius: 0.05,
        };
        let mut image = RgbImage::new(160, 120);
        draw_capsules(&mut image, &camera, &[capsule], None);
        let (u, v) = camera.project(&Vector3::new(0.0, 0.0, 2.0)).unwrap();
        let (u, v) = (u.round() as u32, v.round() as u32);
        // The axis is the bone's line; beside it, the fill over the (black) background.
        assert_eq!(image.get_pixel(u, v).0, BONE);
        assert_eq!(
            image.get_pixel(u, v - 2).0,
            blend(Rgb([0, 0, 0]), ESTIMATE_FILL, FILL_OPACITY).0
        );
        // Radius f·r/z ≈ 139·0.05/2 ≈ 3.5 px: 10 px above the axis is untouched.
        assert_eq!(image.get_pixel(u, v - 10).0, [0, 0, 0]);
        // The truth is outlined only: its axis stays as it was.
        let mut outlined = RgbImage::new(160, 120);
        draw_capsules(&mut outlined, &camera, &[], Some(&[capsule]));
        assert_eq!(outlined.get_pixel(u, v).0, [0, 0, 0]);
        assert!(outlined.pixels().any(|p| p.0 == TRUTH_EDGE));
    }

    #[test]
    fn nearer_points_are_brighter_and_capsules_behind_the_camera_are_skipped() {
        let camera = camera();
        let near = Vector3::new(0.0, 0.0, 1.0);
        let far = Vector3::new(0.5, 0.0, 3.0);
        let image = depth_view(&camera, &[near, far]);
        let at = |p: &Vector3<f32>| {
            let (u, v) = camera.project(p).unwrap();
            image.get_pixel(u.round() as u32, v.round() as u32).0[0]
        };
        assert!(at(&near) > at(&far), "{} vs {}", at(&near), at(&far));
        let behind = Capsule {
            a: Vector3::new(0.0, 0.0, -1.0),
            b: Vector3::new(0.0, 0.0, 1.0),
            radius: 0.1,
        };
        let mut image = RgbImage::new(160, 120);
        draw_capsules(&mut image, &camera, &[behind], Some(&[behind]));
        assert!(image.pixels().all(|p| p.0 == [0, 0, 0]));
    }
}
