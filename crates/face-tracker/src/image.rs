//! Gray images as the tracker sees them: f32 gray levels (0–255), row-major, with bilinear
//! sampling (continuous, so that a rounding difference between CPU and GPU cannot jump a pixel).

use std::path::Path;

use rayon::prelude::*;

use crate::error::{FaceError, file_error};

/// A gray image, `data[y·width + x]`.
#[derive(Debug, Clone, PartialEq)]
pub struct GrayImage {
    pub width: u32,
    pub height: u32,
    pub data: Vec<f32>,
}

impl GrayImage {
    /// An image from its pixels; the size must be at least 2×2 (bilinear sampling needs a cell)
    /// and match the data.
    pub fn new(width: u32, height: u32, data: Vec<f32>) -> Result<Self, FaceError> {
        if width < 2 || height < 2 {
            return Err(FaceError::InvalidInput(format!(
                "an image must be at least 2x2 pixels, got {width}x{height}"
            )));
        }
        if data.len() != width as usize * height as usize {
            return Err(FaceError::InvalidInput(format!(
                "{} pixels for a {width}x{height} image",
                data.len()
            )));
        }
        if let Some(i) = data.iter().position(|v| !v.is_finite()) {
            return Err(FaceError::InvalidInput(format!("pixel {i} is {}", data[i])));
        }
        Ok(Self {
            width,
            height,
            data,
        })
    }

    /// An image from 8-bit gray levels (a decoded video frame, say).
    pub fn from_gray8(width: u32, height: u32, levels: &[u8]) -> Result<Self, FaceError> {
        Self::new(
            width,
            height,
            levels.iter().map(|&v| f32::from(v)).collect(),
        )
    }

    /// The image at 8 bits, each level rounded and clamped to 0–255 — what an 8-bit camera gives
    /// and what the GPU kernel reads — written into `out` (resized to the pixel count), rows in
    /// parallel. Images decoded from files and the synthetic frames are whole levels already,
    /// so for them this loses nothing.
    pub fn write_gray8(&self, out: &mut Vec<u8>) {
        out.resize(self.data.len(), 0);
        const CHUNK: usize = 1 << 14;
        out.par_chunks_mut(CHUNK)
            .zip(self.data.par_chunks(CHUNK))
            .for_each(|(bytes, levels)| {
                for (b, &v) in bytes.iter_mut().zip(levels) {
                    *b = to_level(v);
                }
            });
    }

    /// A constant image.
    pub fn filled(width: u32, height: u32, value: f32) -> Result<Self, FaceError> {
        Self::new(width, height, vec![value; width as usize * height as usize])
    }

    pub fn at(&self, x: u32, y: u32) -> f32 {
        self.data[(y * self.width + x) as usize]
    }

    /// Whether (x, y) lies where bilinear sampling has all four neighbours.
    pub fn contains(&self, x: f32, y: f32) -> bool {
        x >= 0.0 && y >= 0.0 && x <= (self.width - 1) as f32 && y <= (self.height - 1) as f32
    }

    /// The bilinear interpolation at (x, y), or `None` outside [0, w−1] × [0, h−1].
    pub fn bilinear(&self, x: f32, y: f32) -> Option<f32> {
        if !self.contains(x, y) {
            return None;
        }
        // The cell's corner is clamped so that the last row and column interpolate within it.
        let x0 = (x.floor() as u32).min(self.width - 2);
        let y0 = (y.floor() as u32).min(self.height - 2);
        let (fx, fy) = (x - x0 as f32, y - y0 as f32);
        let top = self.at(x0, y0) * (1.0 - fx) + self.at(x0 + 1, y0) * fx;
        let bottom = self.at(x0, y0 + 1) * (1.0 - fx) + self.at(x0 + 1, y0 + 1) * fx;
        Some(top * (1.0 - fy) + bottom * fy)
    }

    /// Reads any image the `image` crate decodes (PNG here) as gray levels.
    pub fn load(path: &Path) -> Result<Self, FaceError> {
        let decoded = image::ImageReader::open(path)
            .map_err(|e| file_error(path, e))?
            .with_guessed_format()
            .map_err(|e| file_error(path, e))?
            .decode()
            .map_err(|e| file_error(path, format!("cannot decode the image: {e}")))?;
        let gray = decoded.to_luma32f();
        let (width, height) = gray.dimensions();
        let data = gray.into_raw().into_iter().map(|v| v * 255.0).collect();
        Self::new(width, height, data).map_err(|e| file_error(path, e))
    }

    /// Writes the image as an 8-bit gray PNG (values clamped to 0–255).
    pub fn save_png(&self, path: &Path) -> Result<(), FaceError> {
        let mut bytes = Vec::new();
        self.write_gray8(&mut bytes);
        image::GrayImage::from_raw(self.width, self.height, bytes)
            .ok_or_else(|| file_error(path, "the pixel buffer does not match the size"))?
            .save_with_format(path, image::ImageFormat::Png)
            .map_err(|e| file_error(path, e))
    }
}

/// A gray level rounded to the nearest of 0–255 (clamped first, so the cast's truncation is a
/// floor; no call to `round`, so the loop vectorises).
fn to_level(v: f32) -> u8 {
    (v.clamp(0.0, 255.0) + 0.5) as u8
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eight_bit_levels_round_trip_and_round_to_nearest() {
        let levels: Vec<u8> = (0..=255).collect();
        let image = GrayImage::from_gray8(16, 16, &levels).unwrap();
        let mut back = vec![7; 3];
        image.write_gray8(&mut back);
        assert_eq!(back, levels);

        let image = GrayImage::new(3, 2, vec![-3.0, 2.49, 2.5, 254.6, 300.0, 0.4]).unwrap();
        image.write_gray8(&mut back);
        assert_eq!(back, [0, 2, 3, 255, 255, 0]);
        assert!(GrayImage::from_gray8(3, 3, &levels[..8]).is_err());
    }
}
