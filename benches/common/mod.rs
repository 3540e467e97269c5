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
