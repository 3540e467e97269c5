//! A camera's intrinsics, given on the command line (`fx,fy,cx,cy`) or read from a calibration
//! file as OpenCV's `FileStorage` writes it (YAML with its `%YAML:1.0` header and
//! `!!opencv-matrix` tags, or JSON), and the [`Lens`] faces are seen through with them.
//!
//! The tracker models square pixels and no lens distortion: `fx` and `fy` may differ by at most
//! [`MAX_ASPECT_DIFFERENCE`] (calibrations of ordinary cameras differ by well under 1 %), and
//! their mean is the focal length; distortion coefficients are read and reported so that a caller
//! can say they are not applied.

use std::path::Path;

use yaml_rust2::{Yaml, YamlLoader};

use crate::error::{FaceError, file_error};
use crate::lens::Lens;

/// The largest |fy/fx − 1| accepted: the tracker's pixels are square.
pub const MAX_ASPECT_DIFFERENCE: f32 = 0.05;

/// Focal lengths (pixels) and the principal point (pixels, x right and y down from the top-left
/// pixel's centre), as OpenCV's camera matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] holds them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Intrinsics {
    pub fx: f32,
    pub fy: f32,
    pub cx: f32,
    pub cy: f32,
}

impl Intrinsics {
    /// Checked intrinsics: finite, positive focal lengths within [`MAX_ASPECT_DIFFERENCE`] of each
    /// other, a finite principal point.
    pub fn new(fx: f32, fy: f32, cx: f32, cy: f32) -> Result<Self, FaceError> {
        if !(fx.is_finite() && fy.is_finite() && fx > 0.0 && fy > 0.0) {
            return Err(FaceError::InvalidInput(format!(
                "focal lengths must be finite and positive (pixels), got fx {fx}, fy {fy}"
            )));
        }
        if !(cx.is_finite() && cy.is_finite()) {
            return Err(FaceError::InvalidInput(format!(
                "the principal point must be finite (pixels), got ({cx}, {cy})"
            )));
        }
        if (fy / fx - 1.0).abs() > MAX_ASPECT_DIFFERENCE {
            return Err(FaceError::InvalidInput(format!(
                "fx {fx} and fy {fy} differ by more than {:.0} %: the tracker models square pixels; \
                 resample the video to square pixels and scale the calibration with it",
                100.0 * MAX_ASPECT_DIFFERENCE
            )));
        }
        Ok(Self { fx, fy, cx, cy })
    }

    /// `fx,fy,cx,cy` in pixels, as `face track --camera` takes them.
    pub fn parse(text: &str) -> Result<Self, FaceError> {
        let values: Vec<f32> = text
            .split(',')
            .map(|v| v.trim().parse::<f32>())
            .collect::<Result<_, _>>()
            .map_err(|e| {
                FaceError::InvalidInput(format!(
                    "camera {text:?}: give fx,fy,cx,cy in pixels ({e})"
                ))
            })?;
        match values[..] {
            [fx, fy, cx, cy] => Self::new(fx, fy, cx, cy),
            _ => Err(FaceError::InvalidInput(format!(
                "camera {text:?}: give four numbers, fx,fy,cx,cy in pixels (got {})",
                values.len()
            ))),
        }
    }

    /// The intrinsics of frames of `frame` size from a calibration made at `calibrated` size:
    /// scaled when the frames are the calibration's images resized (the same aspect within 1 %),
    /// an error when they are cropped or of another camera mode.
    pub fn for_frames(&self, calibrated: (u32, u32), frame: (u32, u32)) -> Result<Self, FaceError> {
        if calibrated == frame {
            return Ok(*self);
        }
        let (sx, sy) = (
            frame.0 as f32 / calibrated.0.max(1) as f32,
            frame.1 as f32 / calibrated.1.max(1) as f32,
        );
        if (sy / sx - 1.0).abs() > 0.01 {
            return Err(FaceError::InvalidInput(format!(
                "the calibration is for {}x{} images and the frames are {}x{}: another shape, so \
                 not the calibrated images resized (calibrate at this size)",
                calibrated.0, calibrated.1, frame.0, frame.1
            )));
        }
        // Pixel centres: x' + ½ = s (x + ½).
        Self::new(
            self.fx * sx,
            self.fy * sy,
            (self.cx + 0.5) * sx - 0.5,
            (self.cy + 0.5) * sy - 0.5,
        )
    }

    /// The focal length the tracker uses: the mean of fx and fy.
    pub fn focal_length(&self) -> f32 {
        (self.fx + self.fy) / 2.0
    }

    /// The pinhole faces are seen through: [`Self::focal_length`], this principal point.
    pub fn lens(&self) -> Lens {
        Lens {
            inverse_focal: 1.0 / self.focal_length(),
            principal: [self.cx, self.cy],
        }
    }

    /// The horizontal field of view of `width`-pixel frames, in degrees.
    pub fn horizontal_fov(&self, width: u32) -> f32 {
        (2.0 * (width as f32 / 2.0 / self.fx).atan()).to_degrees()
    }
}

/// A calibration file's contents.
#[derive(Debug, Clone, PartialEq)]
pub struct Calibration {
    pub intrinsics: Intrinsics,
    /// The images' size it was made at (`image_width`/`image_height` or `image_size`), when the
    /// file says.
    pub image_size: Option<(u32, u32)>,
    /// The distortion coefficients (k1, k2, p1, p2[, k3, ...]); the tracker does not apply them.
    pub distortion: Vec<f64>,
}

/// The names OpenCV's samples and common tools give the camera matrix and the distortion.
const MATRIX_KEYS: [&str; 5] = [
    "camera_matrix",
    "cameraMatrix",
    "K",
    "intrinsic_matrix",
    "M",
];
const DISTORTION_KEYS: [&str; 5] = [
    "distortion_coefficients",
    "dist_coeffs",
    "distCoeffs",
    "D",
    "distortion",
];

impl Calibration {
    /// A calibration as OpenCV's `FileStorage` writes it, YAML or JSON: a 3×3 camera matrix under
    /// one of `camera_matrix`, `cameraMatrix`, `K`, `intrinsic_matrix` or `M` (an
    /// `opencv-matrix` with `rows`, `cols` and `data`, or a plain list of nine numbers or of three
    /// rows), optionally the distortion and the image size.
    pub fn parse(text: &str) -> Result<Self, FaceError> {
        let bad = |message: String| FaceError::InvalidInput(format!("calibration: {message}"));
        // OpenCV writes the YAML 1.0 directive as `%YAML:1.0`, which YAML 1.2 parsers refuse.
        let text = match text.strip_prefix("%YAML:1.0") {
            Some(rest) => rest,
            None => text,
        };
        let docs = YamlLoader::load_from_str(text).map_err(|e| bad(e.to_string()))?;
        let root = docs
            .first()
            .ok_or_else(|| bad("the file is empty".into()))?;
        let (key, matrix) = MATRIX_KEYS
            .iter()
            .find_map(|k| Some((k, &root[*k])).filter(|(_, m)| !m.is_badvalue()))
            .ok_or_else(|| {
                bad(format!(
                    "no camera matrix (one of {})",
                    MATRIX_KEYS.join(", ")
                ))
            })?;
        let m = numbers(matrix).ok_or_else(|| bad(format!("{key} is not a matrix of numbers")))?;
        if m.len() != 9 {
            return Err(bad(format!(
                "{key} has {} values, a camera matrix 9",
                m.len()
            )));
        }
        if m[1] != 0.0 || m[3] != 0.0 || m[6] != 0.0 || m[7] != 0.0 || m[8] != 1.0 {
            return Err(bad(format!(
                "{key} is not a camera matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]: {m:?}"
            )));
        }
        let intrinsics = Intrinsics::new(m[0] as f32, m[4] as f32, m[2] as f32, m[5] as f32)?;
        let distortion = DISTORTION_KEYS
            .iter()
            .map(|k| &root[*k])
            .find(|d| !d.is_badvalue())
            .map(|d| {
                numbers(d).ok_or_else(|| bad("the distortion is not a list of numbers".into()))
            })
            .transpose()?
            .unwrap_or_default();
        if distortion.iter().any(|d| !d.is_finite()) {
            return Err(bad(format!(
                "the distortion has a value that is not finite: {distortion:?}"
            )));
        }
        Ok(Self {
            intrinsics,
            image_size: image_size(root).map_err(bad)?,
            distortion,
        })
    }

    /// [`Self::parse`] of a file.
    pub fn load(path: &Path) -> Result<Self, FaceError> {
        let text = std::fs::read_to_string(path).map_err(|e| file_error(path, e))?;
        Self::parse(&text).map_err(|e| file_error(path, e))
    }

    /// Whether any distortion coefficient is not zero (the tracker would ignore it).
    pub fn distorts(&self) -> bool {
        self.distortion.iter().any(|&d| d != 0.0)
    }
}

/// The numbers of a matrix node: an `opencv-matrix` map's `data` (its `rows × cols` checked), a
/// list of numbers, or a list of rows.
fn numbers(node: &Yaml) -> Option<Vec<f64>> {
    let number = |v: &Yaml| match v {
        Yaml::Real(_) => v.as_f64(),
        Yaml::Integer(i) => Some(*i as f64),
        _ => None,
    };
    match node {
        Yaml::Hash(_) => {
            let data = numbers(&node["data"])?;
            let rows = node["rows"].as_i64()?;
            let cols = node["cols"].as_i64()?;
            (rows.checked_mul(cols)? == data.len() as i64).then_some(data)
        }
        // Numbers, or rows of numbers: no deeper (a nested list goes no further than a row).
        Yaml::Array(items) => items
            .iter()
            .map(|item| match item {
                Yaml::Array(row) => row.iter().map(number).collect(),
                _ => number(item).map(|n| vec![n]),
            })
            .collect::<Option<Vec<_>>>()
            .map(|rows| rows.concat()),
        _ => None,
    }
}

/// `image_width` and `image_height`, or `image_size` / `imageSize` as [width, height]: `None`
/// when the file gives neither; an error when it gives a size that is not two positive whole
/// numbers.
fn image_size(root: &Yaml) -> Result<Option<(u32, u32)>, String> {
    let whole = |v: &Yaml| {
        v.as_i64()
            .filter(|&n| n > 0 && n <= 1 << 20)
            .map(|n| n as u32)
    };
    let (w, h) = (&root["image_width"], &root["image_height"]);
    if !w.is_badvalue() || !h.is_badvalue() {
        return match (whole(w), whole(h)) {
            (Some(w), Some(h)) => Ok(Some((w, h))),
            _ => Err(format!(
                "image_width/image_height must be positive whole numbers, got {w:?}, {h:?}"
            )),
        };
    }
    let size = ["image_size", "imageSize"]
        .iter()
        .map(|k| &root[*k])
        .find(|s| !s.is_badvalue());
    match size {
        None => Ok(None),
        Some(s) => match numbers(s).as_deref() {
            Some(&[w, h])
                if w >= 1.0
                    && h >= 1.0
                    && w.fract() == 0.0
                    && h.fract() == 0.0
                    && w <= 1048576.0
                    && h <= 1048576.0 =>
            {
                Ok(Some((w as u32, h as u32)))
            }
            _ => Err(format!(
                "image_size must be [width, height] in whole pixels, got {s:?}"
            )),
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// As OpenCV's calibration sample writes it.
    const OPENCV_YAML: &str = "%YAML:1.0\n---\nimage_width: 640\nimage_height: 480\n\
        camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 6.5746697944293521e+02, 0., 3.1950000000000000e+02, 0.,\n       6.5746697944293521e+02, 2.3950000000000000e+02, 0., 0., 1. ]\n\
        distortion_coefficients: !!opencv-matrix\n   rows: 5\n   cols: 1\n   dt: d\n   data: [ -4.1802327176423804e-01, 5.0715244063187526e-01, 0., 0.,\n       -5.7843597214487474e-01 ]\n";

    #[test]
    fn reads_opencv_yaml_and_json() {
        let c = Calibration::parse(OPENCV_YAML).unwrap();
        assert!((c.intrinsics.fx - 657.467).abs() < 1e-3);
        assert_eq!((c.intrinsics.cx, c.intrinsics.cy), (319.5, 239.5));
        assert_eq!(c.image_size, Some((640, 480)));
        assert_eq!(c.distortion.len(), 5);
        assert!(c.distorts());
        let json = r#"{"cameraMatrix": {"type_id": "opencv-matrix", "rows": 3, "cols": 3, "dt": "d",
            "data": [500, 0, 320, 0, 502, 240, 0, 0, 1]}, "imageSize": [640, 480]}"#;
        let c = Calibration::parse(json).unwrap();
        assert_eq!(
            c.intrinsics,
            Intrinsics::new(500.0, 502.0, 320.0, 240.0).unwrap()
        );
        assert_eq!(c.image_size, Some((640, 480)));
        assert!(!c.distorts());
        let rows = "K: [[600, 0, 300], [0, 600, 200], [0, 0, 1]]\n";
        assert_eq!(Calibration::parse(rows).unwrap().intrinsics.fx, 600.0);
    }

    #[test]
    fn bad_calibrations_are_clear_errors() {
        for (text, says) in [
            ("", "empty"),
            ("foo: 1\n", "no camera matrix"),
            ("K: [1, 2, 3]\n", "3 values"),
            (
                "K: [500, 1, 320, 0, 500, 240, 0, 0, 1]\n",
                "not a camera matrix",
            ),
            ("K: [500, 0, 320, 0, 800, 240, 0, 0, 1]\n", "square pixels"),
            ("K: [-5, 0, 320, 0, -5, 240, 0, 0, 1]\n", "positive"),
            ("K: [.nan, 0, 320, 0, 500, 240, 0, 0, 1]\n", "finite"),
            (
                "K: {rows: 3, cols: 2, data: [500, 0, 320, 0, 500, 240, 0, 0, 1]}\n",
                "not a matrix",
            ),
            (
                "K: [500, 0, 320, 0, 500, 240, 0, 0, 1]\nimage_width: 0\nimage_height: 4\n",
                "image_width",
            ),
            (
                "K: [500, 0, 320, 0, 500, 240, 0, 0, 1]\nD: [a, b]\n",
                "distortion",
            ),
            ("K: [500, 0, 320, 0, 500, 240, 0, 0, 1\n", "calibration"),
        ] {
            let err = Calibration::parse(text).unwrap_err().to_string();
            assert!(err.contains(says), "{text:?}: {err}");
        }
    }

    #[test]
    fn command_line_intrinsics_and_resized_frames() {
        let c = Intrinsics::parse("600, 600, 319.5, 239.5").unwrap();
        assert_eq!(c.lens().principal, [319.5, 239.5]);
        assert!((1.0 / c.lens().inverse_focal - 600.0).abs() < 1e-3);
        assert!((c.horizontal_fov(640) - 56.14).abs() < 0.01);
        for bad in [
            "600,600,320",
            "a,b,c,d",
            "600,600,320,240,1",
            "0,600,320,240",
            "600,600,inf,240",
        ] {
            assert!(Intrinsics::parse(bad).is_err(), "{bad}");
        }
        // Half the size: the focal lengths halve, the centre stays the centre.
        let half = c.for_frames((640, 480), (320, 240)).unwrap();
        assert_eq!((half.fx, half.cx, half.cy), (300.0, 159.5, 119.5));
        assert_eq!(c.for_frames((640, 480), (640, 480)).unwrap(), c);
        assert!(c.for_frames((640, 480), (640, 360)).is_err());
    }
}
