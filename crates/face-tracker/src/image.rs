//! Gray images, row-major, with bilinear sampling (continuous, so that a rounding difference
//! between CPU and GPU cannot jump a pixel).
//!
//! Frames are [`GrayImage`]: 8-bit levels, as cameras, video decoders and image files give them
//! and as the GPU kernels read them (a texture of 8-bit levels for the likelihood, four to a word
//! for the detector), so a frame reaches the GPU without a conversion, and both backends see the same pixels. Image processing that needs sub-level
//! precision (the smoothing and Laplacian of template extraction) works on [`FloatImage`].

use std::path::Path;

use rayon::prelude::*;

use crate::error::{FaceError, file_error};

/// A pixel type: 8-bit levels or f32 levels (0–255).
pub trait Level: Copy + Send + Sync + 'static {
    fn level(self) -> f32;
}

impl Level for u8 {
    fn level(self) -> f32 {
        f32::from(self)
    }
}

impl Level for f32 {
    fn level(self) -> f32 {
        self
    }
}

/// A gray image, `data[y·width + x]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Image<T: Level> {
    pub width: u32,
    pub height: u32,
    pub data: Vec<T>,
}

/// A frame: 8-bit gray levels.
pub type GrayImage = Image<u8>;

/// Gray levels at f32 precision (smoothed images).
pub type FloatImage = Image<f32>;

/// The size check every image shares: at least 2×2 (bilinear sampling needs a cell), and the
/// data must match the size.
fn check_size(width: u32, height: u32, len: usize) -> Result<(), FaceError> {
    if width < 2 || height < 2 {
        return Err(FaceError::InvalidInput(format!(
            "an image must be at least 2x2 pixels, got {width}x{height}"
        )));
    }
    if len != width as usize * height as usize {
        return Err(FaceError::InvalidInput(format!(
            "{len} pixels for a {width}x{height} image"
        )));
    }
    Ok(())
}

impl<T: Level> Image<T> {
    /// The level at (x, y).
    pub fn at(&self, x: u32, y: u32) -> f32 {
        self.data[(y * self.width + x) as usize].level()
    }

    /// Whether (x, y) lies where bilinear sampling has all four neighbours.
    pub fn contains(&self, x: f32, y: f32) -> bool {
        x >= 0.0 && y >= 0.0 && x <= (self.width - 1) as f32 && y <= (self.height - 1) as f32
    }

    /// The bilinear interpolation at (x, y), or `None` outside [0, w−1] × [0, h−1].
    #[inline]
    pub fn bilinear(&self, x: f32, y: f32) -> Option<f32> {
        if !self.contains(x, y) {
            return None;
        }
        // The cell's corner is clamped so that the last row and column interpolate within it;
        // x, y ≥ 0 here, so truncation is the floor (without a libm call).
        let x0 = (x as u32).min(self.width - 2);
        let y0 = (y as u32).min(self.height - 2);
        let (fx, fy) = (x - x0 as f32, y - y0 as f32);
        let top = self.at(x0, y0) * (1.0 - fx) + self.at(x0 + 1, y0) * fx;
        let bottom = self.at(x0, y0 + 1) * (1.0 - fx) + self.at(x0 + 1, y0 + 1) * fx;
        Some(top * (1.0 - fy) + bottom * fy)
    }
}

impl GrayImage {
    /// A frame from its 8-bit levels; the size must be at least 2×2 and match the data.
    pub fn new(width: u32, height: u32, data: Vec<u8>) -> Result<Self, FaceError> {
        check_size(width, height, data.len())?;
        Ok(Self {
            width,
            height,
            data,
        })
    }

    /// A frame from levels on the 0–255 scale, each rounded to the nearest 8-bit level (and
    /// clamped): rendered or computed images. Non-finite levels are an error.
    pub fn from_levels(width: u32, height: u32, levels: &[f32]) -> Result<Self, FaceError> {
        check_size(width, height, levels.len())?;
        // On all cores: a rendered 1024×768 frame is 786 432 conversions.
        if let Some(i) = levels.par_iter().position_first(|v| !v.is_finite()) {
            return Err(FaceError::InvalidInput(format!(
                "pixel {i} is {}",
                levels[i]
            )));
        }
        let data = levels
            .par_iter()
            .with_min_len(1 << 14)
            .map(|&v| to_level(v))
            .collect();
        Self::new(width, height, data)
    }

    /// [`Image::from_levels`] on the calling thread alone (for work already spread over the
    /// cores a frame at a time).
    pub fn from_levels_on_this_thread(
        width: u32,
        height: u32,
        levels: &[f32],
    ) -> Result<Self, FaceError> {
        check_size(width, height, levels.len())?;
        if let Some(i) = levels.iter().position(|v| !v.is_finite()) {
            return Err(FaceError::InvalidInput(format!(
                "pixel {i} is {}",
                levels[i]
            )));
        }
        Self::new(width, height, levels.iter().map(|&v| to_level(v)).collect())
    }

    /// A constant frame.
    pub fn filled(width: u32, height: u32, level: u8) -> Result<Self, FaceError> {
        Self::new(width, height, vec![level; width as usize * height as usize])
    }

    /// Reads any image the `image` crate decodes (PNG here) as 8-bit gray levels.
    pub fn load(path: &Path) -> Result<Self, FaceError> {
        let decoded = image::ImageReader::open(path)
            .map_err(|e| file_error(path, e))?
            .with_guessed_format()
            .map_err(|e| file_error(path, e))?
            .decode()
            .map_err(|e| file_error(path, format!("cannot decode the image: {e}")))?;
        let gray = decoded.to_luma8();
        let (width, height) = gray.dimensions();
        Self::new(width, height, gray.into_raw()).map_err(|e| file_error(path, e))
    }

    /// Writes the frame as an 8-bit gray PNG.
    pub fn save_png(&self, path: &Path) -> Result<(), FaceError> {
        image::GrayImage::from_raw(self.width, self.height, self.data.clone())
            .ok_or_else(|| file_error(path, "the pixel buffer does not match the size"))?
            .save_with_format(path, image::ImageFormat::Png)
            .map_err(|e| file_error(path, e))
    }
}

impl FloatImage {
    /// An image of f32 levels; the size must be at least 2×2 and match the data.
    pub fn new(width: u32, height: u32, data: Vec<f32>) -> Result<Self, FaceError> {
        check_size(width, height, data.len())?;
        Ok(Self {
            width,
            height,
            data,
        })
    }
}

/// A level rounded to the nearest of 0–255 (clamped first, so the cast's truncation is a floor).
fn to_level(v: f32) -> u8 {
    (v.clamp(0.0, 255.0) + 0.5) as u8
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn levels_round_to_the_nearest_eight_bit_level() {
        let image = GrayImage::from_levels(3, 2, &[-3.0, 2.49, 2.5, 254.6, 300.0, 0.4]).unwrap();
        assert_eq!(image.data, [0, 2, 3, 255, 255, 0]);
        let whole: Vec<f32> = (0..=255).map(|v| v as f32).collect();
        let image = GrayImage::from_levels(16, 16, &whole).unwrap();
        assert!(image.data.iter().enumerate().all(|(i, &v)| v as usize == i));
        assert!(GrayImage::from_levels(2, 2, &[0.0, f32::NAN, 0.0, 0.0]).is_err());
        assert!(GrayImage::new(3, 3, vec![0; 8]).is_err());
        assert!(FloatImage::new(1, 3, vec![0.0; 3]).is_err());
    }

    #[test]
    fn bilinear_reads_eight_bit_and_float_images_alike() {
        let levels = [10.0, 20.0, 30.0, 40.0, 50.0, 60.0];
        let gray = GrayImage::from_levels(3, 2, &levels).unwrap();
        let float = FloatImage::new(3, 2, levels.to_vec()).unwrap();
        for (x, y) in [(0.0, 0.0), (0.5, 0.5), (1.25, 0.75), (2.0, 1.0)] {
            assert_eq!(gray.bilinear(x, y), float.bilinear(x, y));
        }
        // (0.5, 0.5): the mean of 10, 20, 40, 50.
        assert_eq!(gray.bilinear(0.5, 0.5), Some(30.0));
        assert_eq!(gray.bilinear(2.01, 0.0), None);
        assert_eq!(gray.bilinear(-0.01, 0.0), None);
    }
}
