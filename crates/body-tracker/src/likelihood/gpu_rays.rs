//! The fast capsule kernel's host preparation of a frame's rays: the rays put in Morton order of
//! direction, so that a workgroup's tile of rays is compact, and each tile's cone of directions,
//! which the kernel tests every capsule's bounding sphere against. It needs no GPU, so a reader
//! thread can prepare frame t + 1 while the GPU steps frame t.

use rayon::prelude::*;

use super::FAST_TILE;

/// Spreads the low 16 bits of `v` to the even bits of a u32 (8 bits give a 16-bit Morton code).
fn spread_bits(v: u32) -> u32 {
    let mut x = v & 0xffff;
    x = (x | (x << 8)) & 0x00ff_00ff;
    x = (x | (x << 4)) & 0x0f0f_0f0f;
    x = (x | (x << 2)) & 0x3333_3333;
    (x | (x << 1)) & 0x5555_5555
}

/// A frame's rays as the fast kernel reads them: one or more *levels* (level 0 every ray,
/// later levels subsets that coarse annealing layers weigh), each in Morton order of direction
/// and padded with end markers to whole tiles, one after another, with the cone of each tile.
#[derive(Debug, Clone, PartialEq)]
pub struct PreparedRays {
    /// The levels' rays in Morton order, each level's end markers (depth < 0) last.
    pub(super) ordered: Vec<[f32; 4]>,
    /// Per tile of `FAST_TILE` rays, the levels' tiles one after another: (unit axis,
    /// half-angle) of a cone holding them.
    pub(super) tile_cones: Vec<[f32; 4]>,
    /// Per level: its tiles, and its rays that are not end markers.
    pub(super) levels: Vec<RayLevel>,
}

/// One level of [`PreparedRays`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RayLevel {
    /// Tiles of `FAST_TILE` rays.
    pub tiles: usize,
    /// Rays that are real points (not end markers).
    pub points: usize,
}

impl PreparedRays {
    /// The number of rays, end markers included (every level's, padded to whole tiles).
    pub fn len(&self) -> usize {
        self.ordered.len()
    }

    /// Whether there are no rays.
    pub fn is_empty(&self) -> bool {
        self.ordered.is_empty()
    }

    /// The rays in the order the kernel reads them.
    pub fn ordered(&self) -> &[[f32; 4]] {
        &self.ordered
    }

    /// The levels, level 0 first.
    pub fn levels(&self) -> &[RayLevel] {
        &self.levels
    }

    /// Per tile, the cone holding its rays: (unit axis, half-angle).
    pub fn tile_cones(&self) -> &[[f32; 4]] {
        &self.tile_cones
    }
}

/// The fast kernel's host preparation of a frame's rays, one level: the rays in Morton order
/// of direction, padded with end markers to whole tiles, and the cone of each tile (on all
/// cores).
pub fn prepare_rays(rays: &[[f32; 4]]) -> PreparedRays {
    prepare_ray_levels(&[rays])
}

/// [`prepare_rays`] for several levels of one frame (level 0 every ray, then the subsets that
/// coarse layers weigh), one after another in one layout.
pub fn prepare_ray_levels(levels: &[&[[f32; 4]]]) -> PreparedRays {
    let mut prepared = PreparedRays {
        ordered: Vec::new(),
        tile_cones: Vec::new(),
        levels: Vec::with_capacity(levels.len()),
    };
    for rays in levels {
        let mut ordered = morton_ordered(rays);
        let tiles = ordered.len().div_ceil(FAST_TILE);
        ordered.resize(tiles * FAST_TILE, END_MARKER);
        prepared
            .tile_cones
            .par_extend(ordered.par_chunks(FAST_TILE).map(cone));
        prepared.ordered.extend_from_slice(&ordered);
        prepared.levels.push(RayLevel {
            tiles,
            points: rays.iter().filter(|r| !is_marker(r)).count(),
        });
    }
    prepared
}

/// Padding past a level's last point (depth −1): it adds nothing to any sum.
pub const END_MARKER: [f32; 4] = [0.0, 0.0, 1.0, -1.0];

/// An end marker: padding past a frame's last point, which adds nothing to any sum.
fn is_marker(ray: &[f32; 4]) -> bool {
    ray[3] < 0.0
}

/// The rays put in Morton (Z-curve) order of their direction, on a 256 × 256 grid over the
/// directions' own range, by a counting sort (no comparison sort, and the order within a cell
/// is the input's, so the result is deterministic). When every ray looks forward (z > 0, as
/// from a depth camera) a direction's coordinates are (x/z, y/z), its point on the image plane,
/// so that a depth image's pixels keep their neighbours; otherwise (azimuth, elevation). End
/// markers go last, so that no cone has to hold their made-up direction.
fn morton_ordered(rays: &[[f32; 4]]) -> Vec<[f32; 4]> {
    const CELLS_PER_AXIS: f32 = 255.0;
    /// The counting sort's key for end markers: after every Morton cell.
    const MARKER_KEY: usize = 1 << 16;
    let forward = rays.par_iter().all(|r| is_marker(r) || r[2] > 1e-3);
    let coordinates: Vec<(f32, f32)> = rays
        .par_iter()
        .with_min_len(RAYS_PER_TASK)
        .map(|r| {
            if forward {
                (r[0] / r[2], r[1] / r[2])
            } else {
                (r[0].atan2(r[2]), r[1].clamp(-1.0, 1.0).asin())
            }
        })
        .collect();
    let (lo, hi) = rays
        .iter()
        .zip(&coordinates)
        .filter(|(r, _)| !is_marker(r))
        .fold(
            (
                (f32::INFINITY, f32::INFINITY),
                (f32::NEG_INFINITY, f32::NEG_INFINITY),
            ),
            |(lo, hi), (_, &(a, e))| ((lo.0.min(a), lo.1.min(e)), (hi.0.max(a), hi.1.max(e))),
        );
    let quantise = |x: f32, lo: f32, hi: f32| {
        if hi > lo {
            (((x - lo) / (hi - lo)) * CELLS_PER_AXIS) as u32
        } else {
            0
        }
    };
    let keys: Vec<u32> = rays
        .par_iter()
        .zip(&coordinates)
        .with_min_len(RAYS_PER_TASK)
        .map(|(r, &(a, e))| {
            if is_marker(r) {
                MARKER_KEY as u32
            } else {
                spread_bits(quantise(a, lo.0, hi.0)) | (spread_bits(quantise(e, lo.1, hi.1)) << 1)
            }
        })
        .collect();
    // Counting sort by key: each key's first place, then every ray into its key's next.
    let mut next = vec![0usize; MARKER_KEY + 1];
    for &k in &keys {
        next[k as usize] += 1;
    }
    let mut place = 0;
    for n in &mut next {
        (*n, place) = (place, place + *n);
    }
    let mut ordered = vec![[0.0f32; 4]; rays.len()];
    for (ray, &k) in rays.iter().zip(&keys) {
        ordered[next[k as usize]] = *ray;
        next[k as usize] += 1;
    }
    ordered
}

/// Rays per rayon task in the host's ray preparation.
const RAYS_PER_TASK: usize = 4096;

/// The cone of a tile without rays (only end markers): it holds nothing.
const EMPTY_CONE: [f32; 4] = [0.0, 0.0, 1.0, 0.0];

/// The unit axis of a cone holding every ray's direction (their normalised mean) and its
/// half-angle, widened a little for rounding; end markers are left out. One `acos` (of the
/// smallest cosine: acos falls as the cosine grows).
fn cone(rays: &[[f32; 4]]) -> [f32; 4] {
    let mut axis = [0.0f64; 3];
    let mut any = false;
    for r in rays.iter().filter(|r| !is_marker(r)) {
        any = true;
        for (a, &x) in axis.iter_mut().zip(r) {
            *a += f64::from(x);
        }
    }
    if !any {
        return EMPTY_CONE;
    }
    let norm = (axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]).sqrt();
    if norm <= 1e-9 || norm.is_nan() {
        // Rays in every direction: a cone that holds everything.
        return [0.0, 0.0, 1.0, std::f32::consts::PI];
    }
    let axis = axis.map(|a| a / norm);
    let smallest_cos = rays
        .iter()
        .filter(|r| !is_marker(r))
        .map(|r| {
            let cos =
                axis[0] * f64::from(r[0]) + axis[1] * f64::from(r[1]) + axis[2] * f64::from(r[2]);
            cos.clamp(-1.0, 1.0)
        })
        .fold(1.0f64, f64::min);
    [
        axis[0] as f32,
        axis[1] as f32,
        axis[2] as f32,
        (smallest_cos.acos() + 1e-4) as f32,
    ]
}

#[cfg(test)]
mod tests {

    use super::*;

    #[test]
    fn morton_order_is_a_permutation() {
        let rays: Vec<[f32; 4]> = (0..500)
            .map(|i| {
                let (x, y) = ((i % 23) as f32 / 23.0 - 0.5, (i % 17) as f32 / 17.0 - 0.5);
                let n = (x * x + y * y + 1.0).sqrt();
                [x / n, y / n, 1.0 / n, i as f32]
            })
            .collect();
        let mut ordered: Vec<u32> = morton_ordered(&rays).iter().map(|r| r[3] as u32).collect();
        assert_ne!(ordered, (0..500).collect::<Vec<_>>(), "the order changed");
        ordered.sort_unstable();
        assert_eq!(ordered, (0..500).collect::<Vec<_>>());
        assert_eq!(spread_bits(0b1011), 0b1000101);
    }

    #[test]
    fn end_markers_go_last_and_widen_no_cone() {
        // Two tiles' worth: real rays in a narrow patch off the axis, markers mixed in (their
        // made-up direction, straight ahead, lies outside the patch).
        let rays: Vec<[f32; 4]> = (0..2 * FAST_TILE)
            .map(|i| {
                if i % 3 == 0 {
                    [0.0, 0.0, 1.0, -1.0]
                } else {
                    let x = 0.3 + (i % 31) as f32 * 1e-3;
                    let n = (x * x + 1.0).sqrt();
                    [x / n, 0.0, 1.0 / n, 2.0]
                }
            })
            .collect();
        let markers = rays.iter().filter(|r| is_marker(r)).count();
        let prepared = prepare_rays(&rays);
        let first_marker = prepared.ordered.len() - markers;
        assert!(
            prepared.ordered[..first_marker]
                .iter()
                .all(|r| !is_marker(r))
        );
        assert!(prepared.ordered[first_marker..].iter().all(is_marker));
        // The first tile holds real rays only: a narrow cone about x/z ≈ 0.3.
        assert!(
            prepared.tile_cones[0][3] < 0.05,
            "{:?}",
            prepared.tile_cones[0]
        );
        assert!(prepared.tile_cones[0][0] > 0.25);
    }

    #[test]
    fn tile_cones_hold_every_ray_of_their_tile() {
        let mut state = 12345u64;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 33) as f32 / (1u64 << 31) as f32) - 0.5
        };
        let rays: Vec<[f32; 4]> = (0..3000)
            .map(|_| {
                let (x, y) = (next(), next());
                let n = (x * x + y * y + 1.0).sqrt();
                [x / n, y / n, 1.0 / n, 3.0]
            })
            .collect();
        let tile_cones = prepare_rays(&rays).tile_cones;
        assert_eq!(tile_cones.len(), 3);
        // The cones of the rays in their new order.
        let ordered = morton_ordered(&rays);
        for (i, r) in ordered.iter().enumerate() {
            let cone = tile_cones[i / FAST_TILE];
            let cos = cone[0] * r[0] + cone[1] * r[1] + cone[2] * r[2];
            assert!(cos.clamp(-1.0, 1.0).acos() <= cone[3] + 1e-5, "ray {i}");
        }
        // Opposite rays: the axis is undefined, so the cone holds everything.
        let opposite = cone(&[[0.0, 0.0, 1.0, 1.0], [0.0, 0.0, -1.0, 1.0]]);
        assert!(opposite[3] >= std::f32::consts::PI);
    }
}
