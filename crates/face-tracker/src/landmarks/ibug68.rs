//! In the 68-point (iBUG 300-W) scheme: the outer corners of the eyes, whose distance normalises
//! landmark errors, and the jaw, brow, nose and mouth ranges.

pub const COUNT: usize = 68;
pub const RIGHT_EYE_OUTER: usize = 36;
pub const LEFT_EYE_OUTER: usize = 45;
/// Each eye's outline: outer corner, upper lid, inner corner, lower lid.
pub const RIGHT_EYE: std::ops::Range<usize> = 36..42;
pub const LEFT_EYE: std::ops::Range<usize> = 42..48;
pub const JAW: std::ops::Range<usize> = 0..17;
pub const BROWS: std::ops::Range<usize> = 17..27;
pub const NOSE_TIP: usize = 30;
