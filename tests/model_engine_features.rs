//! What the engine gives a researcher's own model (`pf_gpu::model`), shown on the toy plug-in:
//! annealing layers and the constant-velocity drift (from the `BatchConfig`), two frames in
//! flight (`submit`, `finish`) and the targets sharded over several GPUs
//! (`ShardedModelFilter`). Each is checked against stepping one frame at a time on one GPU:
//! the same random numbers and the same arithmetic give the same bits.

mod common;

use pf_core::anneal::Annealing;
use pf_core::batch::{BatchConfig, BatchShape, Motion, gaussian_clouds};
use pf_gpu::engine::EngineReport;
use pf_gpu::model::{ModelFilter, ShardedModelFilter};
use pf_gpu::toy::{TOY_MODEL, ToyConstants, ToyObservation};
use pf_gpu::{GpuContext, GpuResampler};
use proptest::prelude::*;

const FRAMES: usize = 6;

/// A batch with every engine feature a model can have on: annealing layers, the survival rule,
/// the drift, the best-M′ mean.
fn config(targets: usize, particles: usize, seed: u64) -> BatchConfig {
    let shape = BatchShape::new(targets, particles, 7).unwrap();
    let mut config = BatchConfig::new(shape, seed, vec![0.2; 7]);
    config.angular = vec![false, false, false, true, true, true, false];
    config.annealing = Annealing::survival(3, 0.5, 0.6);
    config.motion = Motion::ConstantVelocity { gain: 0.5 };
    config.best = particles.min(10);
    config
}

/// Target t's observation at `frame`: a point moving steadily, so that the drift matters.
fn observations(targets: usize, frame: usize) -> Vec<ToyObservation> {
    (0..targets)
        .map(|t| ToyObservation {
            z: std::array::from_fn(|d| 0.3 * t as f32 + 0.05 * (frame * (d + 1)) as f32),
        })
        .collect()
}

fn start(config: &BatchConfig) -> Vec<f32> {
    let centres: Vec<f32> = (0..config.shape.targets)
        .flat_map(|t| [0.3 * t as f32; 7])
        .collect();
    gaussian_clouds(&config.shape, 4, &centres, &[0.5; 7])
}

/// The toy plug-in's CPU twin (the angles as `config` has them).
fn toy_twin() -> pf_gpu::toy::ToyTwin {
    pf_gpu::toy::ToyTwin {
        angular: [false, false, false, true, true, true, false],
    }
}

fn constants() -> ToyConstants {
    ToyConstants::from_sigma(&[0.4; 7]).unwrap()
}

/// What a frame's results must agree on, bit for bit.
fn bits(estimates: &[f32], spreads: &[f32], best: &[f32], ess: &[f32]) -> Vec<u32> {
    [estimates, spreads, best, ess]
        .concat()
        .iter()
        .map(|x| x.to_bits())
        .collect()
}

fn report_bits(r: &EngineReport) -> Vec<u32> {
    let ess: Vec<f32> = r.ess.iter().map(|&e| e as f32).collect();
    bits(&r.estimates, &r.spreads, &r.best_estimates, &ess)
}

/// One GPU, one frame at a time: the reference.
fn one_at_a_time(ctx: &GpuContext, config: &BatchConfig) -> Vec<Vec<u32>> {
    let c = constants();
    let mut filter = ModelFilter::new(
        ctx,
        config,
        GpuResampler::Systematic,
        &start(config),
        TOY_MODEL,
        &c,
    )
    .unwrap();
    (0..FRAMES)
        .map(|f| report_bits(&filter.step(&observations(config.shape.targets, f)).unwrap()))
        .collect()
}

#[test]
fn two_frames_in_flight_give_the_bits_of_one_at_a_time() {
    let (Some(ctx),) = (common::gpu_context("model frames in flight"),) else {
        return;
    };
    let config = config(5, 300, 11);
    let want = one_at_a_time(&ctx, &config);
    let c = constants();
    let mut filter = ModelFilter::new(
        &ctx,
        &config,
        GpuResampler::Systematic,
        &start(&config),
        TOY_MODEL,
        &c,
    )
    .unwrap();
    let targets = config.shape.targets;
    let mut got = Vec::new();
    let mut in_flight = std::collections::VecDeque::new();
    for f in 0..FRAMES {
        in_flight.push_back(filter.submit(&observations(targets, f)).unwrap());
        if in_flight.len() == 2 {
            let oldest = in_flight.pop_front().unwrap();
            got.push(report_bits(&filter.finish(oldest).unwrap()));
        }
    }
    while let Some(oldest) = in_flight.pop_front() {
        got.push(report_bits(&filter.finish(oldest).unwrap()));
    }
    assert_eq!(got, want);
    // A third frame in flight is refused, not queued over the second's readback.
    let a = filter.submit(&observations(targets, 0)).unwrap();
    let b = filter.submit(&observations(targets, 1)).unwrap();
    assert!(filter.submit(&observations(targets, 2)).is_err());
    // Nor is a frame stepped at once while others are in flight: it would be waited for out of
    // order; the submitted frames still finish.
    let err = filter.step(&observations(targets, 2)).unwrap_err();
    assert!(err.to_string().contains("in flight"), "{err}");
    filter.finish(a).unwrap();
    filter.finish(b).unwrap();
    filter.step(&observations(targets, 2)).unwrap();
}

proptest! {
    #![proptest_config(common::property::config(4))]

    /// Targets split over two GPU contexts, two frames in flight on each: the one-GPU bits.
    #[test]
    fn targets_sharded_over_two_contexts_give_the_bits_of_one(
        targets in 1usize..9,
        particles in 1usize..400,
        seed in any::<u64>(),
    ) {
        let context = || common::gpu_context("model sharded over two contexts");
        let (Some(one), Some(first), Some(second)) = (context(), context(), context()) else {
            return Ok(());
        };
        let config = config(targets, particles, seed);
        let want = one_at_a_time(&one, &config);
        let mut sharded = ShardedModelFilter::new(
            vec![first, second],
            &config,
            GpuResampler::Systematic,
            &start(&config),
            TOY_MODEL,
            &constants(),
        )
        .unwrap();
        prop_assert_eq!(sharded.shards().count(), targets.min(2));
        let mut got = Vec::new();
        let mut in_flight = std::collections::VecDeque::new();
        for f in 0..FRAMES {
            in_flight.push_back(sharded.submit(&observations(targets, f)).unwrap());
            if in_flight.len() == 2 {
                let r = sharded.finish(in_flight.pop_front().unwrap()).unwrap();
                got.push(report_bits(&r));
            }
        }
        while let Some(oldest) = in_flight.pop_front() {
            let r = sharded.finish(oldest).unwrap();
            got.push(report_bits(&r));
        }
        prop_assert_eq!(got, want);
    }
}

/// A target restarted and set moving (`set_target_motion`, angles among its values) in a filter
/// sharded over two contexts: the bits of one GPU doing the same; a target beyond the batch is
/// refused.
#[test]
fn a_target_set_moving_in_a_sharded_filter_moves_as_on_one_gpu() {
    let context = || common::gpu_context("a target set moving, sharded");
    let (Some(one), Some(first), Some(second)) = (context(), context(), context()) else {
        return;
    };
    let config = config(3, 120, 9);
    let block = gaussian_clouds(
        &BatchShape::new(1, 120, 7).unwrap(),
        6,
        &[0.4; 7],
        &[0.1; 7],
    );
    let (estimate, motion) = ([0.4f32; 7], [0.05f32, 0.1, 0.15, 0.2, 6.5, -0.25, 0.0]);
    let mut single = ModelFilter::new(
        &one,
        &config,
        GpuResampler::Systematic,
        &start(&config),
        TOY_MODEL,
        &constants(),
    )
    .unwrap();
    let mut sharded = ShardedModelFilter::new(
        vec![first, second],
        &config,
        GpuResampler::Systematic,
        &start(&config),
        TOY_MODEL,
        &constants(),
    )
    .unwrap();
    let (mut want, mut got) = (Vec::new(), Vec::new());
    for f in 0..4 {
        if f == 2 {
            single.reset_target(2, &block).unwrap();
            single.set_target_motion(2, &estimate, &motion).unwrap();
            sharded.reset_target(2, &block).unwrap();
            sharded.set_target_motion(2, &estimate, &motion).unwrap();
        }
        want.push(report_bits(&single.step(&observations(3, f)).unwrap()));
        got.push(report_bits(&sharded.step(&observations(3, f)).unwrap()));
    }
    assert_eq!(got, want);
    assert!(sharded.set_target_motion(3, &estimate, &motion).is_err());
}

#[test]
fn a_sharded_filter_checks_what_it_is_given() {
    let (Some(a), Some(b)) = (
        common::gpu_context("model sharded errors"),
        common::gpu_context("model sharded errors"),
    ) else {
        return;
    };
    let config = config(3, 50, 1);
    let none = ShardedModelFilter::<ToyObservation, ToyConstants>::new(
        Vec::new(),
        &config,
        GpuResampler::Systematic,
        &start(&config),
        TOY_MODEL,
        &constants(),
    );
    assert!(none.is_err(), "no contexts");
    let short = ShardedModelFilter::<ToyObservation, ToyConstants>::new(
        vec![a],
        &config,
        GpuResampler::Systematic,
        &start(&config)[1..],
        TOY_MODEL,
        &constants(),
    );
    assert!(short.is_err(), "initial states one short");
    let mut filter = ShardedModelFilter::new(
        vec![b],
        &config,
        GpuResampler::Systematic,
        &start(&config),
        TOY_MODEL,
        &constants(),
    )
    .unwrap();
    let err = filter.step(&observations(2, 0)).err().unwrap();
    assert!(err.to_string().contains("observations"), "{err}");
    assert!(filter.reset_target(3, &vec![0.0; 7 * 50]).is_err());
    filter.reset_target(2, &vec![0.0; 7 * 50]).unwrap();
}

/// One filter type runs a plug-in on either engine (`Plugin`: the WGSL with its CPU twin). On
/// the CPU engine it is the twin's own step (`BatchFilter::step_model`), bit for bit, with every
/// engine feature on; on a GPU a frame from the same particles gives the CPU's estimates within
/// the tolerance policy (`agrees`: the same random numbers, f32 sums on the GPU). One layer
/// there: the survival rule's β bisection may part in the last bits between f32 and f64.
#[test]
fn a_plugin_runs_on_either_engine_through_one_filter() {
    use pf_core::batch::BatchFilter;
    use pf_core::resample::{ResamplerKind, Systematic};
    use pf_gpu::engine::Filter;
    use pf_gpu::model::Plugin;

    let config = config(4, 200, 5);
    let twin = toy_twin;
    let model = Plugin::cpu(twin(), constants());
    let mut on_cpu =
        Filter::on_cpu(&config, ResamplerKind::Systematic, start(&config), model).unwrap();
    let mut reference = BatchFilter::new(&config, Systematic, start(&config)).unwrap();
    for f in 0..FRAMES {
        let seen = observations(4, f);
        let a = on_cpu.step(&seen).unwrap();
        let b = reference.step_model(&twin(), &seen, &constants()).unwrap();
        let ess: Vec<f32> = b.ess.iter().map(|&e| e as f32).collect();
        assert_eq!(
            report_bits(&a),
            bits(&b.estimates, &b.spreads, &b.best_estimates, &ess),
            "frame {f}"
        );
    }
    // A frame of the wrong length is refused before a particle moves.
    let before = on_cpu.particles().unwrap();
    let err = on_cpu.step(&observations(3, 0)).unwrap_err();
    assert!(err.to_string().contains("observations"), "{err}");
    assert_eq!(on_cpu.particles().unwrap(), before);

    let Some(ctx) = common::gpu_context("a plug-in on either engine") else {
        return;
    };
    let mut one_layer = config.clone();
    one_layer.annealing = Annealing::none();
    let model = Plugin::gpu(&ctx, TOY_MODEL, &config.shape, twin(), constants()).unwrap();
    let mut on_gpu = Filter::on_gpu(
        ctx.clone(),
        &one_layer,
        GpuResampler::Systematic,
        &start(&config),
        model,
    )
    .unwrap();
    let gpu = on_gpu.step(&observations(4, 0)).unwrap();
    let model = Plugin::cpu(twin(), constants());
    let mut on_cpu =
        Filter::on_cpu(&one_layer, ResamplerKind::Systematic, start(&config), model).unwrap();
    let cpu = on_cpu.step(&observations(4, 0)).unwrap();
    for (i, (g, c)) in gpu.estimates.iter().zip(&cpu.estimates).enumerate() {
        assert!(
            pf_gpu::model::agrees(f64::from(*g), f64::from(*c)),
            "estimate {i}: GPU {g} vs CPU {c}"
        );
    }
    // A model built for the CPU cannot weigh on a GPU: a clear error, not a silent flat step.
    let cpu_only = Plugin::cpu(twin(), constants());
    let mut wrong = Filter::on_gpu(
        ctx,
        &config,
        GpuResampler::Systematic,
        &start(&config),
        cpu_only,
    )
    .unwrap();
    let err = wrong.step(&observations(4, 0)).unwrap_err();
    assert!(err.to_string().contains("Plugin::gpu"), "{err}");
}

/// Samples as islands over GPU contexts (`Islands`), for a plug-in: one island is the plain
/// filter, bit for bit (island 0 keeps the seed); two islands track the toy's moving point,
/// each target's island weights sum to 1, they exchange on the frames due, and a wrong number
/// of island log-weights is an error.
#[test]
fn a_plugin_runs_as_islands_over_two_contexts() {
    use pf_core::plugin::CpuModel;
    use pf_gpu::engine::Islands;
    use pf_gpu::model::Plugin;

    let (Some(a), Some(b), Some(c)) = (
        common::gpu_context("islands a"),
        common::gpu_context("islands b"),
        common::gpu_context("islands c"),
    ) else {
        return;
    };
    let targets = 3;
    let config = config(targets, 400, 7);
    let twin = toy_twin;
    let model = |ctx: &GpuContext, island: &BatchConfig| {
        Plugin::gpu(ctx, TOY_MODEL, &island.shape, twin(), constants())
    };
    // Each island weighed by the likelihood of its estimate, as the body tracker's are.
    let weigh = |obs: &[ToyObservation], r: &EngineReport| -> Result<Vec<f64>, pf_gpu::GpuError> {
        Ok((0..targets)
            .map(|t| {
                let x = &r.point_estimates()[t * 7..(t + 1) * 7];
                f64::from(twin().log_likelihood(x, &obs[t], &constants()))
            })
            .collect())
    };

    let mut one =
        Islands::on_gpus(vec![a], &config, GpuResampler::Systematic, start, model, 0).unwrap();
    let mut plain = ModelFilter::new(
        &c,
        &config,
        GpuResampler::Systematic,
        &start(&config),
        TOY_MODEL,
        &constants(),
    )
    .unwrap();
    for f in 0..FRAMES {
        let obs = observations(targets, f);
        let island = one.step(&obs, |_, r| weigh(&obs, r)).unwrap();
        let alone = plain.step(&obs).unwrap();
        assert_eq!(
            report_bits(&island.islands[0]),
            report_bits(&alone),
            "frame {f}"
        );
        assert!(island.combined.weights.iter().all(|&w| w == 1.0));
    }

    let contexts = vec![b, c];
    let mut two =
        Islands::on_gpus(contexts, &config, GpuResampler::Systematic, start, model, 2).unwrap();
    assert_eq!(two.filters().len(), 2);
    assert_eq!(two.filters()[1].shape().particles, 200);
    for f in 0..FRAMES {
        let obs = observations(targets, f);
        let report = two.step(&obs, |_, r| weigh(&obs, r)).unwrap();
        assert_eq!(report.exchanged.is_some(), (f + 1) % 2 == 0, "frame {f}");
        for (t, seen) in obs.iter().enumerate() {
            let w = &report.combined.weights[t * 2..t * 2 + 2];
            assert!(
                (w[0] + w[1] - 1.0).abs() < 1e-9,
                "frame {f} target {t}: {w:?}"
            );
            for d in 0..7 {
                let error = (report.combined.estimates[t * 7 + d] - seen.z[d]).abs();
                assert!(
                    error < 0.5,
                    "frame {f} target {t} dimension {d}: off by {error}"
                );
            }
        }
    }
    let (states, log_weights) = two.particles().unwrap();
    assert_eq!(
        (states.len(), log_weights.len()),
        (targets * 7 * 400, targets * 400)
    );
    let obs = observations(targets, FRAMES);
    let err = two
        .step(&obs, |_, _| Ok(vec![0.0; targets - 1]))
        .unwrap_err();
    assert!(err.to_string().contains("island log-weights"), "{err}");
}

/// Sharding is the engine's, for any model whose frame is per-target values: a `Plugin` (a WGSL
/// model with its CPU twin) split over two contexts steps as on one GPU, bit for bit.
#[test]
fn any_model_with_per_target_frames_shards_over_contexts() {
    use pf_gpu::engine::{Filter, Sharded};
    use pf_gpu::model::Plugin;

    let (Some(a), Some(b), Some(c)) = (
        common::gpu_context("sharded plug-in a"),
        common::gpu_context("sharded plug-in b"),
        common::gpu_context("sharded plug-in c"),
    ) else {
        return;
    };
    let config = config(5, 200, 13);
    let twin = toy_twin;
    let model = |ctx: &GpuContext, part: &BatchConfig| {
        Plugin::gpu(ctx, TOY_MODEL, &part.shape, twin(), constants())
    };
    let systematic = GpuResampler::Systematic;
    let mut sharded =
        Sharded::on_gpus(vec![a, b], &config, systematic, &start(&config), model).unwrap();
    assert_eq!(sharded.shards().count(), 2);
    let whole = model(&c, &config).unwrap();
    let mut one = Filter::on_gpu(c, &config, systematic, &start(&config), whole).unwrap();
    for f in 0..FRAMES {
        let seen = observations(5, f);
        let got = sharded.step(&seen).unwrap();
        let want = one.step(&seen).unwrap();
        assert_eq!(report_bits(&got), report_bits(&want), "frame {f}");
    }
    let err = sharded.step(&observations(5, 0)[..3]).unwrap_err();
    assert!(err.to_string().contains("observations"), "{err}");
}
