//! GPU step timing: timestamps where the adapter has them, wall clock otherwise; either way a
//! positive duration no longer than the host saw the step take.

mod common;

use pf_core::batch::{BatchConfig, BatchShape};
use pf_gpu::{GpuFilter, GpuResampler, GpuTime, NoLikelihood};

#[test]
fn step_time_is_positive_and_within_the_host_wall_clock() {
    let Some(ctx) = common::gpu_context("step_time") else {
        return;
    };
    let shape = BatchShape::new(4, 500, 7).unwrap();
    let config = BatchConfig {
        shape,
        seed: 9,
        sigma: vec![0.1; 7],
        bounds: None,
        angular: vec![false; 7],
        ess_threshold: f64::INFINITY,
        best: 50,
        annealing: Default::default(),
        motion: Default::default(),
    };
    let mut filter = GpuFilter::new(
        &ctx,
        &config,
        GpuResampler::Systematic,
        &vec![0.0; shape.state_len()],
    )
    .unwrap();
    for _ in 0..3 {
        let started = std::time::Instant::now();
        let report = filter.step(&ctx, &NoLikelihood).unwrap();
        let host = started.elapsed();
        let gpu = report.time.duration();
        assert!(gpu > std::time::Duration::ZERO, "{:?}", report.time);
        assert!(
            gpu <= host,
            "{} {:?} exceeds the host's {host:?}",
            report.time.source(),
            gpu
        );
        assert_eq!(
            matches!(report.time, GpuTime::Timestamps(_)),
            ctx.has_timestamps()
        );
    }
}

/// The toy plug-in's filter: `targets` targets of 300 particles in 7 values, three survival-rule
/// annealing layers, the fused layout.
fn toy_plugin(
    ctx: &pf_gpu::GpuContext,
    targets: usize,
) -> pf_gpu::model::ModelFilter<pf_gpu::toy::ToyObservation, pf_gpu::toy::ToyConstants> {
    use pf_core::anneal::Annealing;
    let shape = BatchShape::new(targets, 300, 7).unwrap();
    let mut config = BatchConfig::new(shape, 5, vec![0.5; 7]);
    config.annealing = Annealing::survival(3, 0.5, 0.7);
    let means: Vec<f32> = (0..targets * 7).map(|i| i as f32).collect();
    let initial = pf_core::batch::gaussian_clouds(&shape, 3, &means, &[1.0; 7]);
    let constants = pf_gpu::toy::ToyConstants::from_sigma(&[1.0; 7]).unwrap();
    let mut filter = pf_gpu::model::ModelFilter::new(
        ctx,
        &config,
        GpuResampler::Systematic,
        &initial,
        pf_gpu::toy::TOY_MODEL,
        &constants,
    )
    .unwrap();
    let (_, gpu, _) = filter.gpu_parts().unwrap();
    gpu.set_step_layout(pf_gpu::StepLayout::Fused).unwrap();
    filter
}

#[test]
fn a_profiled_fused_step_names_and_times_each_dispatch_and_keeps_its_particles() {
    let Some(ctx) = common::gpu_context("dispatch_profile") else {
        return;
    };
    let targets = 3;
    let observations: Vec<_> = (0..targets)
        .map(|t| pf_gpu::toy::ToyObservation {
            z: std::array::from_fn(|d| (t * 7 + d) as f32 + 0.3),
        })
        .collect();
    let mut plain = toy_plugin(&ctx, targets);
    let mut profiled = toy_plugin(&ctx, targets);
    let (ctx_p, gpu, _) = profiled.gpu_parts().unwrap();
    if !ctx.has_timestamps() {
        let refusal = gpu.profile_dispatches(ctx_p, true).unwrap_err();
        assert!(refusal.to_string().contains("timestamp"), "{refusal}");
        return;
    }
    gpu.profile_dispatches(ctx_p, true).unwrap();
    for _ in 0..3 {
        let expected = plain.step(&observations).unwrap();
        let got = profiled.step(&observations).unwrap();
        // Only the passes' boundaries differ: the same particles and weights, hence the same
        // estimates.
        assert_eq!(got.estimates, expected.estimates);
        let (ctx_a, gpu_a, _) = plain.gpu_parts().unwrap();
        let (states_a, weights_a) = (
            gpu_a.download_states(ctx_a).unwrap(),
            gpu_a.download_log_weights(ctx_a).unwrap(),
        );
        let (ctx_p, gpu, _) = profiled.gpu_parts().unwrap();
        assert_eq!(gpu.download_states(ctx_p).unwrap(), states_a);
        assert_eq!(gpu.download_log_weights(ctx_p).unwrap(), weights_a);
        let times = gpu.dispatch_times(ctx_p).unwrap();
        let labels: Vec<&str> = times.iter().map(|t| t.label.as_str()).collect();
        assert_eq!(
            labels,
            [
                "layer 0: select",
                "layer 0: move",
                "layer 0: likelihood",
                "layer 1: select",
                "layer 1: move",
                "layer 1: likelihood",
                "layer 2: select",
                "layer 2: move",
                "layer 2: likelihood",
                "last normalise",
                "estimate",
            ]
        );
        let end = times.iter().map(|t| t.start + t.duration).max().unwrap();
        assert!(end > std::time::Duration::ZERO, "{times:?}");
        assert!(times.iter().all(|t| t.start <= end), "{times:?}");
    }
    // Profiling off: no dispatches reported, and a staged step is refused profiling.
    let (ctx_p, gpu, _) = profiled.gpu_parts().unwrap();
    gpu.profile_dispatches(ctx_p, false).unwrap();
    assert!(gpu.dispatch_times(ctx_p).unwrap().is_empty());
    gpu.set_step_layout(pf_gpu::StepLayout::Staged).unwrap();
    let refusal = gpu.profile_dispatches(ctx_p, true).unwrap_err();
    assert!(refusal.to_string().contains("fused"), "{refusal}");
}

/// Reading a copy back as it lands (`PendingMap::wait_as_it_lands`, polling before the blocking
/// wait) gives the copied values, for freshly drawn ones: a map is not reported arrived before a
/// poll delivers it, polling alone delivers it, and the spinning wait and the blocking one read
/// the same bytes.
#[test]
fn a_readback_read_as_it_lands_holds_the_copied_values() {
    let Some(ctx) = common::gpu_context("wait_as_it_lands") else {
        return;
    };
    let seed = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(7, |d| d.as_nanos() as u64);
    for round in 0..4u64 {
        let len = 1 + ((seed >> (8 * round)) % 5000) as usize;
        let values: Vec<u32> = (0..len as u64)
            .map(|i| (i ^ seed.rotate_left(round as u32 * 7)) as u32)
            .collect();
        let source = pf_gpu::stream::DeviceStream::from_slice(&ctx, "values", &values).unwrap();
        let readback = pf_gpu::stream::Readback::<u32>::new(&ctx, "values back", len).unwrap();
        let copy = || {
            let mut encoder = ctx
                .device
                .create_command_encoder(&pf_gpu::wgpu::CommandEncoderDescriptor { label: None });
            readback.record_copy(&mut encoder, &source);
            ctx.queue.submit([encoder.finish()])
        };
        // Polling alone delivers the map.
        copy();
        let mut pending = readback.request_map();
        assert!(!pending.arrived(), "seed {seed}: arrived before any poll");
        let started = std::time::Instant::now();
        while !pending.arrived() {
            assert!(
                started.elapsed().as_secs() < 60,
                "seed {seed}: never mapped"
            );
            ctx.device.poll(pf_gpu::wgpu::PollType::Poll).unwrap();
        }
        assert_eq!(readback.collect(pending).unwrap(), values, "seed {seed}");
        // The spinning wait (a long spin, so that it is what finds the map here too).
        let submission_2 = copy();
        let mut pending = readback.request_map();
        pending
            .wait_polling_for(
                &ctx,
                submission_2,
                "the copy",
                std::time::Duration::from_secs(60),
            )
            .unwrap();
        assert_eq!(readback.collect(pending).unwrap(), values, "seed {seed}");
        // The adapter's own choice, and the blocking wait.
        let submission_3 = copy();
        let mut pending = readback.request_map();
        pending
            .wait_as_it_lands(&ctx, submission_3, "the copy")
            .unwrap();
        assert_eq!(readback.collect(pending).unwrap(), values, "seed {seed}");
        assert_eq!(readback.read(&ctx, None).unwrap(), values, "seed {seed}");
    }
}
