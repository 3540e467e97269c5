//! The plain C loops the CPU reference kernels are measured against (built by the root
//! package's build.rs), behind safe wrappers.

use face_tracker::image::GrayImage;
use face_tracker::template::Template;

unsafe extern "C" {
    fn streampf_face_residual_c(
        state: *const f32,
        points: *const f32,
        count: usize,
        pixels: *const u8,
        width: u32,
        height: u32,
        min_visible_share: f32,
    ) -> f64;
}

/// ε of one particle by the plain C loop (face_residual.c): the twin of
/// `face_tracker::likelihood::residual_error`.
pub fn face_residual_c(state: &[f32; 7], template: &Template, frame: &GrayImage) -> f64 {
    let points: &[f32] = bytemuck::cast_slice(&template.points);
    assert!(frame.width >= 2 && frame.height >= 2);
    assert_eq!(
        frame.data.len(),
        frame.width as usize * frame.height as usize
    );
    // SAFETY: `points` holds 8 floats per point (FeaturePoint is repr(C), 8 f32s); the frame's
    // data matches its size, which is at least 2x2 (checked above), so every read the loop makes
    // (inside [0, w-1] x [0, h-1]) is in bounds.
    unsafe {
        streampf_face_residual_c(
            state.as_ptr(),
            points.as_ptr(),
            template.points.len(),
            frame.data.as_ptr(),
            frame.width,
            frame.height,
            face_tracker::likelihood::MIN_VISIBLE_SHARE,
        )
    }
}
