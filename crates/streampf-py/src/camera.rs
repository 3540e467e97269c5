//! The camera faces are seen through in Python: `fov=` (a horizontal field of view) or
//! `camera=` ((fx, fy, cx, cy), or an OpenCV calibration file), as `face track --fov`,
//! `--camera` and `--calibration`.

use face_tracker::FaceTrackerConfig;
use face_tracker::camera::{Calibration, Intrinsics};
use pyo3::prelude::*;

use crate::errors::value_error;

/// `config` seeing faces through `fov` or `camera` in frames of `size` (weak perspective without
/// either).
pub(crate) fn with_lens(
    config: FaceTrackerConfig,
    fov: Option<f32>,
    camera: Option<&Bound<'_, PyAny>>,
    size: (u32, u32),
) -> PyResult<FaceTrackerConfig> {
    let config = FaceTrackerConfig {
        focal_length: focal_length(fov, size.0)?,
        ..config
    };
    Ok(match camera_of(camera, fov, size)? {
        Some(camera) => config.with_camera(&camera),
        None => config,
    })
}

/// The focal length in pixels of a camera `fov` degrees across a `width`-pixel frame (`fov`
/// within 1 to 170, as `face track --fov`); `None` (weak perspective) without one.
pub(crate) fn focal_length(fov: Option<f32>, width: u32) -> PyResult<Option<f32>> {
    let Some(fov) = fov else { return Ok(None) };
    let focal = face_tracker::likelihood::Lens::focal_length_for(fov, width)
        .map_err(|e| value_error(format!("fov, the camera's horizontal field of view: {e}")))?;
    Ok(Some(focal))
}

/// `camera=`: (fx, fy, cx, cy) in pixels, or the path of an OpenCV calibration file (YAML or
/// JSON; scaled to frames of `size` when it was made at another size of the same shape), as
/// `face track --camera` and `--calibration` take them; not with `fov`.
fn camera_of(
    camera: Option<&Bound<'_, PyAny>>,
    fov: Option<f32>,
    size: (u32, u32),
) -> PyResult<Option<Intrinsics>> {
    let Some(camera) = camera.filter(|c| !c.is_none()) else {
        return Ok(None);
    };
    if fov.is_some() {
        return Err(value_error(
            "give camera= or fov=, not both: a calibrated camera has its own field of view",
        ));
    }
    let bad = |e: face_tracker::FaceError| value_error(format!("camera: {e}"));
    if let Ok(path) = camera.extract::<std::path::PathBuf>() {
        let calibration = Calibration::load(&path).map_err(bad)?;
        return match calibration.image_size {
            Some(calibrated) => calibration
                .intrinsics
                .for_frames(calibrated, size)
                .map(Some)
                .map_err(bad),
            None => Ok(Some(calibration.intrinsics)),
        };
    }
    let (fx, fy, cx, cy): (f32, f32, f32, f32) = camera.extract().map_err(|_| {
        value_error(
            "camera must be (fx, fy, cx, cy) in pixels or the path of an OpenCV calibration file",
        )
    })?;
    Intrinsics::new(fx, fy, cx, cy).map(Some).map_err(bad)
}
