//! The fused step (`shaders/engine/layer.wgsl`): each annealing layer is a dispatch of one
//! workgroup per target that normalises the layer before it, resamples in workgroup memory and
//! gathers its ancestors' states (from layer 1 on, where the step allows, the move gathers
//! instead: `super::gathering`), a dispatch of one invocation per particle and pair of
//! dimensions that moves them (the random numbers spread over the whole GPU), then the likelihood's own dispatches; the frame ends
//! with the last layer's normalisation and the estimate. All of it is one compute pass: each
//! layer's parameters are a slice of one uniform buffer, bound by a bind group of its own, so no
//! copy splits the pass. The staged step (`record.rs`: resample, gather, copy, diffuse,
//! likelihood, normalise per layer) stays as the reference and for what the fused one does not
//! cover (Metropolis resampling, more particles than a workgroup holds).
//!
//! Both draw the same random numbers in the same order, so they give the same particles (the
//! `fused_step` tests check it, and each against the CPU twin `pf_core::batch::BatchFilter`).

use pf_core::batch::BatchShape;

use super::SINGLE_WORKGROUP_SCAN_LIMIT;
use super::gathering::GatheringMoves;
use super::lag_window::LagStep;
pub(super) use super::layer_bindings::LayerParams;
use super::layer_bindings::{moving_entries, selecting_entries};
use super::profile::{DispatchProfiler, Passes};
use super::setup::{Streams, groups_for};
use super::{FrameParams, GpuFilter, GpuLikelihood, GpuResampler, LikelihoodPhase};
use crate::context::GpuContext;
use crate::error::GpuError;
use crate::kernels::{Kernel, KernelOptions, sources, stage_source};

/// How a [`GpuFilter`] records a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StepLayout {
    /// A dispatch a layer for normalising and selection, one for moving (`layer.wgsl`), in one
    /// compute pass: the default where it fits
    /// ([`fused_layout_refusal`]) and pays ([`FUSED_DEFAULT_MAX_VALUES`]).
    Fused,
    /// Every stage its own dispatch, as `run_stages` records them: the reference.
    Staged,
}

/// The most values (particles × dimensions) a target may have for the fused step to be the
/// default. Its select's one workgroup resamples a target alone (and, in layer 0 or where the
/// moves cannot gather, gathers its values there too), where the staged step spreads that work
/// over many workgroups: that pays for few values a target and costs for many.
/// Measured on an NVIDIA H100 (docs/BENCHMARKS.md): the face tracker (1 000 × 7 a face) fused took
/// 0.36 ms of GPU time a step for one face (0.52 staged, in an earlier build); the body tracker
/// (3 500 samples × its 30-odd angles, one target) 39.4 ms an annealed step against 35.0 staged
/// when the fused layer also moved the particles in that workgroup.
pub const FUSED_DEFAULT_MAX_VALUES: usize = 16_384;

/// Storage buffers the fused kernel binds.
const FUSED_STORAGE_BUFFERS: u32 = 8;

/// Storage buffers the select binds when it also composes the lineage (the lineage before, the
/// lineage after, the restart flags).
const LINEAGE_SELECT_STORAGE_BUFFERS: u32 = FUSED_STORAGE_BUFFERS + 3;

/// Bytes of workgroup memory the fused kernel needs for `particles` a target: their
/// log-likelihoods (the CDF after) and log-weights (the weights after), plus the scan's and the
/// normalisation's partial sums.
pub fn fused_workgroup_bytes(particles: usize) -> u64 {
    let held = 2 * 4 * particles as u64;
    let scan = 256 * 4 + 4;
    let normalise = 256 * 4 + 256 * 16 + 2 * 4;
    held + scan + normalise
}

/// Why the fused step cannot run `shape` with `resampler` on this adapter (`None`: it can).
pub fn fused_layout_refusal(
    ctx: &GpuContext,
    shape: &BatchShape,
    resampler: GpuResampler,
) -> Option<String> {
    let limits = ctx.limits();
    if let GpuResampler::Metropolis(_) = resampler {
        return Some("Metropolis resampling runs per offspring, not per target".into());
    }
    if shape.particles > SINGLE_WORKGROUP_SCAN_LIMIT {
        return Some(format!(
            "{} particles a target are more than one workgroup resamples ({SINGLE_WORKGROUP_SCAN_LIMIT})",
            shape.particles
        ));
    }
    let bytes = fused_workgroup_bytes(shape.particles);
    if bytes > u64::from(limits.max_compute_workgroup_storage_size) {
        return Some(format!(
            "{} particles need {bytes} bytes of workgroup memory; the adapter has {}",
            shape.particles, limits.max_compute_workgroup_storage_size
        ));
    }
    let move_groups = Grids::of(shape).per_pair[0];
    if move_groups > limits.max_compute_workgroups_per_dimension {
        return Some(format!(
            "{} particles × {} dimensions make {move_groups} workgroups of the move; the adapter \
             allows {} a dimension",
            shape.particles, shape.dims, limits.max_compute_workgroups_per_dimension
        ));
    }
    if limits.max_storage_buffers_per_shader_stage < FUSED_STORAGE_BUFFERS {
        return Some(format!(
            "the fused kernel binds {FUSED_STORAGE_BUFFERS} storage buffers; the adapter allows {}",
            limits.max_storage_buffers_per_shader_stage
        ));
    }
    None
}

/// The layout a filter of `shape` starts with, given whether the fused one fits.
pub(super) fn default_layout(shape: &BatchShape, fits: bool) -> StepLayout {
    if fits && shape.particles * shape.dims <= FUSED_DEFAULT_MAX_VALUES {
        StepLayout::Fused
    } else {
        StepLayout::Staged
    }
}

/// The fused layer's kernels and bind groups, built once.
pub(super) struct FusedLayers {
    /// Normalise the previous layer, resample and gather into `selected`: one workgroup a target.
    selecting: Kernel,
    /// Move the selected particles back into `states`: one invocation a particle and pair of
    /// dimensions.
    moving: Kernel,
    /// Copy the selected particles back unmoved (layer 0 of a likelihood that propagates).
    copying: Kernel,
    /// `selecting`'s and `moving`'s bind groups per layer (its parameter slice, and for
    /// `selecting` the one before it).
    selecting_groups: Vec<wgpu::BindGroup>,
    moving_groups: Vec<wgpu::BindGroup>,
    copying_group: wgpu::BindGroup,
    /// The last layer's normalisation (the normalise stage's work, with the survival rule's
    /// passes in workgroup memory), bound to that layer's parameters.
    settling: Kernel,
    settling_group: wgpu::BindGroup,
    /// `select_systematic` or `select_stratified`: the resampler's entry points.
    select_entry: &'static str,
    /// The select that also composes the lineage, once the filter keeps it and where the
    /// adapter binds its storage buffers ([`FusedLayers::keep_lineage`]).
    keeping_lineage: Option<SelectKeepingLineage>,
    /// Whether that select is used (else the lineage's own dispatches, the reference).
    lineage_in_select: bool,
    /// From layer 1 on, the moves gathering the ancestors' values themselves (two or more
    /// layers); used where the step allows ([`FusedLayers::gathering_for`]).
    gathering: Option<GatheringMoves>,
}

/// `select_*_keeping_lineage` and its bind group per layer: the lineage composed in the
/// select's workgroup, with no dispatch of its own (`lineage.wgsl`'s, which it replaces).
struct SelectKeepingLineage {
    kernel: Kernel,
    groups: Vec<wgpu::BindGroup>,
    /// The same without the gather (`GATHER` false), for the layers after the first where the
    /// moves gather ([`GatheringMoves`]); built where the step has them.
    searching: Option<(Kernel, Vec<wgpu::BindGroup>)>,
}

/// The line of `layer.wgsl` that sizes its workgroup array.
const STAGE_CAPACITY_LINE: &str = "const STAGE_CAPACITY: u32 = 4096u;";

/// The layer kernel's source for `particles` a target (its workgroup array sized to them; the
/// limits were checked for that size, so a source without the line to resize is an error).
fn layer_source(particles: usize) -> Result<String, GpuError> {
    let source = stage_source(sources::LAYER);
    if !source.contains(STAGE_CAPACITY_LINE) {
        return Err(GpuError::Shader {
            kernel: "fused layer".into(),
            message: format!("layer.wgsl has no line `{STAGE_CAPACITY_LINE}` to size"),
        });
    }
    Ok(source.replace(
        STAGE_CAPACITY_LINE,
        &format!("const STAGE_CAPACITY: u32 = {}u;", particles.max(1)),
    ))
}

impl FusedLayers {
    /// The fused layer for this filter where it fits, else why not.
    pub(super) fn where_fits(
        ctx: &GpuContext,
        shape: &BatchShape,
        resampler: GpuResampler,
        streams: &Streams,
        layers: &LayerParams<'_>,
    ) -> Result<(Option<Self>, Option<String>), GpuError> {
        Ok(match fused_layout_refusal(ctx, shape, resampler) {
            None => (
                Some(Self::new(ctx, shape, resampler, streams, layers)?),
                None,
            ),
            Some(why) => (None, Some(why)),
        })
    }

    /// Builds the kernels for `resampler` (systematic or stratified) and binds each layer's
    /// parameter slice of `layer_params` (`stride` bytes apart).
    fn new(
        ctx: &GpuContext,
        shape: &BatchShape,
        resampler: GpuResampler,
        streams: &Streams,
        layers: &LayerParams<'_>,
    ) -> Result<Self, GpuError> {
        let source = layer_source(shape.particles)?;
        let select_entry = if resampler == GpuResampler::Stratified {
            "select_stratified"
        } else {
            "select_systematic"
        };
        let selecting = Kernel::trusted(ctx, "fused select", &source, select_entry)?;
        let moving = Kernel::trusted(ctx, "fused move", &source, "move_selected")?;
        let copying = Kernel::trusted(ctx, "fused copy", &source, "copy_selected")?;
        let selecting_groups = (0..layers.count)
            .map(|layer| bind_selecting(ctx, &selecting, streams, layers, layer))
            .collect::<Result<Vec<_>, _>>()?;
        let moving_groups = (0..layers.count)
            .map(|layer| bind_moving(ctx, &moving, streams, layers, layer))
            .collect::<Result<Vec<_>, _>>()?;
        let copying_group = copying.bind(
            ctx,
            &[
                (0, layers.slice(0)),
                (6, streams.selected.binding()),
                (9, streams.states.binding()),
            ],
        )?;
        let gathering = if layers.count >= 2 {
            Some(GatheringMoves::new(
                ctx,
                &source,
                select_entry,
                streams,
                layers,
                shape.state_len(),
            )?)
        } else {
            None
        };
        let settling = Kernel::trusted(ctx, "fused settle", &source, "settle_last_layer")?;
        let settling_group = settling.bind(
            ctx,
            &[
                (0, layers.slice(layers.count - 1)),
                (2, streams.log_weights.binding()),
                (3, streams.log_likelihood.binding()),
                (4, streams.weights.binding()),
                (5, streams.stats.binding()),
            ],
        )?;
        Ok(Self {
            selecting,
            moving,
            copying,
            selecting_groups,
            moving_groups,
            copying_group,
            settling,
            settling_group,
            select_entry,
            keeping_lineage: None,
            lineage_in_select: lineage_fits_in_select(ctx),
            gathering,
        })
    }

    /// The gathering moves where a step of `likelihood` can take them: not where layer 0
    /// moves by the likelihood's own dynamics (its moved values are not the move's to keep).
    fn gathering_for(&self, likelihood: &dyn GpuLikelihood) -> Option<&GatheringMoves> {
        self.gathering.as_ref().filter(|_| !likelihood.propagates())
    }

    /// From the next step on, composes the lineage in each layer's select where the adapter
    /// binds the storage buffers it takes (`lineage_bindings(layer)`: the lineage's buffers for
    /// that layer, `Lineage::select_bindings`); elsewhere the lineage keeps its own dispatches.
    pub(super) fn keep_lineage<'b>(
        &mut self,
        ctx: &GpuContext,
        shape: &BatchShape,
        streams: &'b Streams,
        layers: &'b LayerParams<'_>,
        lineage_bindings: &dyn Fn(usize) -> [(u32, wgpu::BindingResource<'b>); 3],
    ) -> Result<(), GpuError> {
        if self.keeping_lineage.is_some() || !lineage_fits_in_select(ctx) {
            return Ok(());
        }
        let source = layer_source(shape.particles)?;
        let entry = format!("{}_keeping_lineage", self.select_entry);
        let bind_layers = |kernel: &Kernel| {
            (0..layers.count)
                .map(|layer| {
                    let mut entries = selecting_entries(streams, layers, layer);
                    entries.extend(lineage_bindings(layer));
                    kernel.bind(ctx, &entries)
                })
                .collect::<Result<Vec<_>, _>>()
        };
        let kernel = Kernel::trusted(ctx, "fused select keeping the lineage", &source, &entry)?;
        let groups = bind_layers(&kernel)?;
        let searching = match self.gathering {
            Some(_) => {
                let options = KernelOptions {
                    constants: &[("GATHER", 0.0)],
                    ..KernelOptions::trusted()
                };
                let name = "fused search keeping the lineage";
                let kernel = Kernel::with_options(ctx, name, &source, &entry, options)?;
                let groups = bind_layers(&kernel)?;
                Some((kernel, groups))
            }
            None => None,
        };
        self.keeping_lineage = Some(SelectKeepingLineage {
            kernel,
            groups,
            searching,
        });
        Ok(())
    }

    /// Whether each layer's select composes the lineage (no lineage dispatches).
    pub(super) fn composes_lineage(&self) -> bool {
        self.lineage_in_select && self.keeping_lineage.is_some()
    }

    /// Composes the lineage in the select (`on`, where the adapter binds its buffers) or in
    /// the lineage's own dispatches.
    pub(super) fn set_lineage_in_select(
        &mut self,
        ctx: &GpuContext,
        on: bool,
    ) -> Result<(), GpuError> {
        if on && !lineage_fits_in_select(ctx) {
            return Err(GpuError::InvalidConfig(format!(
                "the select composing the lineage binds {LINEAGE_SELECT_STORAGE_BUFFERS} storage \
                 buffers; the adapter allows {}",
                ctx.limits().max_storage_buffers_per_shader_stage
            )));
        }
        self.lineage_in_select = on;
        Ok(())
    }

    /// Records layer `layer`'s select: the one that composes the lineage where the filter keeps
    /// it (`keeps_lineage`) and it was built; after layer 0, where `gathering` moves gather,
    /// the search alone.
    fn record_select(
        &self,
        pass: &mut wgpu::ComputePass<'_>,
        layer: usize,
        keeps_lineage: bool,
        gathering: Option<&GatheringMoves>,
        grid: [u32; 3],
    ) {
        let composing = self
            .keeping_lineage
            .as_ref()
            .filter(|_| keeps_lineage && self.lineage_in_select);
        match (composing, gathering) {
            (Some(select), Some(_)) if layer > 0 => match &select.searching {
                Some((kernel, groups)) => kernel.record(pass, &groups[layer], grid),
                // Not built: the select that gathers (the gathering move reads its snapshot).
                None => select.kernel.record(pass, &select.groups[layer], grid),
            },
            (None, Some(moves)) if layer > 0 => moves.record_search(pass, layer, grid),
            (Some(select), _) => select.kernel.record(pass, &select.groups[layer], grid),
            (None, _) => self
                .selecting
                .record(pass, &self.selecting_groups[layer], grid),
        }
    }
}

/// Whether the adapter binds the storage buffers of the select that composes the lineage.
fn lineage_fits_in_select(ctx: &GpuContext) -> bool {
    ctx.limits().max_storage_buffers_per_shader_stage >= LINEAGE_SELECT_STORAGE_BUFFERS
}

/// `select_*`'s bind group for `layer` (its parameters and the previous layer's, which it settles).
fn bind_selecting(
    ctx: &GpuContext,
    kernel: &Kernel,
    s: &Streams,
    layers: &LayerParams<'_>,
    layer: usize,
) -> Result<wgpu::BindGroup, GpuError> {
    kernel.bind(ctx, &selecting_entries(s, layers, layer))
}

/// `move_selected`'s bind group for `layer`.
fn bind_moving(
    ctx: &GpuContext,
    kernel: &Kernel,
    s: &Streams,
    layers: &LayerParams<'_>,
    layer: usize,
) -> Result<wgpu::BindGroup, GpuError> {
    let entries = moving_entries(s, layers, layer, (6, s.selected.binding()));
    kernel.bind(ctx, &entries)
}

/// Bytes between two layers' parameter blocks: a block rounded up to the uniform offset
/// alignment.
pub(super) fn layer_stride(ctx: &GpuContext) -> u64 {
    let block = std::mem::size_of::<FrameParams>() as u64;
    block.next_multiple_of(u64::from(ctx.limits().min_uniform_buffer_offset_alignment))
}

impl GpuFilter {
    /// How a whole step is recorded: [`StepLayout::Fused`] by default where it fits and a
    /// target has at most [`FUSED_DEFAULT_MAX_VALUES`] values, else [`StepLayout::Staged`].
    pub fn step_layout(&self) -> StepLayout {
        self.layout
    }

    /// Records whole steps as `layout` from the next step on (the same particles either way);
    /// [`StepLayout::Fused`] is refused, with the reason, where it does not fit.
    pub fn set_step_layout(&mut self, layout: StepLayout) -> Result<(), GpuError> {
        self.forget_prerecorded();
        if let (StepLayout::Fused, Some(why)) = (layout, &self.fused_refusal) {
            return Err(GpuError::InvalidConfig(format!(
                "the fused step does not fit this filter: {why}"
            )));
        }
        self.layout = layout;
        if layout != StepLayout::Fused {
            // Staged steps are not profiled: no stale times from the last fused step.
            self.profiler = None;
        }
        Ok(())
    }

    /// Records a frame's whole step the fused way, in one compute pass (the layers' parameters
    /// written by [`GpuFilter::write_layer_params`] first), the lag window's dispatches last
    /// where the step has them (`lag_step`); with `profiler`, each dispatch in a timed pass of
    /// its own ([`GpuFilter::profile_dispatches`]).
    pub(super) fn record_fused(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        fused: &FusedLayers,
        likelihood: &dyn GpuLikelihood,
        profiler: Option<&mut DispatchProfiler>,
        lag_step: Option<LagStep>,
    ) {
        let grids = Grids::of(&self.shape);
        let per_target = grids.per_target;
        let mut passes = Passes::begin(encoder, profiler, "fused step");
        for layer in 0..self.annealing.layers {
            self.record_fused_layer(&mut passes, fused, likelihood, layer, &grids);
        }
        passes.dispatch(
            || "last normalise".into(),
            |pass| {
                fused
                    .settling
                    .record(pass, &fused.settling_group, per_target)
            },
        );
        passes.dispatch(
            || "estimate".into(),
            |pass| self.record_estimate_into(pass, likelihood),
        );
        if let Some(step) = lag_step {
            self.record_lag_dispatches(&mut passes, step);
        }
        // The pass ends here (a profiled step's timestamps are resolved once the whole step is
        // recorded: `DispatchProfiler::resolve`).
        drop(passes);
        self.record_copies_back(encoder, likelihood);
    }

    /// One layer of the fused step: select, then move (or copy back and the likelihood's own
    /// dynamics, in layer 0 of a likelihood that propagates), the lineage where kept, and the
    /// likelihood's weighing.
    fn record_fused_layer(
        &self,
        passes: &mut Passes<'_>,
        fused: &FusedLayers,
        likelihood: &dyn GpuLikelihood,
        layer: usize,
        grids: &Grids,
    ) {
        let keeps_lineage = self.lineage.is_some();
        let gathering = fused.gathering_for(likelihood);
        let layers = self.annealing.layers;
        passes.dispatch(
            || format!("layer {layer}: select"),
            |pass| fused.record_select(pass, layer, keeps_lineage, gathering, grids.per_target),
        );
        if layer == 0 && likelihood.propagates() {
            passes.dispatch(
                || "layer 0: copy back".into(),
                |pass| {
                    fused
                        .copying
                        .record(pass, &fused.copying_group, grids.per_particle)
                },
            );
            passes.dispatch(
                || "layer 0: the likelihood's dynamics".into(),
                |pass| likelihood.record(LikelihoodPhase::Propagate, pass),
            );
        } else {
            passes.dispatch(
                || format!("layer {layer}: move"),
                |pass| match gathering {
                    Some(moves) => moves.record_move(pass, layer, layers, grids.per_pair),
                    None => fused
                        .moving
                        .record(pass, &fused.moving_groups[layer], grids.per_pair),
                },
            );
        }
        if keeps_lineage && !fused.composes_lineage() {
            passes.dispatch(
                || format!("layer {layer}: lineage"),
                |pass| self.record_lineage(pass, layer),
            );
        }
        passes.dispatch(
            || format!("layer {layer}: likelihood"),
            |pass| likelihood.record(LikelihoodPhase::Measure { layer }, pass),
        );
    }
}

/// The workgroup counts of the fused step's dispatches.
struct Grids {
    /// One workgroup a target (select, settle).
    per_target: [u32; 3],
    /// One invocation a particle (copy back).
    per_particle: [u32; 3],
    /// One invocation a particle and pair of dimensions (move).
    per_pair: [u32; 3],
}

impl Grids {
    fn of(shape: &BatchShape) -> Self {
        let targets = shape.targets as u32;
        let pairs = shape.dims.div_ceil(2);
        Self {
            per_target: [1, targets, 1],
            per_particle: [groups_for(shape.particles, 64), targets, 1],
            per_pair: [groups_for(shape.particles * pairs, 64), targets, 1],
        }
    }
}
