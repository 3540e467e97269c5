//! The sparse-template likelihood (eq. 10–13 of the face paper) on the CPU: the reference the GPU
//! kernel is tested against, on one thread (the Fig. 6 baseline) and on all cores.
//!
//! For a particle x and a template {(P, N, J)}: each point that faces the camera is projected to
//! p, the frame is sampled bilinearly there (with the weights rounded to 8 bits, as the GPU's
//! texture unit rounds them), and κ = (α·I(p) − J)/J; ε = (1/N) Σ ρ(κ) with
//! ρ(κ) = κ²/(κ² + 1) over the N points that face the camera. A point that projects outside the
//! frame counts with ρ = 1, the largest value ρ takes, so a face leaving the frame loses weight.
//! A pose that shows less than [`MIN_VISIBLE_SHARE`] of the template's points has ε = 1: the
//! paper skips self-occluded points, and without this floor a face turned edge-on, showing a
//! handful of points that match by chance, would outweigh the true pose. The paper's weight is π ∝ 1/ε; the tracker allows
//! π ∝ ε^−γ (γ, the sharpness, is 1 in the paper), so log π = −γ·ln ε, ε floored at
//! [`MIN_ERROR`].
//!
//! Points are seen through a [`Lens`]: weak perspective (the paper's, and [`residual_error`]'s),
//! or a pinhole of known focal length ([`residual_error_through`]), which magnifies each point
//! by its depth about the principal point.

use pf_gpu::image::quantised_weight;
use rayon::prelude::*;

#[cfg(target_arch = "x86_64")]
mod gather;
pub mod gpu;

pub use crate::lens::Lens;

/// The WGSL of the face likelihood, launched by [`gpu::FaceLikelihoodGpu`]; this module's
/// functions are its CPU twin.
pub const SHADER: &str = include_str!("../../../../shaders/face/likelihood.wgsl");

use crate::image::GrayImage;
use crate::projection::{ALPHA, DIMS, RX, RY, RZ, SCALE, TX, TY};
use crate::template::Template;

/// The floor of ε, so that a perfect match has a finite weight.
pub const MIN_ERROR: f32 = 1e-6;

/// The smallest share of a template's points a pose must show to be weighed (else ε = 1).
pub const MIN_VISIBLE_SHARE: f32 = 0.25;

/// ρ(κ) = κ²/(κ² + 1).
pub fn rho(kappa: f32) -> f32 {
    let k2 = kappa * kappa;
    k2 / (k2 + 1.0)
}

/// ρ(κ) for κ = d/J, the residual d = α·I − J relative to the template's level J, computed as
/// d²/(d² + J²): the same value with one division instead of two (divisions were half the
/// loop's time). The GPU kernel and the benchmarks' C loop compute it so too.
#[inline]
pub fn rho_of_residual(residual: f32, gray: f32) -> f32 {
    let d2 = residual * residual;
    d2 / (d2 + gray * gray)
}

/// A particle's pose as the likelihood uses it: row 2 of R decides a point's visibility, rows 0
/// and 1 times the scale (plus the translation) give its image position.
#[derive(Debug, Clone, Copy)]
struct Projector {
    row_x: [f32; 3],
    row_y: [f32; 3],
    row_z: [f32; 3],
    tx: f32,
    ty: f32,
    /// S, which turns row_z's depth into pixels for a lens.
    scale: f32,
    alpha: f32,
}

impl Projector {
    /// The rows of R = Rx·Ry·Rz written out (the product of `projection::rotation` without its
    /// 54 multiplications, most by 0 or 1).
    fn new(state: &[f32; DIMS]) -> Self {
        let (sx, cx) = state[RX].sin_cos();
        let (sy, cy) = state[RY].sin_cos();
        let (sz, cz) = state[RZ].sin_cos();
        let s = state[SCALE];
        let row_x = [cy * cz, -cy * sz, sy];
        let row_y = [sx * sy * cz + cx * sz, -sx * sy * sz + cx * cz, -sx * cy];
        Self {
            row_x: row_x.map(|r| s * r),
            row_y: row_y.map(|r| s * r),
            row_z: [-cx * sy * cz + sx * sz, cx * sy * sz + sx * cz, cx * cy],
            tx: state[TX],
            ty: state[TY],
            scale: s,
            alpha: state[ALPHA],
        }
    }
}

/// The frame as the likelihood reads it.
struct Pixels<'a> {
    levels: &'a [u8],
    width: usize,
    x_max: f32,
    y_max: f32,
    x_cell_max: u32,
    y_cell_max: u32,
}

impl<'a> Pixels<'a> {
    fn new(frame: &'a GrayImage) -> Self {
        Self {
            levels: &frame.data,
            width: frame.width as usize,
            x_max: (frame.width - 1) as f32,
            y_max: (frame.height - 1) as f32,
            x_cell_max: frame.width - 2,
            y_cell_max: frame.height - 2,
        }
    }

    /// Whether bilinear sampling at (x, y) has its four neighbours (NaN is outside).
    #[allow(clippy::neg_cmp_op_on_partial_ord)]
    #[inline]
    fn inside(&self, x: f32, y: f32) -> bool {
        // `&`, not `&&`: no branches, so that the lanes of `residual_errors` vectorise.
        (x >= 0.0) & (y >= 0.0) & (x <= self.x_max) & (y <= self.y_max)
    }

    /// The top-left corner of the cell that (x, y), [`Pixels::inside`] the frame, lies in: the
    /// last row and column interpolate within the cell before them.
    #[inline]
    fn cell(&self, x: f32, y: f32) -> (u32, u32) {
        // x, y ≥ 0 here, so truncation is the floor (without a libm call); through i32, which
        // vector registers convert in one instruction (frames are far below 2³¹ pixels).
        let (x0, y0) = ((x as i32) as u32, (y as i32) as u32);
        (x0.min(self.x_cell_max), y0.min(self.y_cell_max))
    }

    /// The levels of the cell whose top-left pixel is `at`: top left, top right, bottom left,
    /// bottom right.
    #[inline]
    fn corners(&self, at: usize) -> [f32; 4] {
        let (upper, lower) = (
            &self.levels[at..at + 2],
            &self.levels[at + self.width..at + self.width + 2],
        );
        [upper[0], upper[1], lower[0], lower[1]].map(f32::from)
    }

    /// The bilinear interpolation at a point [`Pixels::inside`] the frame as the GPU's texture
    /// unit computes it (the twin of `bilinear` in `shaders/face/likelihood.wgsl`): the weights
    /// rounded to 8 fractional bits ([`quantised_weight`]), so within 1/512 of
    /// [`GrayImage::bilinear`]'s per axis.
    #[inline]
    fn bilinear(&self, x: f32, y: f32) -> f32 {
        let (x0, y0) = self.cell(x, y);
        let (fx, fy) = (
            quantised_weight(x - x0 as f32),
            quantised_weight(y - y0 as f32),
        );
        let [top_left, top_right, bottom_left, bottom_right] =
            self.corners(y0 as usize * self.width + x0 as usize);
        let top = top_left * (1.0 - fx) + top_right * fx;
        let bottom = bottom_left * (1.0 - fx) + bottom_right * fx;
        top * (1.0 - fy) + bottom * fy
    }
}

/// Whether a point whose rotated normal has this z faces the camera: only what is surely turned
/// away is skipped (a NaN pose counts as facing, and its ε comes out NaN).
#[allow(clippy::neg_cmp_op_on_partial_ord)]
#[inline]
fn facing_camera(normal_z: f32) -> bool {
    !(normal_z < 0.0)
}

/// ε from the sum of ρ over the `visible` points of a template of `points` points.
fn mean_residual(sum: f64, visible: usize, points: usize) -> f64 {
    if visible == 0 || (visible as f32) < MIN_VISIBLE_SHARE * points as f32 {
        1.0
    } else {
        sum / visible as f64
    }
}

/// ε of one particle through weak perspective, accumulated in f64: the definition, written as
/// the plain loop it is (the rotation's rows once per particle; no `Option` or `floor` call per
/// point). [`residual_errors`] computes the same values, bit for bit, several particles at a time.
pub fn residual_error(state: &[f32; DIMS], template: &Template, frame: &GrayImage) -> f64 {
    residual_error_through(state, template, frame, &Lens::WEAK)
}

/// [`residual_error`] with the points seen through `lens` (a point at or behind the camera
/// counts as outside the frame).
pub fn residual_error_through(
    state: &[f32; DIMS],
    template: &Template,
    frame: &GrayImage,
    lens: &Lens,
) -> f64 {
    let alpha = state[crate::projection::ALPHA];
    let mut sum = 0.0f64;
    let visible = visit_samples(state, template, frame, lens, |sample| {
        sum += sample.map_or(1.0, |(intensity, gray)| {
            f64::from(rho_of_residual(alpha * intensity - gray, gray))
        });
    });
    mean_residual(sum, visible, template.points.len())
}

/// The contrast α that best fits `template` to `frame` at `state`'s geometry in least squares
/// (Σ I·g / Σ I² over the visible points inside the frame; `state`'s own α is not read), or
/// `None` where no such point sees light: a starting α for a pose search, which ε's robust ρ
/// then refines.
pub fn least_squares_gain(
    state: &[f32; DIMS],
    template: &Template,
    frame: &GrayImage,
    lens: &Lens,
) -> Option<f32> {
    let (mut cross, mut square) = (0.0f64, 0.0f64);
    visit_samples(state, template, frame, lens, |sample| {
        if let Some((intensity, gray)) = sample {
            cross += f64::from(intensity) * f64::from(gray);
            square += f64::from(intensity) * f64::from(intensity);
        }
    });
    (square > 0.0).then(|| (cross / square) as f32)
}

/// Calls `visit` for each template point facing the camera at `state` with Some((the frame's
/// bilinear intensity there, the point's gray level)), or None where it falls outside the
/// frame; returns how many points faced the camera.
fn visit_samples(
    state: &[f32; DIMS],
    template: &Template,
    frame: &GrayImage,
    lens: &Lens,
    mut visit: impl FnMut(Option<(f32, f32)>),
) -> usize {
    let x = Projector::new(state);
    let pixels = Pixels::new(frame);
    let mut visible = 0usize;
    for q in &template.points {
        let ([nx, ny, nz], [px, py, pz]) = (q.normal, q.position);
        if !facing_camera(x.row_z[0] * nx + x.row_z[1] * ny + x.row_z[2] * nz) {
            continue;
        }
        visible += 1;
        let weak = [
            x.row_x[0] * px + x.row_x[1] * py + x.row_x[2] * pz + x.tx,
            x.row_y[0] * px + x.row_y[1] * py + x.row_y[2] * pz + x.ty,
        ];
        let depth = x.scale * (x.row_z[0] * px + x.row_z[1] * py + x.row_z[2] * pz);
        let [u, v] = lens.apply(weak, depth).unwrap_or([f32::NAN; 2]);
        visit(pixels.inside(u, v).then(|| (pixels.bilinear(u, v), q.gray)));
    }
    visible
}

/// Where the lanes sample the frame: each one's position within its cell and the cell's four
/// corners (top left, top right, bottom left, bottom right), one array per corner so that the
/// interpolation vectorises.
struct LaneSamples {
    fx: [f32; LANES],
    fy: [f32; LANES],
    corners: [[f32; LANES]; 4],
}

/// The [`LaneSamples`] of points (u, v) [`Pixels::inside`] the frame, one lane at a time.
#[inline(always)]
fn sample_lanes(pixels: &Pixels, u: &[f32; LANES], v: &[f32; LANES]) -> LaneSamples {
    let (mut fx, mut fy) = ([0.0f32; LANES], [0.0f32; LANES]);
    let mut corners = [[0.0f32; LANES]; 4];
    // Plain loops: `cells.map(..)` compiled to a call that took a third of the time.
    for l in 0..LANES {
        let (x0, y0) = pixels.cell(u[l], v[l]);
        (fx[l], fy[l]) = (u[l] - x0 as f32, v[l] - y0 as f32);
        let [a, b, c, d] = pixels.corners(y0 as usize * pixels.width + x0 as usize);
        (corners[0][l], corners[1][l], corners[2][l], corners[3][l]) = (a, b, c, d);
    }
    LaneSamples { fx, fy, corners }
}

/// Particles weighed together by [`residual_errors`].
pub const LANES: usize = 8;

/// ε of [`LANES`] particles at once, bit for bit [`residual_error`]'s: each template point is
/// loaded once for all of them and the arithmetic runs without branches, so that the compiler
/// keeps the lanes in vector registers (the pixel reads are scalar here; the AVX2 build of
/// [`residual_errors_of`] gathers them). This is the CPU path's whole
/// cost: 5 layers × 4 000 particles × ~230 points a frame at the defaults.
#[inline(always)]
pub fn residual_errors(
    states: &[[f32; DIMS]; LANES],
    template: &Template,
    frame: &GrayImage,
) -> [f64; LANES] {
    lanes::<false>(states, template, frame, &Lens::WEAK)
}

/// [`residual_errors`], the pixels read with AVX2's gather when `GATHER` (only ever
/// instantiated so inside [`residual_errors_of_avx2`], which runs where the CPU has AVX2), the
/// points seen through `lens`.
#[inline(always)]
fn lanes<const GATHER: bool>(
    states: &[[f32; DIMS]; LANES],
    template: &Template,
    frame: &GrayImage,
    lens: &Lens,
) -> [f64; LANES] {
    // The weak path keeps its arithmetic (bit for bit what it was); a pinhole adds its own.
    if lens.is_weak() {
        lanes_through::<GATHER, false>(states, template, frame, lens)
    } else {
        lanes_through::<GATHER, true>(states, template, frame, lens)
    }
}

/// [`lanes`] for weak perspective, or through a pinhole when `PINHOLE` (the arithmetic of
/// [`Lens::apply`], lane by lane without branches).
#[inline(always)]
fn lanes_through<const GATHER: bool, const PINHOLE: bool>(
    states: &[[f32; DIMS]; LANES],
    template: &Template,
    frame: &GrayImage,
    lens: &Lens,
) -> [f64; LANES] {
    #[cfg(target_arch = "x86_64")]
    let gather = GATHER && gather::can_gather(&frame.data, frame.width, frame.height);
    let poses = LanePoses::of(states);
    let pixels = Pixels::new(frame);
    let mut sum = [0.0f64; LANES];
    let mut visible = [0usize; LANES];
    // Three passes per point: the lanes' arithmetic (no branches, so vectorised), the pixel
    // reads (scalar), the residuals (vectorised).
    for q in &template.points {
        let (facing, inside, u, v) = poses.project::<PINHOLE>(q, lens, &pixels);
        let LaneSamples {
            fx,
            fy,
            corners: [top_left, top_right, bottom_left, bottom_right],
        } = {
            #[cfg(target_arch = "x86_64")]
            if gather {
                // SAFETY: GATHER is set only in the AVX2 build (see above), `can_gather` held,
                // and every lane's point is inside the frame.
                unsafe { gather::sample_lanes(&pixels, &u, &v) }
            } else {
                sample_lanes(&pixels, &u, &v)
            }
            #[cfg(not(target_arch = "x86_64"))]
            sample_lanes(&pixels, &u, &v)
        };
        for l in 0..LANES {
            // The texture unit's weights, as Pixels::bilinear.
            let (fx, fy) = (quantised_weight(fx[l]), quantised_weight(fy[l]));
            let top = top_left[l] * (1.0 - fx) + top_right[l] * fx;
            let bottom = bottom_left[l] * (1.0 - fx) + bottom_right[l] * fx;
            let intensity = top * (1.0 - fy) + bottom * fy;
            let rho = f64::from(rho_of_residual(poses.alpha[l] * intensity - q.gray, q.gray));
            let term = if inside[l] { rho } else { 1.0 };
            // Adding 0.0 leaves a sum of non-negative terms unchanged, bit for bit.
            sum[l] += if facing[l] { term } else { 0.0 };
            visible[l] += usize::from(facing[l]);
        }
    }
    std::array::from_fn(|l| mean_residual(sum[l], visible[l], template.points.len()))
}

/// One value of every lane's pose.
#[inline(always)]
fn each_lane(poses: &[Projector; LANES], value: impl Fn(&Projector) -> f32) -> [f32; LANES] {
    std::array::from_fn(|l| value(&poses[l]))
}

/// The lanes' poses component by component (`z[0][l]` is lane l's `row_z[0]`), so that a
/// point's arithmetic runs across the lanes without branches.
struct LanePoses {
    z: [[f32; LANES]; 3],
    x: [[f32; LANES]; 3],
    y: [[f32; LANES]; 3],
    tx: [f32; LANES],
    ty: [f32; LANES],
    alpha: [f32; LANES],
    scale: [f32; LANES],
}

impl LanePoses {
    #[inline(always)]
    fn of(states: &[[f32; DIMS]; LANES]) -> Self {
        let poses = states.map(|s| Projector::new(&s));
        Self {
            z: std::array::from_fn(|k| each_lane(&poses, |p| p.row_z[k])),
            x: std::array::from_fn(|k| each_lane(&poses, |p| p.row_x[k])),
            y: std::array::from_fn(|k| each_lane(&poses, |p| p.row_y[k])),
            tx: each_lane(&poses, |p| p.tx),
            ty: each_lane(&poses, |p| p.ty),
            alpha: each_lane(&poses, |p| p.alpha),
            scale: each_lane(&poses, |p| p.scale),
        }
    }

    /// Point `q` in every lane: whether it faces the camera, whether it lands inside the frame
    /// (and, through a pinhole, in front of the camera), and where (`u`, `v`; the corner for a
    /// lane outside, whose pixels are read and then ignored).
    #[inline(always)]
    #[allow(clippy::type_complexity)]
    fn project<const PINHOLE: bool>(
        &self,
        q: &crate::template::FeaturePoint,
        lens: &Lens,
        pixels: &Pixels<'_>,
    ) -> ([bool; LANES], [bool; LANES], [f32; LANES], [f32; LANES]) {
        let ([nx, ny, nz], [px, py, pz]) = (q.normal, q.position);
        let (inverse_focal, [principal_x, principal_y]) = (lens.inverse_focal, lens.principal);
        let ([zx, zy, zz], [xx, xy, xz], [yx, yy, yz]) = (&self.z, &self.x, &self.y);
        let (mut facing, mut inside) = ([false; LANES], [false; LANES]);
        let (mut u, mut v) = ([0.0f32; LANES], [0.0f32; LANES]);
        for l in 0..LANES {
            facing[l] = facing_camera(zx[l] * nx + zy[l] * ny + zz[l] * nz);
            let mut x = xx[l] * px + xy[l] * py + xz[l] * pz + self.tx[l];
            let mut y = yx[l] * px + yy[l] * py + yz[l] * pz + self.ty[l];
            let mut near = true;
            if PINHOLE {
                let depth = self.scale[l] * (zx[l] * px + zy[l] * py + zz[l] * pz);
                let distance = 1.0 - depth * inverse_focal;
                near = distance > Lens::MIN_DISTANCE_SHARE;
                x = principal_x + (x - principal_x) / distance;
                y = principal_y + (y - principal_y) / distance;
            }
            inside[l] = near & pixels.inside(x, y);
            (u[l], v[l]) = if inside[l] { (x, y) } else { (0.0, 0.0) };
        }
        (facing, inside, u, v)
    }
}

/// ε of every particle of `states` (any number) into `out`, [`LANES`] at a time: with AVX2's
/// 8-wide registers where the CPU has them (the same values bit for bit: the instructions
/// differ, the arithmetic and its order do not; Rust never fuses a multiply and an add).
pub fn residual_errors_of(
    states: &[[f32; DIMS]],
    template: &Template,
    frame: &GrayImage,
    out: &mut [f64],
) {
    residual_errors_of_through(states, template, frame, &Lens::WEAK, out);
}

/// [`residual_errors_of`] with the points seen through `lens`: [`residual_error_through`]'s
/// values, bit for bit.
pub fn residual_errors_of_through(
    states: &[[f32; DIMS]],
    template: &Template,
    frame: &GrayImage,
    lens: &Lens,
    out: &mut [f64],
) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2, detected just above.
        unsafe { residual_errors_of_avx2(states, template, frame, lens, out) };
        return;
    }
    errors_of::<false>(states, template, frame, lens, out);
}

/// [`residual_errors_of`] compiled for AVX2: the baseline x86-64 target has 4-wide registers,
/// so each of the eight lanes' f32 operations takes two instructions and each f64 one four.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn residual_errors_of_avx2(
    states: &[[f32; DIMS]],
    template: &Template,
    frame: &GrayImage,
    lens: &Lens,
    out: &mut [f64],
) {
    errors_of::<true>(states, template, frame, lens, out);
}

/// [`residual_errors_of`] built for the target the crate is compiled for, without AVX2.
pub fn residual_errors_of_baseline(
    states: &[[f32; DIMS]],
    template: &Template,
    frame: &GrayImage,
    out: &mut [f64],
) {
    errors_of::<false>(states, template, frame, &Lens::WEAK, out);
}

/// [`residual_errors_of`], its lanes' pixels gathered with AVX2 when `GATHER` (inlined into
/// each caller, so that the AVX2 variant compiles it with the wider registers).
#[inline(always)]
fn errors_of<const GATHER: bool>(
    states: &[[f32; DIMS]],
    template: &Template,
    frame: &GrayImage,
    lens: &Lens,
    out: &mut [f64],
) {
    let mut groups = states.chunks_exact(LANES);
    let mut outs = out.chunks_exact_mut(LANES);
    for (group, out) in (&mut groups).zip(&mut outs) {
        let group: &[[f32; DIMS]; LANES] = group.try_into().expect("chunks_exact gives LANES");
        out.copy_from_slice(&lanes::<GATHER>(group, template, frame, lens));
    }
    for (state, out) in groups.remainder().iter().zip(outs.into_remainder()) {
        *out = residual_error_through(state, template, frame, lens);
    }
}

/// log π = −γ·ln max(ε, [`MIN_ERROR`]).
pub fn log_weight(error: f64, sharpness: f32) -> f32 {
    (-f64::from(sharpness) * error.max(f64::from(MIN_ERROR)).ln()) as f32
}

/// ε for every particle on one thread: the paper's CPU baseline (Fig. 6).
pub fn weigh_single_thread(
    states: &[[f32; DIMS]],
    template: &Template,
    frame: &GrayImage,
) -> Vec<f64> {
    let mut errors = vec![0.0; states.len()];
    residual_errors_of(states, template, frame, &mut errors);
    errors
}

/// The same on all cores.
pub fn weigh_parallel(states: &[[f32; DIMS]], template: &Template, frame: &GrayImage) -> Vec<f64> {
    weigh_parallel_through(states, template, frame, &Lens::WEAK)
}

/// [`weigh_parallel`] with the points seen through `lens`.
pub fn weigh_parallel_through(
    states: &[[f32; DIMS]],
    template: &Template,
    frame: &GrayImage,
    lens: &Lens,
) -> Vec<f64> {
    let mut errors = vec![0.0; states.len()];
    // Tasks of 64 particles: one particle is about a microsecond of work.
    states
        .par_chunks(64)
        .zip(errors.par_chunks_mut(64))
        .for_each(|(states, out)| residual_errors_of_through(states, template, frame, lens, out));
    errors
}

#[cfg(test)]
mod projector_tests {
    use super::*;
    use crate::projection::rotation;
    use proptest::prelude::*;

    proptest! {
        /// The written-out rows are those of `projection::rotation` (the twin of the GPU
        /// kernel's Rx·Ry·Rz), scaled for x and y, to rounding.
        #[test]
        fn projector_rows_are_the_rotation_s(
            angles in prop::array::uniform3(-3.2f32..3.2),
            scale in 0.2f32..5.0,
            t in prop::array::uniform2(-100.0f32..2000.0),
            alpha in 0.25f32..4.0,
        ) {
            let state = [t[0], t[1], scale, angles[0], angles[1], angles[2], alpha];
            let x = Projector::new(&state);
            let r = rotation(angles[0], angles[1], angles[2]);
            for c in 0..3 {
                prop_assert!((x.row_x[c] - scale * r[(0, c)]).abs() <= 1e-5 * scale);
                prop_assert!((x.row_y[c] - scale * r[(1, c)]).abs() <= 1e-5 * scale);
                prop_assert!((x.row_z[c] - r[(2, c)]).abs() <= 1e-5);
            }
            prop_assert_eq!((x.tx, x.ty, x.alpha), (t[0], t[1], alpha));
        }
    }
}
