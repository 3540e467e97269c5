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
    NoAdapter {
        /// The adapter-name filter in force (`WGPU_ADAPTER_NAME`), if any.
        filter: Option<String>,
    },

    /// Only software adapters matched, and the options did not allow one.
    #[error(
        "only software adapters were found ({names}): they are far too slow to track with, so they are used only when allowed explicitly (add --allow-software to the streampf command; in Rust, ContextOptions::allow_software) or named with WGPU_ADAPTER_NAME"
    )]
    OnlySoftwareAdapters {
        /// The software adapters found.
        names: String,
    },

    /// The adapter refused to open a device.
    #[error("opening a device on {adapter} failed: {message}")]
    RequestDevice {
        /// The adapter.
        adapter: String,
        /// wgpu's message.
        message: String,
    },

    /// A WGSL kernel failed to parse, validate or build into a pipeline.
    #[error("kernel {kernel} is invalid: {message}")]
    Shader {
        /// The kernel or model.
        kernel: String,
        /// naga's or wgpu's message, with the source location.
        message: String,
    },

    /// wgpu reported a validation error while doing `what`.
    #[error("GPU validation error while {what}: {message}")]
    Validation {
        /// What was being done.
        what: String,
        /// wgpu's message.
        message: String,
    },

    /// The device ran out of memory while doing `what`.
    #[error("the GPU ran out of memory while {what}: {message}")]
    OutOfMemory {
        /// What was being done.
        what: String,
        /// wgpu's message.
        message: String,
    },

    /// A buffer larger than the adapter allows was requested.
    #[error(
        "buffer {label} needs {bytes} bytes, over the adapter's limit of {limit} bytes ({limit_name}); use fewer targets or particles, or split the work across adapters"
    )]
    BufferTooLarge {
        /// The buffer's label.
        label: String,
        /// The size requested.
        bytes: u64,
        /// The adapter's limit.
        limit: u64,
        /// Which of wgpu's limits it is.
        limit_name: &'static str,
    },

    /// Data handed to a device stream has the wrong length.
    #[error("{what}: got {got} elements, expected {expected}")]
    LengthMismatch {
        /// The data.
        what: String,
        /// The length it must have.
        expected: usize,
        /// The length it has.
        got: usize,
    },

    /// The device was lost (driver reset, GPU removed, out of resources).
    #[error("the GPU device was lost: {0}")]
    DeviceLost(String),

    /// Waiting on the GPU took longer than the context's poll timeout.
    #[error("the GPU did not finish within {seconds} s ({what})")]
    Timeout {
        /// What was waited for.
        what: String,
        /// The timeout.
        seconds: u64,
    },

    /// Mapping a buffer for reading back failed.
    #[error("reading back {what} failed: {message}")]
    Readback {
        /// The buffer.
        what: String,
        /// wgpu's message.
        message: String,
    },

    /// A configuration value is out of its domain.
    #[error("invalid configuration: {0}")]
    InvalidConfig(String),

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
