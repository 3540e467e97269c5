//! The survival rule's β searched in rounds spread over the GPU, for the fused step
//! (`shaders/engine/survival_search.wgsl`, `survival_round.wgsl`).
//!
//! The rule (`pf_core::anneal::survival_beta`) bisects for the β that keeps `rate`·M effective
//! particles: a test at `max_beta`, then 20 levels, each an ESS reduction over the target's
//! particles that waits for the one before. In one workgroup a target that is 21 serial passes a
//! layer, most of a layer's time when a frame has few targets (the rest of the GPU idle). Here a
//! round of dispatches tests `levels` levels at once: one workgroup per node of the round's
//! subtree of midpoints, each reducing exactly as the serial bisection would at that node, so the
//! next select walks the rounds' decisions to the serial bisection's β, bit for bit. For one target
//! a layer's 21 passes become two dispatches of 1 024 workgroups; with many targets the rounds
//! shrink (the GPU is already full) until the workgroup's own bisection is the better shape.

use pf_core::anneal::SURVIVAL_BISECTION_STEPS;
use pf_core::batch::BatchShape;

use super::fused::LayerParams;
use super::profile::Passes;
use super::setup::Streams;
use crate::context::GpuContext;
use crate::error::GpuError;
use crate::kernels::{Kernel, sources, stage_source};
use crate::stream::DeviceStream;

/// The bisection's levels (`BISECTION_LEVELS` in survival_search.wgsl; pf-core's steps).
const BISECTION_LEVELS: u32 = SURVIVAL_BISECTION_STEPS;

/// About how many workgroups a round should launch over all targets: enough to fill a large GPU
/// (an NVIDIA H100's 132 SMs hold eight 256-invocation workgroups each) without making the
/// rounds' exponentials the work.
const ROUND_WORKGROUPS: usize = 1024;

/// Rounds testing fewer levels than this are more dispatches than they save: the workgroup's own
/// bisection is kept (from 256 targets on, with [`ROUND_WORKGROUPS`]).
const MIN_SEARCH_LEVELS: u32 = 3;

/// The most levels a round tests (2^10 − 1 workgroups a target).
const MAX_SEARCH_LEVELS: u32 = 10;

/// The line of survival_search.wgsl that sets a round's levels.
const SEARCH_LEVELS_LINE: &str = "const SEARCH_LEVELS: u32 = 7u;";

/// The line of layer.wgsl that chooses between the rounds' β and the workgroup's bisection.
const BY_ROUNDS_LINE: &str = "const SURVIVAL_BY_ROUNDS: bool = false;";

/// How many of the bisection's levels a round of the search tests for `targets` targets (about
/// [`ROUND_WORKGROUPS`] workgroups a round), or `None` where the fused layer's workgroup bisects
/// for itself.
pub fn survival_search_levels(targets: usize) -> Option<u32> {
    let per_target = ROUND_WORKGROUPS / targets.max(1) + 1;
    let levels = per_target.ilog2().min(MAX_SEARCH_LEVELS);
    (levels >= MIN_SEARCH_LEVELS).then_some(levels)
}

/// How many search rounds a survival layer dispatches after its likelihood for `targets` targets
/// (0 where the fused layer's workgroup bisects for itself).
pub fn survival_search_rounds(targets: usize) -> u32 {
    survival_search_levels(targets).map_or(0, rounds_of)
}

/// Rounds of `levels` levels that cover the bisection.
fn rounds_of(levels: u32) -> u32 {
    BISECTION_LEVELS.div_ceil(levels)
}

/// `source` with the line `line` replaced by `replacement`; an error naming `kernel` where the
/// line is missing (the WGSL and the driver disagree).
pub(super) fn with_line(
    source: String,
    kernel: &str,
    line: &str,
    replacement: &str,
) -> Result<String, GpuError> {
    if !source.contains(line) {
        return Err(GpuError::Shader {
            kernel: kernel.into(),
            message: format!("the source has no line `{line}` to set"),
        });
    }
    Ok(source.replace(line, replacement))
}

/// The fused layer's source set to search by rounds of `levels` (or to bisect in its workgroup).
pub(super) fn layer_with_search(source: String, levels: Option<u32>) -> Result<String, GpuError> {
    match levels {
        None => Ok(source),
        Some(levels) => {
            let source = with_line(
                source,
                "fused layer",
                SEARCH_LEVELS_LINE,
                &format!("const SEARCH_LEVELS: u32 = {levels}u;"),
            )?;
            with_line(
                source,
                "fused layer",
                BY_ROUNDS_LINE,
                "const SURVIVAL_BY_ROUNDS: bool = true;",
            )
        }
    }
}

/// The search's kernel, its decisions and a bind group per layer and round.
pub(super) struct SurvivalSearch {
    levels: u32,
    kernel: Kernel,
    /// Whether each node's ESS reached the wanted one, per target, round and node.
    decisions: DeviceStream<u32>,
    /// The round index of each dispatch, one uniform slice a round (kept alive for the groups).
    _rounds: wgpu::Buffer,
    /// `groups[layer][round]`.
    groups: Vec<Vec<wgpu::BindGroup>>,
}

impl SurvivalSearch {
    /// The search in rounds of `levels` levels for a filter of `shape`, bound to each layer's
    /// parameters.
    pub(super) fn new(
        ctx: &GpuContext,
        shape: &BatchShape,
        levels: u32,
        streams: &Streams,
        layers: &LayerParams<'_>,
    ) -> Result<Self, GpuError> {
        let source = with_line(
            stage_source(sources::SURVIVAL_ROUND),
            "survival round",
            SEARCH_LEVELS_LINE,
            &format!("const SEARCH_LEVELS: u32 = {levels}u;"),
        )?;
        let kernel = Kernel::new(ctx, "survival round", &source, "survival_round")?;
        let rounds = rounds_of(levels);
        let slots = shape.targets * rounds as usize * (1usize << levels);
        let decisions = DeviceStream::zeroed(ctx, "survival search decisions", slots)?;
        let stride = u64::from(ctx.limits().min_uniform_buffer_offset_alignment).max(16);
        let round_buffer = round_indices(ctx, rounds, stride)?;
        let groups = (0..layers.count)
            .map(|layer| {
                (0..u64::from(rounds))
                    .map(|round| {
                        let index = wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                            buffer: &round_buffer,
                            offset: round * stride,
                            size: wgpu::BufferSize::new(16),
                        });
                        kernel.bind(
                            ctx,
                            &[
                                (0, layers.slice(layer)),
                                (1, index),
                                (2, streams.log_weights.binding()),
                                (3, streams.log_likelihood.binding()),
                                (4, decisions.binding()),
                            ],
                        )
                    })
                    .collect::<Result<Vec<_>, _>>()
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Self {
            levels,
            kernel,
            decisions,
            _rounds: round_buffer,
            groups,
        })
    }

    /// The levels a round tests.
    pub(super) fn levels(&self) -> u32 {
        self.levels
    }

    /// The decisions the fused layer walks (its binding 15).
    pub(super) fn decisions(&self) -> wgpu::BindingResource<'_> {
        self.decisions.binding()
    }

    /// Records `layer`'s rounds, after its likelihood, for `targets` targets.
    pub(super) fn record(&self, passes: &mut Passes<'_>, layer: usize, targets: usize) {
        for (round, group) in self.groups[layer].iter().enumerate() {
            let levels = self
                .levels
                .min(BISECTION_LEVELS - round as u32 * self.levels);
            // The round's nodes, and in round 0 the test at max_beta.
            let nodes = (1u32 << levels) - 1 + u32::from(round == 0);
            passes.dispatch(
                || format!("layer {layer}: survival round {round}"),
                |pass| self.kernel.record(pass, group, [nodes, targets as u32, 1]),
            );
        }
    }
}

/// A uniform buffer of `rounds` slices `stride` bytes apart, slice r holding r.
fn round_indices(ctx: &GpuContext, rounds: u32, stride: u64) -> Result<wgpu::Buffer, GpuError> {
    let words = (stride / 4) as usize;
    let mut contents = vec![0u32; words * rounds as usize];
    for round in 0..rounds {
        contents[round as usize * words] = round;
    }
    let buffer = ctx.scoped("creating the survival rounds' indices", || {
        ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("survival round indices"),
            size: (contents.len() * 4) as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    })?;
    ctx.queue
        .write_buffer(&buffer, 0, bytemuck::cast_slice(&contents));
    Ok(buffer)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rounds_shrink_with_the_targets_until_the_workgroup_bisects() {
        assert_eq!(survival_search_levels(1), Some(10));
        assert_eq!(survival_search_levels(4), Some(8));
        assert_eq!(survival_search_levels(64), Some(4));
        assert_eq!(survival_search_levels(128), Some(3));
        assert_eq!(survival_search_levels(256), None);
        assert_eq!(survival_search_levels(0), Some(10));
        for targets in 1..2000 {
            if let Some(levels) = survival_search_levels(targets) {
                // At most ROUND_WORKGROUPS workgroups a round (round 0's test at max_beta aside).
                assert!(targets * ((1 << levels) - 1) <= ROUND_WORKGROUPS);
                assert!((MIN_SEARCH_LEVELS..=MAX_SEARCH_LEVELS).contains(&levels));
            }
        }
        assert_eq!(rounds_of(10), 2);
        assert_eq!(rounds_of(7), 3);
        assert_eq!(rounds_of(3), 7);
        assert_eq!(survival_search_rounds(1), 2);
        assert_eq!(survival_search_rounds(1000), 0);
    }
}
