//! Viola–Jones face detection with OpenCV's Haar cascades, in Rust (no OpenCV at run time).
//!
//! As OpenCV's `CascadeClassifier::detectMultiScale`: the frame is shrunk by `scale_factor` per
//! level (bilinear), the cascade's window slides over each level (step 2, 1 once the frame is
//! shrunk more than twice; a window rejected by the first stage also skips the next position),
//! each window is variance-normalised by its integral and squared-integral images (windows of
//! standard deviation below about 10 gray levels are skipped), and the hits are grouped:
//! rectangles within `eps = 0.2` of each other form a cluster, clusters of at most
//! `min_neighbors` hits are dropped, the rest are averaged, and a cluster inside a stronger one
//! is dropped.

pub mod cascade;
mod compiled;
mod detector;
pub mod gpu;

use rayon::prelude::*;

pub use cascade::Cascade;
use compiled::{CompiledCascade, LevelFeatures};
pub use detector::FaceDetector;
pub use gpu::GpuCascade;

/// The WGSL of the Viola–Jones detector, launched by [`gpu::GpuCascade`]; [`Cascade::window_hits`]
/// is its CPU twin.
pub const SHADER: &str = include_str!("../../../../shaders/face/detect.wgsl");

use crate::error::FaceError;
use crate::image::GrayImage;

/// Where Debian's opencv-data puts OpenCV's frontal-face cascade, the detector's default for the
/// command line and the Python package alike.
pub const DEFAULT_CASCADE: &str =
    "/usr/share/opencv4/haarcascades/haarcascade_frontalface_alt2.xml";

/// Where the detector runs (`face track --detector`, Python's `detector=`): the one rule for
/// both.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DetectorPlacement {
    /// On a GPU when the tracker runs on one, else on the CPU.
    Auto,
    Cpu,
    Gpu,
}

impl DetectorPlacement {
    /// Whether the detector goes on a GPU beside a tracker on `backend`.
    pub fn runs_on_gpu(self, backend: &crate::FaceBackend) -> bool {
        match self {
            DetectorPlacement::Cpu => false,
            DetectorPlacement::Gpu => true,
            DetectorPlacement::Auto => !matches!(backend, crate::FaceBackend::Cpu),
        }
    }
}

impl std::str::FromStr for DetectorPlacement {
    type Err = FaceError;

    fn from_str(name: &str) -> Result<Self, FaceError> {
        match name {
            "auto" => Ok(DetectorPlacement::Auto),
            "cpu" => Ok(DetectorPlacement::Cpu),
            "gpu" => Ok(DetectorPlacement::Gpu),
            other => Err(FaceError::InvalidInput(format!(
                "detector must be \"auto\", \"cpu\" or \"gpu\", got {other:?}"
            ))),
        }
    }
}

/// A detected face: a rectangle in frame pixels, and how many raw hits it groups.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Detection {
    pub x: i32,
    pub y: i32,
    pub width: i32,
    pub height: i32,
    pub neighbors: usize,
}

impl Detection {
    /// Intersection over union with another rectangle.
    pub fn iou(&self, other: &Detection) -> f64 {
        let ix = (self.x + self.width).min(other.x + other.width) - self.x.max(other.x);
        let iy = (self.y + self.height).min(other.y + other.height) - self.y.max(other.y);
        if ix <= 0 || iy <= 0 {
            return 0.0;
        }
        let inter = f64::from(ix) * f64::from(iy);
        let union = f64::from(self.width) * f64::from(self.height)
            + f64::from(other.width) * f64::from(other.height)
            - inter;
        inter / union
    }
}

/// The detector's settings (OpenCV's `detectMultiScale` arguments).
#[derive(Debug, Clone, PartialEq)]
pub struct DetectConfig {
    /// The shrink factor between pyramid levels (> 1).
    pub scale_factor: f64,
    /// A cluster needs more than this many raw hits.
    pub min_neighbors: usize,
    /// The smallest face searched for (pixels; the cascade's window when smaller).
    pub min_size: u32,
    /// The largest face searched for (pixels; the frame when `None`).
    pub max_size: Option<u32>,
}

impl Default for DetectConfig {
    fn default() -> Self {
        Self {
            scale_factor: 1.1,
            min_neighbors: 3,
            min_size: 30,
            max_size: None,
        }
    }
}

impl DetectConfig {
    pub fn validate(&self) -> Result<(), FaceError> {
        if !(self.scale_factor.is_finite() && self.scale_factor > 1.0) {
            return Err(FaceError::InvalidInput(format!(
                "the scale factor must be > 1, got {}",
                self.scale_factor
            )));
        }
        if let Some(max) = self.max_size
            && max < self.min_size
        {
            return Err(FaceError::InvalidInput(format!(
                "the largest face ({max} px) is smaller than the smallest ({} px)",
                self.min_size
            )));
        }
        Ok(())
    }
}

/// Grouping tolerance (OpenCV's `groupRectangles` eps).
const GROUP_EPS: f64 = 0.2;

/// One level of the detector's pyramid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct PyramidLevel {
    /// How much the frame is shrunk.
    pub factor: f64,
    /// The shrunk frame's size.
    pub scaled: (u32, u32),
    /// The cascade's window in frame pixels.
    pub window: (u32, u32),
}

impl PyramidLevel {
    /// The window's step on this level: 2, or 1 once the frame is shrunk more than twice.
    pub fn step(&self) -> usize {
        if self.factor > 2.0 { 1 } else { 2 }
    }

    /// A window found at (x, y) of this level, in frame pixels.
    pub fn detection(&self, x: usize, y: usize) -> Detection {
        Detection {
            x: (x as f64 * self.factor).round_ties_even() as i32,
            y: (y as f64 * self.factor).round_ties_even() as i32,
            width: self.window.0 as i32,
            height: self.window.1 as i32,
            neighbors: 1,
        }
    }
}

impl Cascade {
    /// The faces in `frame`.
    pub fn detect(
        &self,
        frame: &GrayImage,
        config: &DetectConfig,
    ) -> Result<Vec<Detection>, FaceError> {
        Ok(group(
            &self.window_hits(frame, config)?,
            config.min_neighbors,
        ))
    }

    /// Every window that passes the cascade, ungrouped: level by level (finest first), row by
    /// row, left to right.
    pub fn window_hits(
        &self,
        frame: &GrayImage,
        config: &DetectConfig,
    ) -> Result<Vec<Detection>, FaceError> {
        config.validate()?;
        // Each level's resize, integral images and scan are a task of their own (its rows in
        // parallel too), and the hits come back in level order.
        let compiled = CompiledCascade::new(self);
        Ok(self
            .pyramid((frame.width, frame.height), config)
            .into_par_iter()
            .flat_map_iter(|level| {
                let image = Level::new(&resize(frame, level.scaled.0, level.scaled.1));
                let features = LevelFeatures::new(&self.features, image.width + 1);
                self.scan(&image, &compiled, &features, &level)
            })
            .collect())
    }

    /// The pyramid's levels for a frame of `size` (finest first): those whose window is at least
    /// `min_size` and at most `max_size`, while the shrunk frame is larger than the window.
    pub(crate) fn pyramid(&self, size: (u32, u32), config: &DetectConfig) -> Vec<PyramidLevel> {
        let mut levels = Vec::new();
        let mut factor = 1.0f64;
        loop {
            let window = (
                (f64::from(self.width) * factor).round_ties_even() as u32,
                (f64::from(self.height) * factor).round_ties_even() as u32,
            );
            let scaled = (
                (f64::from(size.0) / factor).round_ties_even() as u32,
                (f64::from(size.1) / factor).round_ties_even() as u32,
            );
            if scaled.0 <= self.width || scaled.1 <= self.height {
                break;
            }
            if config
                .max_size
                .is_some_and(|max| window.0 > max || window.1 > max)
            {
                break;
            }
            if window.0 >= config.min_size && window.1 >= config.min_size {
                levels.push(PyramidLevel {
                    factor,
                    scaled,
                    window,
                });
            }
            factor *= config.scale_factor;
        }
        levels
    }

    /// Every window of one pyramid level that passes the cascade, in frame pixels.
    fn scan(
        &self,
        level: &Level,
        compiled: &CompiledCascade,
        features: &LevelFeatures,
        pyramid_level: &PyramidLevel,
    ) -> Vec<Detection> {
        let (w, h) = (self.width as usize, self.height as usize);
        let step = pyramid_level.step();
        let rows: Vec<usize> = (0..level.height - h).step_by(step).collect();
        rows.par_iter()
            .flat_map_iter(|&y| {
                let mut found = Vec::new();
                let mut x = 0;
                while x < level.width - w {
                    match self.run_at(level, compiled, features, x, y) {
                        Verdict::Face => found.push(pyramid_level.detection(x, y)),
                        // Rejected by the first stage: the next window is skipped too.
                        Verdict::FirstStage => x += step,
                        Verdict::Later | Verdict::Flat => {}
                    }
                    x += step;
                }
                found
            })
            .collect()
    }

    fn run_at(
        &self,
        level: &Level,
        compiled: &CompiledCascade,
        features: &LevelFeatures,
        x: usize,
        y: usize,
    ) -> Verdict {
        let (w, h) = (self.width as usize, self.height as usize);
        // The variance over the window less a one-pixel border.
        let area = ((w - 2) * (h - 2)) as f64;
        let sum = level.sum(x + 1, y + 1, w - 2, h - 2) as f64;
        let squares = level.sum_of_squares(x + 1, y + 1, w - 2, h - 2) as f64;
        let spread = area * squares - sum * sum;
        if spread <= 0.0 {
            return Verdict::Flat;
        }
        let norm = 1.0 / spread.sqrt();
        if area * norm >= 0.1 {
            return Verdict::Flat;
        }
        let origin = y * (level.width + 1) + x;
        let feature = |f: usize| features.value(f, &level.integral, origin) * norm;
        match compiled.first_failing_stage(feature) {
            None => Verdict::Face,
            Some(0) => Verdict::FirstStage,
            Some(_) => Verdict::Later,
        }
    }
}

enum Verdict {
    Face,
    FirstStage,
    Later,
    /// Too little contrast to evaluate.
    Flat,
}

/// A pyramid level's integral and squared-integral images, `(width + 1) × (height + 1)`.
struct Level {
    width: usize,
    height: usize,
    integral: Vec<i64>,
    squares: Vec<i64>,
}

impl Level {
    fn new(image: &GrayImage) -> Self {
        let (w, h) = (image.width as usize, image.height as usize);
        let stride = w + 1;
        let mut integral = vec![0i64; stride * (h + 1)];
        let mut squares = vec![0i64; stride * (h + 1)];
        for y in 0..h {
            let (mut row, mut row_sq) = (0i64, 0i64);
            for x in 0..w {
                let v = i64::from(image.data[y * w + x]);
                row += v;
                row_sq += v * v;
                integral[(y + 1) * stride + x + 1] = integral[y * stride + x + 1] + row;
                squares[(y + 1) * stride + x + 1] = squares[y * stride + x + 1] + row_sq;
            }
        }
        Self {
            width: w,
            height: h,
            integral,
            squares,
        }
    }

    fn rect(table: &[i64], stride: usize, x: usize, y: usize, w: usize, h: usize) -> i64 {
        table[(y + h) * stride + x + w] - table[y * stride + x + w] - table[(y + h) * stride + x]
            + table[y * stride + x]
    }

    fn sum(&self, x: usize, y: usize, w: usize, h: usize) -> i64 {
        Self::rect(&self.integral, self.width + 1, x, y, w, h)
    }

    fn sum_of_squares(&self, x: usize, y: usize, w: usize, h: usize) -> i64 {
        Self::rect(&self.squares, self.width + 1, x, y, w, h)
    }
}

/// Bilinear resize with pixel centres aligned (OpenCV's `INTER_LINEAR` convention), rounded to
/// 8 bits.
pub(crate) fn resize(image: &GrayImage, width: u32, height: u32) -> GrayImage {
    let mut data = vec![0u8; width as usize * height as usize];
    resize_into(image, width, height, &mut data);
    GrayImage {
        width,
        height,
        data,
    }
}

/// [`resize`] into `out` (`width × height` bytes, row-major): the GPU detector writes each
/// pyramid level straight into its upload.
pub(crate) fn resize_into(image: &GrayImage, width: u32, height: u32, out: &mut [u8]) {
    debug_assert_eq!(out.len(), width as usize * height as usize);
    if (width, height) == (image.width, image.height) {
        out.copy_from_slice(&image.data);
        return;
    }
    if width == 0 || height == 0 {
        return;
    }
    let (sx, sy) = (
        f64::from(image.width) / f64::from(width),
        f64::from(image.height) / f64::from(height),
    );
    let source = |c: u32, scale: f64, size: u32| -> (usize, usize, f32) {
        let s = ((f64::from(c) + 0.5) * scale - 0.5).max(0.0);
        let i0 = (s.floor() as u32).min(size - 1);
        let i1 = (i0 + 1).min(size - 1);
        (
            i0 as usize,
            i1 as usize,
            (s - f64::from(i0)).min(1.0) as f32,
        )
    };
    let columns: Vec<_> = (0..width).map(|x| source(x, sx, image.width)).collect();
    let stride = image.width as usize;
    out.par_chunks_mut(width as usize)
        .enumerate()
        .for_each(|(y, row)| {
            let (y0, y1, fy) = source(y as u32, sy, image.height);
            let at = |yy: usize, xx: usize| f32::from(image.data[yy * stride + xx]);
            for (value, &(x0, x1, fx)) in row.iter_mut().zip(&columns) {
                let top = at(y0, x0) * (1.0 - fx) + at(y0, x1) * fx;
                let bottom = at(y1, x0) * (1.0 - fx) + at(y1, x1) * fx;
                *value = (top * (1.0 - fy) + bottom * fy + 0.5) as u8;
            }
        });
}

/// OpenCV's `groupRectangles` (rounding halves to even, as its cvRound): clusters of similar rectangles (union of pairs within eps) with
/// more than `min_neighbors` members, averaged; a cluster inside a stronger one is dropped.
pub fn group(hits: &[Detection], min_neighbors: usize) -> Vec<Detection> {
    let n = hits.len();
    let mut parent: Vec<usize> = (0..n).collect();
    fn root(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    let similar = |a: &Detection, b: &Detection| {
        let delta = GROUP_EPS * f64::from(a.width.min(b.width) + a.height.min(b.height)) * 0.5;
        let close = |p: i32, q: i32| f64::from((p - q).abs()) <= delta;
        close(a.x, b.x)
            && close(a.y, b.y)
            && close(a.x + a.width, b.x + b.width)
            && close(a.y + a.height, b.y + b.height)
    };
    for i in 0..n {
        for j in i + 1..n {
            if similar(&hits[i], &hits[j]) {
                let (a, b) = (root(&mut parent, i), root(&mut parent, j));
                parent[a.max(b)] = a.min(b);
            }
        }
    }
    // Sums per cluster, in order of first member.
    let mut clusters: Vec<(usize, [i64; 4], usize)> = Vec::new();
    for (i, h) in hits.iter().enumerate() {
        let r = root(&mut parent, i);
        let add = [h.x, h.y, h.width, h.height].map(i64::from);
        match clusters.iter_mut().find(|c| c.0 == r) {
            Some(c) => {
                for (sum, v) in c.1.iter_mut().zip(add) {
                    *sum += v;
                }
                c.2 += 1;
            }
            None => clusters.push((r, add, 1)),
        }
    }
    let averaged: Vec<Detection> = clusters
        .iter()
        .map(|&(_, s, count)| {
            let mean = |v: i64| (v as f64 / count as f64).round_ties_even() as i32;
            Detection {
                x: mean(s[0]),
                y: mean(s[1]),
                width: mean(s[2]),
                height: mean(s[3]),
                neighbors: count,
            }
        })
        .collect();
    averaged
        .iter()
        .filter(|r1| r1.neighbors > min_neighbors)
        .filter(|r1| {
            !averaged.iter().any(|r2| {
                if std::ptr::eq(*r1, r2) || r2.neighbors <= min_neighbors {
                    return false;
                }
                let dx = (f64::from(r2.width) * GROUP_EPS).round_ties_even() as i32;
                let dy = (f64::from(r2.height) * GROUP_EPS).round_ties_even() as i32;
                r1.x >= r2.x - dx
                    && r1.y >= r2.y - dy
                    && r1.x + r1.width <= r2.x + r2.width + dx
                    && r1.y + r1.height <= r2.y + r2.height + dy
                    && (r2.neighbors > r1.neighbors.max(3) || r1.neighbors < 3)
            })
        })
        .copied()
        .collect()
}

#[cfg(test)]
mod tests {
    use super::DetectorPlacement;
    use crate::FaceBackend;

    #[test]
    fn the_detector_goes_where_it_is_told_and_beside_a_cpu_tracker_by_default() {
        assert!(!DetectorPlacement::Auto.runs_on_gpu(&FaceBackend::Cpu));
        assert!(!DetectorPlacement::Cpu.runs_on_gpu(&FaceBackend::Cpu));
        assert!(DetectorPlacement::Gpu.runs_on_gpu(&FaceBackend::Cpu));
        for (name, placement) in [
            ("auto", DetectorPlacement::Auto),
            ("cpu", DetectorPlacement::Cpu),
            ("gpu", DetectorPlacement::Gpu),
        ] {
            assert_eq!(name.parse::<DetectorPlacement>().ok(), Some(placement));
        }
        let err = "tpu".parse::<DetectorPlacement>().unwrap_err().to_string();
        assert!(
            err.contains("detector must be") && err.contains("tpu"),
            "{err}"
        );
    }
}
