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
