//! The shared helper of the GPU tests.
//!
//! A GPU test never passes silently for lack of an adapter: [`require_gpu`] fails the test with a
//! message that says how to get one, unless the run opts out explicitly with
//! `STREAMPF_ALLOW_NO_GPU=1`, in which case it returns `None` and says so on stderr.

#![allow(dead_code)]

pub mod capsule_cases;
pub mod media;
pub mod property;

/// The environment variable that lets a run without any adapter skip the GPU tests.
pub const OPT_OUT: &str = "STREAMPF_ALLOW_NO_GPU";

/// The adapters of this machine, or the opt-out.
pub fn require_gpu(test: &str) -> Option<Vec<pf_gpu::AdapterSummary>> {
    match pf_gpu::list_adapters() {
        Ok(adapters) => Some(adapters),
        Err(err) if std::env::var(OPT_OUT).is_ok_and(|v| v == "1") => {
            eprintln!("{test}: SKIPPED, no GPU adapter and {OPT_OUT}=1 ({err})");
            None
        }
        Err(err) => panic!(
            "{test} needs a GPU adapter: {err}.\nSet {OPT_OUT}=1 to skip the GPU tests explicitly."
        ),
    }
}

/// A GPU context for tests: the software adapter first, validation on, a generous timeout.
/// `None` only when the run opted out and there is no adapter.
pub fn gpu_context(test: &str) -> Option<pf_gpu::GpuContext> {
    require_gpu(test)?;
    match pf_gpu::GpuContext::new(&pf_gpu::ContextOptions::for_tests()) {
        Ok(ctx) => Some(ctx),
        Err(err) => panic!("{test}: opening the GPU failed: {err}"),
    }
}
