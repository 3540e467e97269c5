//! The depth camera: pinhole intrinsics, pixel rays and 16-bit depth images.
//!
//! Camera frame: origin at the optical centre, x right, y up, z forward (the skeleton stands at
//! z > 0 facing −z). Pixel (u, v) has v growing downwards, so its ray is
//! ((u − cx)/fx, −(v − cy)/fy, 1). A depth image stores z (not the range along the ray) in
//! units of `depth_scale` metres; 0 means "no measurement".

use std::path::Path;

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::error::BodyError;

/// Pinhole intrinsics and the depth unit of a depth camera.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    pub width: u32,
    pub height: u32,
    pub fx: f32,
    pub fy: f32,
    pub cx: f32,
    pub cy: f32,
    /// Metres per depth unit in a 16-bit depth image (0.001: millimetres).
    pub depth_scale: f32,
}

impl Intrinsics {
    /// A camera of `width × height` pixels with the given horizontal field of view, square pixels
    /// and millimetre depth.
    pub fn with_fov(width: u32, height: u32, horizontal_fov_deg: f32) -> Result<Self, BodyError> {
        let f = width as f32 / 2.0 / (horizontal_fov_deg.to_radians() / 2.0).tan();
        let intrinsics = Self {
            width,
            height,
            fx: f,
            fy: f,
            cx: (width as f32 - 1.0) / 2.0,
            cy: (height as f32 - 1.0) / 2.0,
            depth_scale: 0.001,
        };
        intrinsics.validate()?;
        Ok(intrinsics)
    }

    pub fn validate(&self) -> Result<(), BodyError> {
        let finite = [self.fx, self.fy, self.cx, self.cy, self.depth_scale]
            .iter()
            .all(|x| x.is_finite());
        if self.width == 0 || self.height == 0 {
            return Err(BodyError::InvalidInput(format!(
                "camera size {}x{}: both must be > 0",
                self.width, self.height
            )));
        }
        if !finite || self.fx <= 0.0 || self.fy <= 0.0 || self.depth_scale <= 0.0 {
            return Err(BodyError::InvalidInput(format!(
                "camera intrinsics need finite fx, fy, depth_scale > 0 and finite cx, cy; got fx {}, fy {}, cx {}, cy {}, depth_scale {}",
                self.fx, self.fy, self.cx, self.cy, self.depth_scale
            )));
        }
        Ok(())
    }

    /// The ray through pixel (u, v), scaled to z = 1.
    pub fn pixel_ray(&self, u: f32, v: f32) -> Vector3<f32> {
        Vector3::new((u - self.cx) / self.fx, -(v - self.cy) / self.fy, 1.0)
    }

    /// The pixel a camera-frame point projects to (None behind the camera).
    pub fn project(&self, p: &Vector3<f32>) -> Option<(f32, f32)> {
        (p.z > 0.0).then(|| (self.cx + self.fx * p.x / p.z, self.cy - self.fy * p.y / p.z))
    }

    /// Reads intrinsics from a JSON file.
    pub fn load(path: &Path) -> Result<Self, BodyError> {
        let text = std::fs::read_to_string(path).map_err(|e| file_error(path, e))?;
        let intrinsics: Self = serde_json::from_str(&text).map_err(|e| file_error(path, e))?;
        intrinsics
            .validate()
            .map_err(|e| file_error(path, e.to_string()))?;
        Ok(intrinsics)
    }

    pub fn save(&self, path: &Path) -> Result<(), BodyError> {
        let text = serde_json::to_string_pretty(self).map_err(|e| file_error(path, e))?;
        std::fs::write(path, text).map_err(|e| file_error(path, e))
    }
}

pub(crate) fn file_error(path: &Path, message: impl ToString) -> BodyError {
    BodyError::File {
        path: path.display().to_string(),
        message: message.to_string(),
    }
}

/// A depth image: z in depth units per pixel, row-major, 0 = no measurement.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthImage {
    pub width: u32,
    pub height: u32,
    pub depth: Vec<u16>,
}

impl DepthImage {
    /// The measured pixels back-projected to camera-frame points.
    pub fn to_points(&self, intrinsics: &Intrinsics) -> Result<Vec<Vector3<f32>>, BodyError> {
        if (self.width, self.height) != (intrinsics.width, intrinsics.height) {
            return Err(BodyError::InvalidInput(format!(
                "the depth image is {}x{} but the camera is {}x{}",
                self.width, self.height, intrinsics.width, intrinsics.height
            )));
        }
        let mut points = Vec::new();
        for v in 0..self.height {
            for u in 0..self.width {
                let raw = self.depth[(v * self.width + u) as usize];
                if raw > 0 {
                    let z = f32::from(raw) * intrinsics.depth_scale;
                    points.push(intrinsics.pixel_ray(u as f32, v as f32) * z);
                }
            }
        }
        Ok(points)
    }
}

/// Reads a 16-bit single-channel (gray) PNG depth image. Any other PNG — 8-bit, colour, with
/// alpha — is an error that says what was found.
pub fn read_depth_png(path: &Path) -> Result<DepthImage, BodyError> {
    let reader = image::ImageReader::open(path)
        .map_err(|e| file_error(path, e))?
        .with_guessed_format()
        .map_err(|e| file_error(path, e))?;
    if reader.format() != Some(image::ImageFormat::Png) {
        return Err(file_error(path, "not a PNG file"));
    }
    let decoded = reader
        .decode()
        .map_err(|e| file_error(path, format!("cannot decode the PNG: {e}")))?;
    match decoded {
        image::DynamicImage::ImageLuma16(img) => Ok(DepthImage {
            width: img.width(),
            height: img.height(),
            depth: img.into_raw(),
        }),
        other => Err(file_error(
            path,
            format!(
                "a depth image must be a 16-bit single-channel PNG; this one is {:?}",
                other.color()
            ),
        )),
    }
}

/// Writes a 16-bit gray PNG depth image.
pub fn write_depth_png(path: &Path, depth: &DepthImage) -> Result<(), BodyError> {
    let img = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_raw(
        depth.width,
        depth.height,
        depth.depth.clone(),
    )
    .ok_or_else(|| file_error(path, "the depth buffer does not match its size"))?;
    img.save_with_format(path, image::ImageFormat::Png)
        .map_err(|e| file_error(path, e))
}
