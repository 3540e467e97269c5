//! The particles' lineage through a frame (`pf_core::batch::BatchFilter::lineage`,
//! `pf_gpu::GpuFilter::download_lineage`, `shaders/engine/lineage.wgsl`): each particle's ancestor
//! among the previous frame's particles, every annealing layer's resampling composed.
//!
//! Checked against its definition, not engine against engine: dimension 0 of every particle is
//! set to the particle's own index before each frame and never moves (σ 0, no drift, no bounds,
//! the model does not see it), so after the frame it holds the index of the particle it descends
//! from, whatever the layers did on the way: the lineage must equal it exactly. A target reset
//! between frames has no ancestors in the next frame (`NO_ANCESTOR`), and has them again after.
//! Fresh random configurations: shapes with edge cases, one to four layers of fixed or survival
//! β, systematic and stratified resampling, resampling every step or by ESS; the CPU engine and
//! the GPU's fused and staged steps (the staged one with Metropolis resampling too).

mod common;

use bytemuck::{Pod, Zeroable};
use pf_core::anneal::Annealing;
use pf_core::batch::{BatchConfig, BatchFilter, BatchShape, gaussian_clouds};
use pf_core::plugin::CpuModel;
use pf_core::resample::{Stratified, Systematic};
use pf_core::smooth::ancestry::NO_ANCESTOR;
use pf_gpu::model::{ModelFilter, ModelSource};
use pf_gpu::{GpuResampler, StepLayout};
use proptest::prelude::*;

const FRAMES: usize = 4;
/// The frame before which one target is reset.
const RESET_BEFORE: usize = 2;

/// A Gaussian around the observation of dimensions 1..8: dimension 0 is the particle's label.
const MODEL: &str = "
struct Observation { z: array<f32, 8> }
struct Constants { sigma: f32, unused: f32 }
fn log_likelihood(x: State, o: Observation, c: Constants) -> f32 {
    var z = o.z;
    var sum = 0.0;
    for (var d = 1u; d < min(DIMS, 8u); d++) {
        let e = (x[d] - z[d]) / c.sigma;
        sum += e * e;
    }
    return -0.5 * sum;
}";

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Observed {
    z: [f32; 8],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Constants {
    sigma: f32,
    unused: f32,
}

const CONSTANTS: Constants = Constants {
    sigma: 0.2,
    unused: 0.0,
};

/// The CPU twin of `MODEL`.
struct Labelled;

impl CpuModel<Observed, Constants> for Labelled {
    const PROPAGATES: bool = false;

    fn log_likelihood(&self, x: &[f32], o: &Observed, c: &Constants) -> f32 {
        -0.5 * (1..x.len().min(8))
            .map(|d| ((x[d] - o.z[d]) / c.sigma).powi(2))
            .sum::<f32>()
    }

    fn propagate(&self, _: &[f32], _: &[f32], _: &Constants, _: &mut [f32]) {}
}

#[derive(Debug, Clone)]
struct Case {
    config: BatchConfig,
    stratified: bool,
    reset: usize,
}

fn case() -> impl Strategy<Value = Case> {
    (
        1usize..=4,
        prop_oneof![
            Just(1usize),
            Just(2),
            Just(256),
            Just(257),
            Just(1025),
            3usize..600
        ],
        2usize..=8,
        (1usize..=4, 0.2f32..0.8, any::<bool>()),
        (any::<u64>(), any::<bool>(), any::<bool>(), any::<usize>()),
    )
        .prop_map(
            |(targets, particles, dims, (layers, rate, fixed), (seed, stratified, by_ess, r))| {
                let shape = BatchShape::new(targets, particles, dims).unwrap();
                let mut sigma = vec![0.1; dims];
                sigma[0] = 0.0;
                let mut config = BatchConfig::new(shape, seed, sigma);
                config.annealing = Annealing::survival(layers, rate, 0.7);
                if fixed {
                    let betas = (0..layers).map(|l| 0.3 + 0.2 * l as f32).collect();
                    config.annealing.tempering = pf_core::anneal::Tempering::Fixed(betas);
                }
                if by_ess {
                    config.ess_threshold = 0.5;
                }
                Case {
                    config,
                    stratified,
                    reset: r % targets,
                }
            },
        )
}

fn observations(targets: usize, frame: usize) -> Vec<Observed> {
    (0..targets)
        .map(|t| Observed {
            z: std::array::from_fn(|d| 0.3 * ((t + 2 * d) as f32 * 0.7 + frame as f32).sin()),
        })
        .collect()
}

fn start(shape: &BatchShape) -> Vec<f32> {
    let means = vec![0.0; shape.targets * shape.dims];
    gaussian_clouds(shape, 5, &means, &vec![0.3; shape.dims])
}

/// Dimension 0 of each target's block set to the particles' own indices.
fn label(shape: &BatchShape, states: &mut [f32]) {
    let block = shape.dims * shape.particles;
    for target in states.chunks_mut(block) {
        for (m, v) in target[..shape.particles].iter_mut().enumerate() {
            *v = m as f32;
        }
    }
}

/// The labels the particles carry after a frame (dimension 0 of each target), `[t·M + m]`.
fn carried(shape: &BatchShape, states: &[f32]) -> Vec<u32> {
    let block = shape.dims * shape.particles;
    (states.chunks(block))
        .flat_map(|target| target[..shape.particles].iter().map(|&v| v as u32))
        .collect()
}

/// The lineage `lineage` must be after a frame whose particles carry `labels`: the labels, and
/// no ancestor for every particle of a target reset before it.
fn check(
    shape: &BatchShape,
    lineage: &[u32],
    labels: &[u32],
    reset: Option<usize>,
    what: &str,
) -> Result<(), TestCaseError> {
    let m = shape.particles;
    for t in 0..shape.targets {
        let range = t * m..(t + 1) * m;
        if reset == Some(t) {
            prop_assert!(
                lineage[range].iter().all(|&a| a == NO_ANCESTOR),
                "{what}: target {t} was reset, yet its particles have ancestors"
            );
        } else {
            prop_assert_eq!(
                &lineage[range.clone()],
                &labels[range],
                "{}: target {}",
                what,
                t
            );
        }
    }
    Ok(())
}

fn check_cpu(case: &Case) -> Result<(), TestCaseError> {
    let shape = case.config.shape;
    let states = start(&shape);
    let mut filter = if case.stratified {
        BatchFilterEither::Stratified(BatchFilter::new(&case.config, Stratified, states).unwrap())
    } else {
        BatchFilterEither::Systematic(BatchFilter::new(&case.config, Systematic, states).unwrap())
    };
    for frame in 0..FRAMES {
        let reset = (frame == RESET_BEFORE).then_some(case.reset);
        if let Some(t) = reset {
            let block = shape.dims * shape.particles;
            let fresh = start(&BatchShape::new(1, shape.particles, shape.dims).unwrap());
            filter.reset_target(t, &fresh[..block]);
        }
        label(&shape, filter.states_mut());
        filter.step(&observations(shape.targets, frame));
        let labels = carried(&shape, filter.states_mut());
        check(
            &shape,
            filter.lineage(),
            &labels,
            reset,
            &format!("CPU frame {frame}"),
        )?;
    }
    Ok(())
}

/// The CPU engine with either resampler (the type differs).
enum BatchFilterEither {
    Systematic(BatchFilter<Systematic>),
    Stratified(BatchFilter<Stratified>),
}

impl BatchFilterEither {
    fn states_mut(&mut self) -> &mut Vec<f32> {
        match self {
            Self::Systematic(f) => &mut f.states,
            Self::Stratified(f) => &mut f.states,
        }
    }

    fn step(&mut self, z: &[Observed]) {
        match self {
            Self::Systematic(f) => f.step_model(&Labelled, z, &CONSTANTS).map(drop),
            Self::Stratified(f) => f.step_model(&Labelled, z, &CONSTANTS).map(drop),
        }
        .unwrap();
    }

    fn lineage(&self) -> &[u32] {
        match self {
            Self::Systematic(f) => f.lineage(),
            Self::Stratified(f) => f.lineage(),
        }
    }

    fn reset_target(&mut self, t: usize, states: &[f32]) {
        match self {
            Self::Systematic(f) => f.reset_target(t, states),
            Self::Stratified(f) => f.reset_target(t, states),
        }
        .unwrap();
    }
}

fn check_gpu(
    ctx: &pf_gpu::GpuContext,
    case: &Case,
    resampler: GpuResampler,
    layout: StepLayout,
    in_select: bool,
) -> Result<(), TestCaseError> {
    let shape = case.config.shape;
    let source = ModelSource {
        name: "Labelled",
        wgsl: MODEL,
    };
    let mut filter = ModelFilter::new(
        ctx,
        &case.config,
        resampler,
        &start(&shape),
        source,
        &CONSTANTS,
    )
    .unwrap();
    filter.engine_mut().keep_lineage().unwrap();
    let (_, gpu, _) = filter.gpu_parts().unwrap();
    gpu.set_step_layout(layout).unwrap();
    // The select composing the lineage binds 11 storage buffers; an adapter with fewer refuses
    // it (lavapipe and NVIDIA's allow it, so CI runs it).
    if in_select && ctx.limits().max_storage_buffers_per_shader_stage < 11 {
        prop_assert!(gpu.set_lineage_in_select(ctx, true).is_err());
        return Ok(());
    }
    gpu.set_lineage_in_select(ctx, in_select).unwrap();
    prop_assert_eq!(
        gpu.lineage_in_select(),
        in_select && layout == StepLayout::Fused
    );
    for frame in 0..FRAMES {
        let reset = (frame == RESET_BEFORE).then_some(case.reset);
        if let Some(t) = reset {
            let block = shape.dims * shape.particles;
            let fresh = start(&BatchShape::new(1, shape.particles, shape.dims).unwrap());
            filter.reset_target(t, &fresh[..block]).unwrap();
        }
        let (_, gpu, _) = filter.gpu_parts().unwrap();
        let mut states = gpu.download_states(ctx).unwrap();
        label(&shape, &mut states);
        gpu.streams().states.upload(ctx, &states).unwrap();
        filter.step(&observations(shape.targets, frame)).unwrap();
        let (_, gpu, _) = filter.gpu_parts().unwrap();
        let labels = carried(&shape, &gpu.download_states(ctx).unwrap());
        let lineage = filter.engine().lineage().unwrap().unwrap();
        let what =
            format!("GPU {layout:?} {resampler:?} (lineage in select: {in_select}) frame {frame}");
        check(&shape, &lineage, &labels, reset, &what)?;
        // Read back in one go: the same streams.
        let (_, gpu, _) = filter.gpu_parts().unwrap();
        let together = gpu.download_particles(ctx).unwrap();
        prop_assert_eq!(together.states, gpu.download_states(ctx).unwrap());
        prop_assert_eq!(together.log_weights, gpu.download_log_weights(ctx).unwrap());
        prop_assert_eq!(together.lineage, Some(lineage));
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 16, ..ProptestConfig::default() })]

    #[test]
    fn the_cpu_lineage_names_each_particles_ancestor(case in case()) {
        check_cpu(&case)?;
    }

    #[test]
    fn the_gpu_lineage_names_each_particles_ancestor(case in case()) {
        let Some(ctx) = common::gpu_context("lineage on the GPU") else {
            return Ok(());
        };
        let resampler = if case.stratified {
            GpuResampler::Stratified
        } else {
            GpuResampler::Systematic
        };
        // The fused step composing the lineage in its select, and in dispatches of its own.
        check_gpu(&ctx, &case, resampler, StepLayout::Fused, true)?;
        check_gpu(&ctx, &case, resampler, StepLayout::Fused, false)?;
        check_gpu(&ctx, &case, resampler, StepLayout::Staged, false)?;
        check_gpu(&ctx, &case, GpuResampler::Metropolis(8), StepLayout::Staged, false)?;
    }
}

/// Without asking, a GPU filter keeps no lineage (no dispatches spent on it).
#[test]
fn a_gpu_filter_keeps_no_lineage_unless_asked() {
    let Some(ctx) = common::gpu_context("lineage off by default") else {
        return;
    };
    let shape = BatchShape::new(2, 64, 3).unwrap();
    let config = BatchConfig::new(shape, 1, vec![0.0, 0.1, 0.1]);
    let source = ModelSource {
        name: "Labelled",
        wgsl: MODEL,
    };
    let mut filter = ModelFilter::new(
        &ctx,
        &config,
        GpuResampler::Systematic,
        &start(&shape),
        source,
        &CONSTANTS,
    )
    .unwrap();
    filter.step(&observations(2, 0)).unwrap();
    assert_eq!(filter.engine().lineage().unwrap(), None);
    let (_, gpu, _) = filter.gpu_parts().unwrap();
    assert!(!gpu.keeps_lineage());
}
