//! An 8-bit gray frame on the GPU as a texture, read through the texture unit's bilinear filter:
//! for image likelihoods (the face tracker's, or a researcher's own), whose cost at many targets
//! is the sampling. One `textureSampleLevel` replaces four loads and the interpolation by hand
//! (see `shaders/face/likelihood.wgsl`), and the texture cache holds the neighbourhood.
//!
//! What the hardware computes, and what a CPU twin must compute to agree: for a pixel position
//! (x, y) (pixel centres at integers, as the CPU's images have them) the kernel samples at
//! ((x + ½)/width, (y + ½)/height); the unit takes the cell (⌊x⌋, ⌊y⌋) with clamp-to-edge, and
//! its fractional weights fx, fy carry 8 bits (Vulkan's `subTexelPrecisionBits`: 8 on NVIDIA's
//! drivers and Mesa's lavapipe): [`quantised_weight`] is that rounding. The sampled value is a
//! level / 255 (`R8Unorm`).

use crate::context::GpuContext;
use crate::error::GpuError;

/// The fractional bits of a texture unit's bilinear weights (Vulkan's `subTexelPrecisionBits`).
pub const SUBTEXEL_BITS: u32 = 8;

/// A bilinear weight in [0, 1] as the texture unit applies it: rounded to `SUBTEXEL_BITS`
/// fractional bits (to nearest; whether a unit truncates instead is within the GPU-vs-CPU tests'
/// bound, one step of 1/256). Written with a conversion to `i32` rather than `round`, so that it
/// vectorises in the CPU likelihood's lanes.
#[inline(always)]
pub fn quantised_weight(fraction: f32) -> f32 {
    const STEPS: f32 = (1u32 << SUBTEXEL_BITS) as f32;
    ((fraction * STEPS + 0.5) as i32) as f32 * (1.0 / STEPS)
}

/// A `width × height` frame of 8-bit gray levels as an `R8Unorm` texture, with the linear,
/// clamp-to-edge sampler that reads it.
#[derive(Debug)]
pub struct GrayTexture {
    texture: wgpu::Texture,
    view: wgpu::TextureView,
    sampler: wgpu::Sampler,
    width: u32,
    height: u32,
}

impl GrayTexture {
    /// A zeroed frame. Larger than the adapter's 2-D texture limit is a
    /// [`GpuError::InvalidConfig`] that names the limit.
    pub fn new(ctx: &GpuContext, label: &str, width: u32, height: u32) -> Result<Self, GpuError> {
        let limit = ctx.device.limits().max_texture_dimension_2d;
        if width == 0 || height == 0 || width > limit || height > limit {
            return Err(GpuError::InvalidConfig(format!(
                "a {width}x{height} frame does not fit this adapter's textures (1 to {limit} pixels a side)"
            )));
        }
        let (texture, sampler) = ctx.scoped(&format!("creating texture {label}"), || {
            let texture = ctx.device.create_texture(&wgpu::TextureDescriptor {
                label: Some(label),
                size: extent(width, height),
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: wgpu::TextureFormat::R8Unorm,
                usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
                view_formats: &[],
            });
            let sampler = ctx.device.create_sampler(&wgpu::SamplerDescriptor {
                label: Some(label),
                address_mode_u: wgpu::AddressMode::ClampToEdge,
                address_mode_v: wgpu::AddressMode::ClampToEdge,
                mag_filter: wgpu::FilterMode::Linear,
                min_filter: wgpu::FilterMode::Linear,
                ..Default::default()
            });
            (texture, sampler)
        })?;
        let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
        Ok(Self {
            texture,
            view,
            sampler,
            width,
            height,
        })
    }

    /// Uploads a frame's levels, `[y·width + x]` (queued; it lands before the next submission).
    pub fn upload(&self, ctx: &GpuContext, levels: &[u8]) -> Result<(), GpuError> {
        let pixels = self.width as usize * self.height as usize;
        if levels.len() != pixels {
            return Err(GpuError::LengthMismatch {
                what: format!("gray frame ({}x{} pixels)", self.width, self.height),
                expected: pixels,
                got: levels.len(),
            });
        }
        ctx.queue.write_texture(
            wgpu::TexelCopyTextureInfo {
                texture: &self.texture,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            levels,
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(self.width),
                rows_per_image: Some(self.height),
            },
            extent(self.width, self.height),
        );
        Ok(())
    }

    /// The texture's binding (`texture_2d<f32>` in WGSL).
    pub fn binding(&self) -> wgpu::BindingResource<'_> {
        wgpu::BindingResource::TextureView(&self.view)
    }

    /// The sampler's binding (`sampler` in WGSL).
    pub fn sampler_binding(&self) -> wgpu::BindingResource<'_> {
        wgpu::BindingResource::Sampler(&self.sampler)
    }

    /// The frame size (width, height).
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }
}

fn extent(width: u32, height: u32) -> wgpu::Extent3d {
    wgpu::Extent3d {
        width,
        height,
        depth_or_array_layers: 1,
    }
}

#[cfg(test)]
mod tests {
    use super::quantised_weight;

    #[test]
    fn weights_round_to_the_nearest_256th() {
        assert_eq!(quantised_weight(0.0), 0.0);
        assert_eq!(quantised_weight(1.0), 1.0);
        assert_eq!(quantised_weight(0.5), 0.5);
        assert_eq!(quantised_weight(0.3), 77.0 / 256.0);
        assert_eq!(quantised_weight(1.0 / 512.0 - 1e-6), 0.0);
        assert_eq!(quantised_weight(0.999), 1.0);
        for i in 0..=1000 {
            let f = i as f32 / 1000.0;
            assert!((quantised_weight(f) - f).abs() <= 0.5 / 256.0 + 1e-7);
        }
    }
}
