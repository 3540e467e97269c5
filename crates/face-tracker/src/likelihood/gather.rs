//! The lanes' pixel reads with AVX2: the cells in vector registers and two 32-bit gathers for
//! all eight lanes' four corners, where the scalar reads take sixteen loads and as many inserts
//! (most of the CPU likelihood's time once its arithmetic is vectorised). The values are the
//! scalar path's: the same truncation, clamp and conversions, lane by lane.

use std::arch::x86_64::{
    _mm256_add_epi32, _mm256_and_si256, _mm256_cvtepi32_ps, _mm256_cvttps_epi32,
    _mm256_i32gather_epi32, _mm256_loadu_ps, _mm256_min_epi32, _mm256_mullo_epi32,
    _mm256_set1_epi32, _mm256_srli_epi32, _mm256_storeu_ps, _mm256_sub_ps,
};

use super::{LANES, LaneSamples, Pixels};

/// Whether [`sample_lanes`] may read `levels` as a `width × height` frame: they are that many,
/// at least 2×2 (so that every 4-byte word it reads lies inside, see there), and few enough for
/// i32 offsets. (A `GrayImage`'s fields are public: nothing else guarantees this.)
pub(super) fn can_gather(levels: &[u8], width: u32, height: u32) -> bool {
    width >= 2
        && height >= 2
        && (width as usize).checked_mul(height as usize) == Some(levels.len())
        && levels.len() <= i32::MAX as usize
}

/// [`super::sample_lanes`] with AVX2.
///
/// # Safety
/// The CPU must have AVX2; [`can_gather`] must hold for the frame of `pixels`; and every
/// (u, v) must be [`Pixels::inside`] it (or (0, 0)). Then each cell's top-left pixel `at` is
/// at most (height − 2)·width + width − 2, and both words read per lane lie inside the levels:
/// the top row's at `at` (bytes at..at + 3), the bottom row's at `at + width − 2` (bytes up to
/// at + width + 1 = (height − 1)·width + width − 1 at most), its corners in the upper half.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn sample_lanes(
    pixels: &Pixels,
    u: &[f32; LANES],
    v: &[f32; LANES],
) -> LaneSamples {
    // SAFETY: loads eight f32s from arrays of eight.
    let (x, y) = unsafe { (_mm256_loadu_ps(u.as_ptr()), _mm256_loadu_ps(v.as_ptr())) };
    // Truncation, as `as i32`: the points are inside the frame, within i32 (`can_gather`).
    let x0 = _mm256_min_epi32(
        _mm256_cvttps_epi32(x),
        _mm256_set1_epi32(pixels.x_cell_max as i32),
    );
    let y0 = _mm256_min_epi32(
        _mm256_cvttps_epi32(y),
        _mm256_set1_epi32(pixels.y_cell_max as i32),
    );
    let mut samples = LaneSamples {
        fx: [0.0; LANES],
        fy: [0.0; LANES],
        corners: [[0.0; LANES]; 4],
    };
    let width = pixels.width as i32;
    let top = _mm256_add_epi32(_mm256_mullo_epi32(y0, _mm256_set1_epi32(width)), x0);
    let bottom = _mm256_add_epi32(top, _mm256_set1_epi32(width - 2));
    let base = pixels.levels.as_ptr() as *const i32;
    // SAFETY: every offset is in bounds by the contract above.
    let (top, bottom) = unsafe {
        (
            _mm256_i32gather_epi32::<1>(base, top),
            _mm256_i32gather_epi32::<1>(base, bottom),
        )
    };
    let byte = _mm256_set1_epi32(0xff);
    let words = [
        _mm256_and_si256(top, byte),
        _mm256_and_si256(_mm256_srli_epi32::<8>(top), byte),
        _mm256_and_si256(_mm256_srli_epi32::<16>(bottom), byte),
        _mm256_srli_epi32::<24>(bottom),
    ];
    // SAFETY: each store writes eight f32s into an array of eight.
    unsafe {
        _mm256_storeu_ps(
            samples.fx.as_mut_ptr(),
            _mm256_sub_ps(x, _mm256_cvtepi32_ps(x0)),
        );
        _mm256_storeu_ps(
            samples.fy.as_mut_ptr(),
            _mm256_sub_ps(y, _mm256_cvtepi32_ps(y0)),
        );
        for (corner, word) in samples.corners.iter_mut().zip(words) {
            _mm256_storeu_ps(corner.as_mut_ptr(), _mm256_cvtepi32_ps(word));
        }
    }
    samples
}
