//! A small face enlarged before its template is taken.
//!
//! The template's extraction works at a fixed pixel scale (a blur of σ 1.2 px, points at least
//! 3 px apart, dipole ends 2 px from their edge) and the 68-landmark fit was trained on faces a
//! hundred pixels and more across. A face 35–45 px wide gets 50–60 coarse points and a poor fit,
//! and its tracks read pitch and yaw badly (docs/ACCURACY.md, "Small faces"). Such a face's
//! region is enlarged by a whole factor (bilinear: no detail is invented, the pixel scale of the
//! extraction and of the fit is what changes), the landmarks are fitted and the template is
//! extracted there, and the template is scaled back to the frame. The likelihood still samples
//! the frame itself: at whole factors the enlarged region's bilinear samples are the frame's
//! (a bilinear patch is reproduced exactly by bilinear interpolation of its own samples) to
//! within the 8-bit rounding of the region's levels (half a gray level), so the template's gray
//! levels agree with what the tracker will see.

use crate::error::FaceError;
use crate::extraction::FaceRect;
use crate::image::GrayImage;
use crate::lens::Lens;
use crate::template::Template;

/// The largest factor a face is enlarged by (a 12-px face to 48 px; smaller faces stay smaller).
pub const MAX_FACTOR: u32 = 4;

/// The region around a face, enlarged by a whole factor.
#[derive(Debug, Clone)]
pub struct Enlarged {
    /// The enlarged region: its pixel (i, j) is the frame's bilinear sample at
    /// `origin + (i, j) / factor`.
    pub frame: GrayImage,
    /// The face's rectangle in `frame`.
    pub rect: FaceRect,
    origin: [f32; 2],
    factor: f32,
}

impl Enlarged {
    /// The region around `rect` (half its width on every side, within the frame) enlarged by the
    /// smallest whole factor that makes the face at least `min_width` pixels wide (at most
    /// [`MAX_FACTOR`]); `None` when the face is that wide already.
    pub fn around(
        frame: &GrayImage,
        rect: &FaceRect,
        min_width: f32,
    ) -> Result<Option<Self>, FaceError> {
        rect.validate(frame)?;
        if !(min_width.is_finite() && min_width >= 0.0) {
            return Err(FaceError::InvalidInput(format!(
                "the width faces are enlarged to must be finite and >= 0 pixels, got {min_width}"
            )));
        }
        if rect.width >= min_width {
            return Ok(None);
        }
        let factor = ((min_width / rect.width).ceil() as u32).clamp(2, MAX_FACTOR) as f32;
        // Room around the face on every side (the landmark fit looks at a square of the
        // rectangle's height about its centre, within half a width of it; the blur and the
        // dipoles need a few pixels past the face's ellipse).
        let margin = 0.5 * rect.width;
        let (last_x, last_y) = ((frame.width - 1) as f32, (frame.height - 1) as f32);
        let x0 = (rect.x - margin).max(0.0).floor();
        let y0 = (rect.y - margin).max(0.0).floor();
        // Up to the frame's far edge, not its last pixel: a rectangle may end at the edge, and
        // the region must hold it; samples past the last pixel repeat it.
        let x1 = (rect.x + rect.width + margin)
            .ceil()
            .min(frame.width as f32);
        let y1 = (rect.y + rect.height + margin)
            .ceil()
            .min(frame.height as f32);
        let width = ((x1 - x0) * factor) as u32 + 1;
        let height = ((y1 - y0) * factor) as u32 + 1;
        let mut data = Vec::with_capacity(width as usize * height as usize);
        for j in 0..height {
            for i in 0..width {
                let (x, y) = (x0 + i as f32 / factor, y0 + j as f32 / factor);
                let level = frame
                    .bilinear(x.min(last_x), y.min(last_y))
                    .unwrap_or_default();
                data.push(level.round().clamp(0.0, 255.0) as u8);
            }
        }
        Ok(Some(Self {
            frame: GrayImage::new(width, height, data)?,
            rect: FaceRect {
                x: (rect.x - x0) * factor,
                y: (rect.y - y0) * factor,
                width: rect.width * factor,
                height: rect.height * factor,
            },
            origin: [x0, y0],
            factor,
        }))
    }

    /// How many times the region is enlarged.
    pub fn factor(&self) -> f32 {
        self.factor
    }

    /// The frame's pixel of a point of the enlarged region.
    pub fn to_frame(&self, point: [f32; 2]) -> [f32; 2] {
        [
            self.origin[0] + point[0] / self.factor,
            self.origin[1] + point[1] / self.factor,
        ]
    }

    /// `lens` as the enlarged region sees the scene: the principal point moved with the region,
    /// the focal length (in pixels) times the factor.
    pub fn lens(&self, lens: &Lens) -> Lens {
        if lens.is_weak() {
            return *lens;
        }
        Lens {
            inverse_focal: lens.inverse_focal / self.factor,
            principal: [
                (lens.principal[0] - self.origin[0]) * self.factor,
                (lens.principal[1] - self.origin[1]) * self.factor,
            ],
        }
    }

    /// A template taken from the enlarged region, in the frame's pixels: its points and
    /// landmarks (pixels at S = 1, depth included) divided by the factor; normals and gray
    /// levels are unchanged.
    pub fn shrink(&self, mut template: Template) -> Template {
        for point in &mut template.points {
            for c in &mut point.position {
                *c /= self.factor;
            }
        }
        for landmark in template.landmarks.iter_mut().flatten() {
            for c in landmark.iter_mut() {
                *c /= self.factor;
            }
        }
        template
    }
}
