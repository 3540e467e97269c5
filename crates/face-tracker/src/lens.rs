//! The camera a face is seen through ([`Lens`]), shared by projection, the likelihood on both
//! paths (its GPU launcher uploads it in the kernel's parameters), extraction and the renderer.

use pf_gpu::GpuError;

/// The camera a face is seen through: weak perspective (the face paper's: a point's image is
/// S·R₂ₓ₃·P + T whatever its depth), or a pinhole whose focal length is f pixels, the principal
/// point at `principal`. Through a pinhole a point lying d pixels nearer the camera than the
/// face's centre is magnified f/(f − d) about the principal point: at a webcam's range the
/// side of a face that turns towards the camera grows and moves out, which weak perspective reads
/// as a larger turn. `through_lens` in `shaders/face/likelihood.wgsl` is the GPU's copy of
/// [`Lens::apply`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lens {
    /// 1/f (0: weak perspective).
    pub inverse_focal: f32,
    /// Where the camera's axis meets the frame (pixels).
    pub principal: [f32; 2],
}

impl Lens {
    /// Weak perspective: images are not magnified by depth.
    pub const WEAK: Lens = Lens {
        inverse_focal: 0.0,
        principal: [0.0, 0.0],
    };

    /// A pinhole of focal length `focal` pixels whose principal point is the middle of a
    /// `width × height` frame.
    pub fn pinhole(focal: f32, width: u32, height: u32) -> Result<Self, GpuError> {
        if !(focal.is_finite() && focal > 0.0) {
            return Err(GpuError::InvalidConfig(format!(
                "a focal length must be finite and positive (pixels), got {focal}"
            )));
        }
        Ok(Self {
            inverse_focal: 1.0 / focal,
            principal: [
                (width.max(1) - 1) as f32 / 2.0,
                (height.max(1) - 1) as f32 / 2.0,
            ],
        })
    }

    /// The horizontal fields of view, in degrees, that [`Self::focal_length_for`] takes.
    pub const FIELD_OF_VIEW: std::ops::RangeInclusive<f32> = 1.0..=170.0;

    /// The focal length in pixels of a camera whose `width`-pixel frames span `fov` degrees
    /// across; an error outside [`Self::FIELD_OF_VIEW`].
    pub fn focal_length_for(fov: f32, width: u32) -> Result<f32, GpuError> {
        if !Self::FIELD_OF_VIEW.contains(&fov) {
            return Err(GpuError::InvalidConfig(format!(
                "a field of view is {} to {} degrees, got {fov}",
                Self::FIELD_OF_VIEW.start(),
                Self::FIELD_OF_VIEW.end()
            )));
        }
        Ok(width as f32 / 2.0 / (fov.to_radians() / 2.0).tan())
    }

    /// Whether this is weak perspective (no focal length).
    pub fn is_weak(&self) -> bool {
        self.inverse_focal == 0.0
    }

    /// Where a point is seen whose weak-perspective image is `weak` (S·R₂ₓ₃·P + T) and which
    /// lies `depth` pixels nearer the camera than the face's centre (S·(R·P)_z): `weak` itself
    /// through weak perspective, else magnified f/(f − depth) about the principal point. `None`
    /// for a point at or behind the camera's centre (within [`Self::MIN_DISTANCE_SHARE`] of f).
    #[inline]
    pub fn apply(&self, weak: [f32; 2], depth: f32) -> Option<[f32; 2]> {
        if self.is_weak() {
            return Some(weak);
        }
        let distance = 1.0 - depth * self.inverse_focal;
        #[allow(clippy::neg_cmp_op_on_partial_ord)]
        if !(distance > Self::MIN_DISTANCE_SHARE) {
            return None;
        }
        let [px, py] = self.principal;
        Some([
            px + (weak[0] - px) / distance,
            py + (weak[1] - py) / distance,
        ])
    }

    /// The inverse of [`Self::apply`] at a known depth: the weak-perspective image of a point
    /// seen at `image` that lies `depth` nearer the camera than the face's centre.
    pub fn unapply(&self, image: [f32; 2], depth: f32) -> [f32; 2] {
        if self.is_weak() {
            return image;
        }
        let distance = 1.0 - depth * self.inverse_focal;
        let [px, py] = self.principal;
        [
            px + (image[0] - px) * distance,
            py + (image[1] - py) * distance,
        ]
    }

    /// A point nearer the camera than 1 − this share of the focal length (of the face's
    /// distance, in the focal length's units) is not imaged: it is at or behind the camera.
    pub const MIN_DISTANCE_SHARE: f32 = 0.05;
}
