//! Where a head's surface samples land in a frame: the splats of eight samples at a time
//! (projection, depth, shading), shared by the banded one-frame pass and the frame-per-core
//! batch pass, so that both draw the same pixels.

use rayon::prelude::*;

use super::{FaceSynthConfig, HEIGHT_RATIO};
use crate::lens::Lens;
use crate::projection::{DIMS, Pose};

/// Rows per band of the renderer's parallel depth test.
pub(super) const BAND_ROWS: usize = 16;

/// Samples splatted together by [`Splatter::splat_lanes`]: the loop over them has no branches,
/// so that the compiler keeps them in vector registers.
pub(super) const SPLAT_LANES: usize = 8;

/// One surface sample of a head's model on the (u, v) grid: what does not depend on the pose.
#[derive(Debug, Clone, Copy)]
pub(super) struct SurfaceSample {
    pub u: f32,
    pub v: f32,
    pub height: f32,
    pub normal: [f32; 3],
    pub albedo: f32,
}

/// A head's surface samples for one grid density (`steps` per unit of u and v), in row order,
/// one array per quantity, padded to whole groups of [`SPLAT_LANES`] (the padding never lands).
#[derive(Debug, Clone)]
pub(super) struct HeadSurface {
    pub steps: i32,
    len: usize,
    u: Vec<f32>,
    v: Vec<f32>,
    height: Vec<f32>,
    normal: [Vec<f32>; 3],
    albedo: Vec<f32>,
}

impl HeadSurface {
    pub(super) fn new(steps: i32, samples: &[SurfaceSample]) -> Self {
        let padded = samples.len().next_multiple_of(SPLAT_LANES);
        let column = |f: fn(&SurfaceSample) -> f32| {
            let mut values: Vec<f32> = samples.iter().map(f).collect();
            values.resize(padded, 0.0);
            values
        };
        Self {
            steps,
            len: samples.len(),
            u: column(|s| s.u),
            v: column(|s| s.v),
            height: column(|s| s.height),
            normal: [
                column(|s| s.normal[0]),
                column(|s| s.normal[1]),
                column(|s| s.normal[2]),
            ],
            albedo: column(|s| s.albedo),
        }
    }

    /// Samples, padding included: a multiple of [`SPLAT_LANES`].
    pub(super) fn len(&self) -> usize {
        self.u.len()
    }
}

/// Where [`SPLAT_LANES`] samples land: the pixel index, the depth towards the camera and the
/// shaded albedo of each, and whether it lands at all (faces the camera, inside the frame, not
/// padding).
struct LaneSplats {
    pixel: [u32; SPLAT_LANES],
    depth: [f32; SPLAT_LANES],
    value: [f32; SPLAT_LANES],
    valid: [bool; SPLAT_LANES],
}

/// Where a head's surface samples land in a frame, for one pose.
pub(super) struct Splatter {
    /// R row by row.
    rotation: [f32; 9],
    scale: f32,
    translation: [f32; 2],
    light: [f32; 3],
    half_width: f32,
    half_height: f32,
    width: u32,
    height: u32,
    /// The camera (weak perspective unless the video has a focal length).
    lens: Lens,
}

/// `samples[first..first + SPLAT_LANES]`, which the padding keeps in bounds.
fn lanes(samples: &[f32], first: usize) -> &[f32; SPLAT_LANES] {
    samples[first..first + SPLAT_LANES]
        .try_into()
        .expect("a slice of SPLAT_LANES")
}

impl Splatter {
    pub(super) fn new(config: &FaceSynthConfig, state: &[f32; DIMS]) -> Self {
        let pose = Pose::new(state);
        let r = &pose.rotation;
        let light = nalgebra::Vector3::new(0.3f32, -0.4, 1.0).normalize();
        Self {
            rotation: std::array::from_fn(|k| r[(k / 3, k % 3)]),
            scale: pose.scale,
            translation: [pose.translation.x, pose.translation.y],
            light: [light.x, light.y, light.z],
            half_width: config.half_width,
            half_height: config.half_width * HEIGHT_RATIO,
            width: config.width,
            height: config.height,
            lens: config.lens(),
        }
    }

    /// Calls `land(pixel, depth, value)` for every sample of `samples` (a range of `surface`
    /// that starts at a multiple of [`SPLAT_LANES`]) that lands, in sample order: with AVX2's
    /// 8-wide registers where the CPU has them (the same values: the instructions differ, the
    /// arithmetic does not).
    pub(super) fn splat(
        &self,
        surface: &HeadSurface,
        samples: std::ops::Range<usize>,
        mut land: impl FnMut(usize, f32, f32),
    ) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2, detected just above.
            unsafe { self.splat_avx2(surface, samples, &mut land) };
            return;
        }
        self.splat_all(surface, samples, &mut land);
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn splat_avx2(
        &self,
        surface: &HeadSurface,
        samples: std::ops::Range<usize>,
        land: &mut impl FnMut(usize, f32, f32),
    ) {
        self.splat_all(surface, samples, land);
    }

    /// [`Splatter::splat`] for the target it is inlined into.
    #[inline(always)]
    fn splat_all(
        &self,
        surface: &HeadSurface,
        samples: std::ops::Range<usize>,
        land: &mut impl FnMut(usize, f32, f32),
    ) {
        let pinhole = !self.lens.is_weak();
        for first in samples.step_by(SPLAT_LANES) {
            let splats = if pinhole {
                self.splat_lanes::<true>(surface, first)
            } else {
                self.splat_lanes::<false>(surface, first)
            };
            for l in 0..SPLAT_LANES {
                if splats.valid[l] {
                    land(splats.pixel[l] as usize, splats.depth[l], splats.value[l]);
                }
            }
        }
    }

    /// The splats of samples `first..first + SPLAT_LANES` of `surface` (`first` a multiple of
    /// [`SPLAT_LANES`]). A sample lands on its nearest pixel when its rotated normal faces the
    /// camera; Lambert shading under a fixed light. Through a pinhole when `PINHOLE` (the
    /// arithmetic of [`Lens::apply`], without branches), else weak perspective.
    #[inline(always)]
    fn splat_lanes<const PINHOLE: bool>(&self, surface: &HeadSurface, first: usize) -> LaneSplats {
        let r = &self.rotation;
        let (u, v, h) = (
            lanes(&surface.u, first),
            lanes(&surface.v, first),
            lanes(&surface.height, first),
        );
        let (nx, ny, nz) = (
            lanes(&surface.normal[0], first),
            lanes(&surface.normal[1], first),
            lanes(&surface.normal[2], first),
        );
        let albedo = lanes(&surface.albedo, first);
        let mut out = LaneSplats {
            pixel: [0; SPLAT_LANES],
            depth: [0.0; SPLAT_LANES],
            value: [0.0; SPLAT_LANES],
            valid: [false; SPLAT_LANES],
        };
        let (width, height) = (self.width as i32, self.height as i32);
        for l in 0..SPLAT_LANES {
            let normal = [
                r[0] * nx[l] + r[1] * ny[l] + r[2] * nz[l],
                r[3] * nx[l] + r[4] * ny[l] + r[5] * nz[l],
                r[6] * nx[l] + r[7] * ny[l] + r[8] * nz[l],
            ];
            let p = [
                u[l] * self.half_width,
                v[l] * self.half_height,
                h[l] * self.half_width,
            ];
            let rotated = [
                r[0] * p[0] + r[1] * p[1] + r[2] * p[2],
                r[3] * p[0] + r[4] * p[1] + r[5] * p[2],
                r[6] * p[0] + r[7] * p[1] + r[8] * p[2],
            ];
            // The nearest pixel: x + 0.5 truncated is its floor wherever it is ≥ 0, the only
            // place a pixel lands (NaN fails the comparisons; `as` saturates far outside).
            let mut x = rotated[0] * self.scale + self.translation[0];
            let mut y = rotated[1] * self.scale + self.translation[1];
            let mut near = true;
            if PINHOLE {
                let distance = 1.0 - rotated[2] * self.scale * self.lens.inverse_focal;
                near = distance > Lens::MIN_DISTANCE_SHARE;
                let [px, py] = self.lens.principal;
                x = px + (x - px) / distance;
                y = py + (y - py) / distance;
            }
            let (x, y) = (x + 0.5, y + 0.5);
            let (column, row) = (x as i32, y as i32);
            // `&`, not `&&`: no branches, so that the lanes vectorise.
            out.valid[l] = near
                & (normal[2] >= 0.0)
                & (x >= 0.0)
                & (y >= 0.0)
                & (column < width)
                & (row < height)
                & (first + l < surface.len);
            out.pixel[l] = (row.clamp(0, height - 1) * width + column.clamp(0, width - 1)) as u32;
            out.depth[l] = rotated[2];
            let lit =
                normal[0] * self.light[0] + normal[1] * self.light[1] + normal[2] * self.light[2];
            out.value[l] = albedo[l] * (0.55 + 0.45 * lit.max(0.0));
        }
        out
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
    const CHUNK: usize = 4096;
    const _: () = assert!(CHUNK.is_multiple_of(SPLAT_LANES));
    let splatter = Splatter::new(config, state);
    let bands = (config.height as usize).div_ceil(BAND_ROWS);
    let row_len = config.width as usize;
    (0..surface.len())
        .step_by(CHUNK)
        .collect::<Vec<_>>()
        .into_par_iter()
        .map(|start| {
            let mut by_band = vec![Vec::new(); bands];
            let end = (start + CHUNK).min(surface.len());
            splatter.splat(surface, start..end, |pixel, depth, value| {
                by_band[pixel / row_len / BAND_ROWS].push((pixel, depth, value));
            });
            by_band
        })
        .collect()
}
