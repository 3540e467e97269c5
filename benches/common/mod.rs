//! Shared set-up of the GPU benchmarks.

#![allow(dead_code)]

use pf_gpu::{ContextOptions, GpuContext};

/// The machine's GPU (a hardware adapter first, else any, such as lavapipe under
/// `cargo test --benches`), named on stderr so that every table says where it came from.
pub fn context() -> GpuContext {
    let ctx = GpuContext::new(&ContextOptions::default())
        .or_else(|_| GpuContext::new(&ContextOptions::for_tests()))
        .expect("a GPU adapter (see `streampf devices`)");
    eprintln!(
        "GPU adapter: {} ({}, {})",
        ctx.adapter().name,
        ctx.adapter().device_type,
        ctx.adapter().backend
    );
    ctx
}

/// Prints where a profiled step's GPU time goes (`pf_gpu::GpuFilter::profile_dispatches`):
/// for each dispatch, the median over 50 steps of its start (from the step's first pass) and
/// of its own time, then the sum of the dispatches' own times against the whole span.
/// `profiled_step` runs one step and returns its dispatches (`None` to leave a step out).
pub fn report_dispatch_profile(
    what: &str,
    mut profiled_step: impl FnMut() -> Option<Vec<pf_gpu::DispatchTime>>,
) {
    let steps: Vec<Vec<pf_gpu::DispatchTime>> = (0..50).filter_map(|_| profiled_step()).collect();
    let Some(first) = steps.first() else {
        eprintln!("{what}: no profiled steps");
        return;
    };
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let us = |d: std::time::Duration| d.as_secs_f64() * 1e6;
    let mut own_sum = 0.0;
    eprintln!("{what}: dispatches (median of {} steps)", steps.len());
    for (k, dispatch) in first.iter().enumerate() {
        let of = |f: &dyn Fn(&pf_gpu::DispatchTime) -> f64| {
            median(steps.iter().filter_map(|s| s.get(k)).map(f).collect())
        };
        let start = of(&|d| us(d.start));
        let own = of(&|d| us(d.duration));
        own_sum += own;
        eprintln!(
            "  {:<40} starts {start:8.1} us, takes {own:7.1} us",
            dispatch.label
        );
    }
    let span = median(
        steps
            .iter()
            .filter_map(|s| s.last().map(|d| us(d.start + d.duration)))
            .collect(),
    );
    eprintln!("  dispatches' own times {own_sum:.1} us of a {span:.1} us span");
}
