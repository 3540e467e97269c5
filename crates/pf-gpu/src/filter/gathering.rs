//! The fused step's moves that gather (`layer.wgsl`'s `move_gathering`). From layer 1 on, the
//! select only normalises and searches (`GATHER` false), and the move reads each particle's
//! ancestor and that ancestor's values from the snapshot the layer before's move wrote, instead
//! of the select's one workgroup copying every value serially (about 6 µs of each layer's chain
//! on an NVIDIA H200: docs/BENCHMARKS.md, "What the gather costs a select"). Layer 0 still
//! gathers from `states`, which the trackers write between frames, and keeps the first snapshot.
//! The same values in the same order as the gathering select, so the same particles.
//!
//! Used where every layer moves with the engine's diffusion (not a likelihood's own dynamics);
//! elsewhere the fused step gathers in the select. A select that composes the lineage has its
//! own searching variant (`fused.rs`, `SelectKeepingLineage::searching`).

use super::layer_bindings::{LayerParams, moving_entries, selecting_entries};
use super::setup::Streams;
use crate::context::GpuContext;
use crate::error::GpuError;
use crate::kernels::{Kernel, KernelOptions};
use crate::stream::DeviceStream;

/// The kernels, the snapshots and the bind groups of a fused step whose moves gather.
pub(super) struct GatheringMoves {
    /// `select_*` without the gather, with its bind group per layer (layer 0's unused).
    searching: Kernel,
    searching_groups: Vec<wgpu::BindGroup>,
    /// Layer 0's move (from `selected`) and the middle layers' (from a snapshot), each keeping
    /// the next snapshot, and the last layer's, which keeps none.
    first: Kernel,
    middle: Kernel,
    last: Kernel,
    /// The move's bind group per layer, for the kernel of [`GatheringMoves::move_kernel`].
    moving_groups: Vec<wgpu::BindGroup>,
    /// Two snapshots of the states, written in turn (bound to every move).
    snapshots: DeviceStream<f32>,
}

impl GatheringMoves {
    /// Built for `layers.count` ≥ 2 layers of a filter of `state_len` values, from the layer
    /// kernel's `source` and the resampler's `select_entry`.
    pub(super) fn new(
        ctx: &GpuContext,
        source: &str,
        select_entry: &str,
        streams: &Streams,
        layers: &LayerParams<'_>,
        state_len: usize,
    ) -> Result<Self, GpuError> {
        let with = |name: &str, entry: &str, constants: &[(&str, f64)]| {
            let options = KernelOptions {
                constants,
                ..KernelOptions::trusted()
            };
            Kernel::with_options(ctx, name, source, entry, options)
        };
        let searching = with("fused search", select_entry, &[("GATHER", 0.0)])?;
        let first = Kernel::trusted(ctx, "fused first move", source, "move_keeping_snapshot")?;
        let middle = with(
            "fused gathering move",
            "move_gathering",
            &[("WRITES_SNAPSHOT", 1.0)],
        )?;
        let last = with(
            "fused last move",
            "move_gathering",
            &[("WRITES_SNAPSHOT", 0.0)],
        )?;
        let snapshots = DeviceStream::zeroed(ctx, "state snapshots", 2 * state_len)?;
        let searching_groups = (0..layers.count)
            .map(|layer| searching.bind(ctx, &selecting_entries(streams, layers, layer)))
            .collect::<Result<Vec<_>, _>>()?;
        let mut moves = Self {
            searching,
            searching_groups,
            first,
            middle,
            last,
            moving_groups: Vec::new(),
            snapshots,
        };
        moves.moving_groups = (0..layers.count)
            .map(|layer| moves.bind_move(ctx, streams, layers, layer))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(moves)
    }

    /// The move kernel of `layer` of `count`.
    fn move_kernel(&self, layer: usize, count: usize) -> &Kernel {
        if layer == 0 {
            &self.first
        } else if layer + 1 < count {
            &self.middle
        } else {
            &self.last
        }
    }

    fn bind_move(
        &self,
        ctx: &GpuContext,
        s: &Streams,
        layers: &LayerParams<'_>,
        layer: usize,
    ) -> Result<wgpu::BindGroup, GpuError> {
        // Layer 0 reads `selected`, the others each particle's ancestor.
        let source = if layer == 0 {
            (6, s.selected.binding())
        } else {
            (7, s.ancestors.binding())
        };
        let mut entries = moving_entries(s, layers, layer, source);
        entries.push((18, self.snapshots.binding()));
        self.move_kernel(layer, layers.count).bind(ctx, &entries)
    }

    /// Records layer `layer`'s select (after layer 0: the search alone; layer 0's is the
    /// gathering select, which the caller records).
    pub(super) fn record_search(
        &self,
        pass: &mut wgpu::ComputePass<'_>,
        layer: usize,
        grid: [u32; 3],
    ) {
        self.searching
            .record(pass, &self.searching_groups[layer], grid);
    }

    /// Records layer `layer`'s move (of `count` layers).
    pub(super) fn record_move(
        &self,
        pass: &mut wgpu::ComputePass<'_>,
        layer: usize,
        count: usize,
        grid: [u32; 3],
    ) {
        self.move_kernel(layer, count)
            .record(pass, &self.moving_groups[layer], grid);
    }
}
