//! The lanes' pixel reads with AVX2's gather: two 32-bit gathers fetch all eight lanes' four
//! corners, where the scalar reads take sixteen loads and as many inserts into vector
//! registers (most of the CPU likelihood's time once the arithmetic is vectorised).

use std::arch::x86_64::{
    __m256i, _mm256_and_si256, _mm256_cvtepi32_ps, _mm256_i32gather_epi32, _mm256_loadu_si256,
    _mm256_set1_epi32, _mm256_srli_epi32, _mm256_storeu_ps,
};

use super::LANES;

/// Whether [`gather_corners`] may read `levels` as a `width × height` frame: they are that
/// many, at least 2×2 (so that every 4-byte word it reads lies inside, see there), and few
/// enough for i32 offsets. (A `GrayImage`'s fields are public: nothing else guarantees this.)
pub(super) fn can_gather(levels: &[u8], width: u32, height: u32) -> bool {
    width >= 2
        && height >= 2
        && (width as usize).checked_mul(height as usize) == Some(levels.len())
        && levels.len() <= i32::MAX as usize
}

/// The four corners (top left, top right, bottom left, bottom right) of each lane's cell, the
/// cell's top-left pixel at `at[l]` (≤ (height − 2)·width + width − 2, as `Pixels::cell`
/// clamps it), as f32 levels: the same values as the scalar reads.
///
/// # Safety
/// The CPU must have AVX2; [`can_gather`] must hold for `levels`, `width` and the height; and
/// every `at[l] + width + 1` must be below `levels.len()` (true of any cell inside the frame). Then both words read per lane lie inside
/// `levels`: the top row's at `at` (bytes at..at+3, and at + 3 ≤ at + width + 1), the bottom
/// row's at `at + width − 2` (bytes up to at + width + 1), its corners in the word's upper half.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn gather_corners(
    levels: &[u8],
    width: usize,
    at: &[usize; LANES],
) -> [[f32; LANES]; 4] {
    let top_offsets: [i32; LANES] = at.map(|a| a as i32);
    let bottom_offsets: [i32; LANES] = at.map(|a| (a + width - 2) as i32);
    let base = levels.as_ptr() as *const i32;
    // SAFETY: the offsets are in bounds by the caller's contract (above); the loads read the
    // two local arrays of eight i32s.
    let (top, bottom) = unsafe {
        (
            _mm256_i32gather_epi32::<1>(
                base,
                _mm256_loadu_si256(top_offsets.as_ptr() as *const __m256i),
            ),
            _mm256_i32gather_epi32::<1>(
                base,
                _mm256_loadu_si256(bottom_offsets.as_ptr() as *const __m256i),
            ),
        )
    };
    let byte = _mm256_set1_epi32(0xff);
    let words = [
        _mm256_and_si256(top, byte),
        _mm256_and_si256(_mm256_srli_epi32::<8>(top), byte),
        _mm256_and_si256(_mm256_srli_epi32::<16>(bottom), byte),
        _mm256_srli_epi32::<24>(bottom),
    ];
    let mut corners = [[0.0f32; LANES]; 4];
    for (corner, word) in corners.iter_mut().zip(words) {
        // SAFETY: stores eight f32s into an array of eight.
        unsafe { _mm256_storeu_ps(corner.as_mut_ptr(), _mm256_cvtepi32_ps(word)) };
    }
    corners
}
