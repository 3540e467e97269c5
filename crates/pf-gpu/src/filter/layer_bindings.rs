//! What the fused layer's kernels (`shaders/engine/layer.wgsl`) bind in common: each layer's
//! slice of the parameter buffer, the select's bindings, shared by the gathering select
//! (`super::fused`) and the one that leaves the gather to the move (`super::gathering`), and the
//! bindings every move takes.

use super::FrameParams;
use super::setup::Streams;

/// The per-layer parameter blocks in one uniform buffer, `stride` bytes apart (the adapter's
/// uniform offset alignment).
pub(super) struct LayerParams<'a> {
    pub buffer: &'a wgpu::Buffer,
    pub stride: u64,
    pub count: usize,
}

impl LayerParams<'_> {
    pub(super) fn slice(&self, layer: usize) -> wgpu::BindingResource<'_> {
        wgpu::BindingResource::Buffer(wgpu::BufferBinding {
            buffer: self.buffer,
            offset: layer as u64 * self.stride,
            size: wgpu::BufferSize::new(std::mem::size_of::<FrameParams>() as u64),
        })
    }
}

/// The bindings of `select_*` for `layer`.
pub(super) fn selecting_entries<'a>(
    s: &'a Streams,
    layers: &'a LayerParams<'_>,
    layer: usize,
) -> Vec<(u32, wgpu::BindingResource<'a>)> {
    vec![
        (0, layers.slice(layer)),
        (1, layers.slice(layer.saturating_sub(1))),
        (2, s.log_weights.binding()),
        (3, s.log_likelihood.binding()),
        (4, s.weights.binding()),
        (5, s.stats.binding()),
        (6, s.selected.binding()),
        (7, s.ancestors.binding()),
        (8, s.resampling_keys.binding()),
        (9, s.states.binding()),
    ]
}

/// The bindings of a move for `layer`, reading its particles from `source` (`selected`, or the
/// ancestors of a move that gathers).
pub(super) fn moving_entries<'a>(
    s: &'a Streams,
    layers: &'a LayerParams<'_>,
    layer: usize,
    source: (u32, wgpu::BindingResource<'a>),
) -> Vec<(u32, wgpu::BindingResource<'a>)> {
    vec![
        (0, layers.slice(layer)),
        source,
        (9, s.states.binding()),
        (10, s.sigma.binding()),
        (11, s.lower.binding()),
        (12, s.upper.binding()),
        (13, s.diffusion_keys.binding()),
        (14, s.velocity.binding()),
    ]
}
