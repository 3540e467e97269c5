//! The one error type of pf-gpu.

use thiserror::Error;

/// Shown whenever no adapter is found: what to install, per platform.
pub const NO_ADAPTER_HELP: &str = "no GPU adapter was found. On Debian/Ubuntu without a GPU, install Mesa's software \
Vulkan driver (lavapipe): `sudo apt-get install mesa-vulkan-drivers libvulkan1`; \
with an NVIDIA GPU, install the driver's Vulkan ICD. `cargo xtask test` installs lavapipe \
when it runs as root. WGPU_BACKEND (vulkan, gl, metal, dx12) and WGPU_ADAPTER_NAME narrow the choice";

/// Everything that can go wrong in the GPU runtime.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum GpuError {
    /// No adapter matched (or none exists).
    #[error("{NO_ADAPTER_HELP}{}", filter_note(.filter))]
    NoAdapter { filter: Option<String> },

    /// A lower pf-core error surfaced through a GPU stage.
    #[error(transparent)]
    Core(#[from] pf_core::PfError),
}

fn filter_note(filter: &Option<String>) -> String {
    match filter {
        Some(f) => format!(" (none matched {f})"),
        None => String::new(),
    }
}
