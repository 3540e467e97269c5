//! Where a head's surface samples land in a frame: the splat of one sample (projection, depth,
//! shading) shared by the banded one-frame pass and the frame-per-core batch pass.

use nalgebra::{Vector2, Vector3};
use rayon::prelude::*;

use super::{FaceSynthConfig, HEIGHT_RATIO, HeadSurface, SurfaceSample};
use crate::projection::{DIMS, Pose};

/// Rows per band of the renderer's parallel depth test.
pub(super) const BAND_ROWS: usize = 16;

/// Where a head's surface samples land in a frame, for one pose.
pub(super) struct Splatter {
    pose: Pose,
    light: Vector3<f32>,
    half_width: f32,
    half_height: f32,
    width: u32,
    height: u32,
}

impl Splatter {
    pub(super) fn new(config: &FaceSynthConfig, state: &[f32; DIMS]) -> Self {
        Self {
            pose: Pose::new(state),
            light: Vector3::new(0.3, -0.4, 1.0).normalize(),
            half_width: config.half_width,
            half_height: config.half_width * HEIGHT_RATIO,
            width: config.width,
            height: config.height,
        }
    }

    /// (pixel index, depth towards the camera, shaded albedo) of a sample that faces the camera
    /// and lands in the frame.
    pub(super) fn splat(&self, s: &SurfaceSample) -> Option<(usize, f32, f32)> {
        // Half the samples face away: their rotated normal's z alone (the last row of the
        // product below, in the same order) decides that.
        let r = &self.pose.rotation;
        if r[(2, 0)] * s.normal[0] + r[(2, 1)] * s.normal[1] + r[(2, 2)] * s.normal[2] < 0.0 {
            return None;
        }
        let n = self.pose.rotation * Vector3::from(s.normal);
        let p = Vector3::new(
            s.u * self.half_width,
            s.v * self.half_height,
            s.height * self.half_width,
        );
        // Pose::project's arithmetic, keeping the rotated point for its depth.
        let rotated = self.pose.rotation * p;
        let image_point =
            Vector2::new(rotated.x, rotated.y) * self.pose.scale + self.pose.translation;
        let (px, py) = (
            round_half_away(image_point.x),
            round_half_away(image_point.y),
        );
        if px < 0.0 || py < 0.0 || px >= self.width as f32 || py >= self.height as f32 {
            return None;
        }
        let shade = 0.55 + 0.45 * n.dot(&self.light).max(0.0);
        Some((
            (py as u32 * self.width + px as u32) as usize,
            rotated.z,
            s.albedo * shade,
        ))
    }
}

/// `x.round()` (halves away from zero) without the libm call it compiles to on a baseline
/// x86-64 target, which took a tenth of the renderer's time. Exact: below 2²³ in magnitude the
/// truncation and the fraction are exact; from there on every f32 is an integer. (A negative
/// value that rounds to zero gives +0 where `round` gives −0: the same pixel.)
pub(crate) fn round_half_away(x: f32) -> f32 {
    // From 2²³ on (and NaN) there is nothing to round.
    if x.is_nan() || x.abs() >= 8_388_608.0 {
        return x;
    }
    let truncated = x as i32 as f32;
    let fraction = x - truncated;
    if fraction >= 0.5 {
        truncated + 1.0
    } else if fraction <= -0.5 {
        truncated - 1.0
    } else {
        truncated
    }
}

/// Every surface sample of a head in pose `state` that faces the camera and lands in the frame:
/// (pixel index, depth towards the camera, shaded albedo), per chunk of samples (in order) and
/// within it per band of [`BAND_ROWS`] rows.
pub(super) fn splat_head(
    config: &FaceSynthConfig,
    surface: &HeadSurface,
    state: &[f32; DIMS],
) -> Vec<Vec<Vec<(usize, f32, f32)>>> {
    let splatter = Splatter::new(config, state);
    let bands = (config.height as usize).div_ceil(BAND_ROWS);
    let row_len = config.width as usize;
    surface
        .samples
        .par_chunks(4096)
        .map(|chunk| {
            let mut by_band = vec![Vec::new(); bands];
            for splat in chunk.iter().filter_map(|s| splatter.splat(s)) {
                by_band[splat.0 / row_len / BAND_ROWS].push(splat);
            }
            by_band
        })
        .collect()
}

#[cfg(test)]
mod rounding_tests {
    use super::round_half_away;
    use proptest::prelude::*;

    #[test]
    fn rounds_as_round_at_the_edges() {
        let edges = [
            0.0f32,
            -0.0,
            0.5,
            -0.5,
            1.5,
            -1.5,
            2.5,
            0.499_999_97,
            -0.499_999_97,
            1023.5,
            767.49994,
            8_388_607.5,
            -8_388_607.5,
            8_388_608.0,
            16_777_217.0,
            3.4e38,
            -3.4e38,
            f32::MIN_POSITIVE,
            f32::INFINITY,
            f32::NEG_INFINITY,
        ];
        for x in edges {
            assert_eq!(round_half_away(x), x.round(), "{x}");
        }
        assert!(round_half_away(f32::NAN).is_nan());
    }

    proptest! {
        #[test]
        fn rounds_as_round(x in prop::num::f32::NORMAL | prop::num::f32::SUBNORMAL | prop::num::f32::ZERO, pixel in -100.0f32..2100.0) {
            prop_assert_eq!(round_half_away(x), x.round());
            prop_assert_eq!(round_half_away(pixel), pixel.round());
        }
    }
}
