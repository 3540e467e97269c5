//! The GPU context: one adapter, its device and queue, opened with the adapter's real limits.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use crate::adapters::{AdapterSummary, instance_from_env};
use crate::error::GpuError;

/// How to choose and open an adapter.
#[derive(Debug, Clone)]
pub struct ContextOptions {
    /// High performance by default: a discrete GPU before an integrated one.
    pub power_preference: wgpu::PowerPreference,
    /// Accept a software adapter (Mesa's lavapipe). Off by default: a tracker on lavapipe is
    /// correct but far too slow, so it must be asked for.
    pub allow_software: bool,
    /// Rank software adapters first (tests: the same adapter on every machine).
    pub prefer_software: bool,
    /// How long a wait on the GPU may take before it is a [`GpuError::Timeout`].
    pub poll_timeout: Duration,
    /// Only adapters whose name contains this (case-insensitive); `WGPU_ADAPTER_NAME` by default.
    pub adapter_name: Option<String>,
    /// Build every kernel with wgpu's runtime checks, the project's own too (which are otherwise
    /// built without: [`crate::kernels::ShaderChecks::Trusted`]): for a kernel suspected of
    /// indexing past an array, whose reads are then clamped into it. On by default when
    /// `STREAMPF_CHECK_KERNELS=1`.
    pub check_every_kernel: bool,
    /// Build a plug-in model's kernels ([`crate::model`]: the WGSL a researcher writes) without
    /// wgpu's runtime checks too, as the project's own are. Off by default: only for a model
    /// whose indices stay in range and whose loops end, which its check against its CPU twin
    /// ([`crate::model::check_against_cpu`]) on random particles, edges included, is there to
    /// find out (docs/BENCHMARKS.md, "Trusted kernels", has what it saved the toy plug-in).
    /// [`Self::check_every_kernel`] wins.
    pub trust_model_kernels: bool,
}

/// The environment variable that turns [`ContextOptions::check_every_kernel`] on by default.
pub const CHECK_KERNELS_VAR: &str = "STREAMPF_CHECK_KERNELS";

impl Default for ContextOptions {
    fn default() -> Self {
        Self {
            power_preference: wgpu::PowerPreference::HighPerformance,
            allow_software: false,
            prefer_software: false,
            poll_timeout: Duration::from_secs(60),
            adapter_name: std::env::var("WGPU_ADAPTER_NAME").ok(),
            check_every_kernel: std::env::var_os(CHECK_KERNELS_VAR).is_some_and(|v| v == "1"),
            trust_model_kernels: false,
        }
    }
}

impl ContextOptions {
    /// Tests: the software adapter first (any adapter when there is none), and a generous
    /// timeout, since lavapipe is slow.
    pub fn for_tests() -> Self {
        Self {
            allow_software: true,
            prefer_software: true,
            poll_timeout: Duration::from_secs(600),
            ..Self::default()
        }
    }
}

/// An open device on one adapter. A clone is another handle to the same device and queue (wgpu's
/// handles are reference-counted), so a filter can own its context while its caller keeps one.
#[derive(Clone)]
pub struct GpuContext {
    /// The wgpu device.
    pub device: wgpu::Device,
    /// The device's queue.
    pub queue: wgpu::Queue,
    summary: AdapterSummary,
    limits: wgpu::Limits,
    timestamps: bool,
    check_every_kernel: bool,
    trust_model_kernels: bool,
    /// Whether the device runs on Vulkan, whose robust buffer access bounds storage buffers
    /// whatever a kernel's checks (the only backend whose kernels are built trusted).
    vulkan: bool,
    lost: Arc<Mutex<Option<String>>>,
    poll_timeout: Duration,
}

impl std::fmt::Debug for GpuContext {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuContext")
            .field("adapter", &self.summary)
            .field("timestamps", &self.timestamps)
            .finish_non_exhaustive()
    }
}

/// Adapters that pass the name filter (`WGPU_ADAPTER_NAME`), best first for `options`.
fn ranked_adapters(options: &ContextOptions) -> Result<Vec<wgpu::Adapter>, GpuError> {
    let instance = instance_from_env();
    let backends = wgpu::Backends::from_env().unwrap_or(wgpu::Backends::PRIMARY);
    let name_filter = options.adapter_name.clone();
    let mut adapters: Vec<wgpu::Adapter> =
        pollster::block_on(instance.enumerate_adapters(backends))
            .into_iter()
            .filter(|a| {
                name_filter
                    .as_ref()
                    .is_none_or(|f| a.get_info().name.to_lowercase().contains(&f.to_lowercase()))
            })
            .collect();
    if adapters.is_empty() {
        return Err(GpuError::NoAdapter {
            filter: name_filter.map(|n| format!("adapter name {n:?}")),
        });
    }
    // A software adapter named explicitly counts as asked for.
    let allow_software = options.allow_software || name_filter.is_some();
    let rank = |a: &wgpu::Adapter| {
        let kind = a.get_info().device_type;
        let software = kind == wgpu::DeviceType::Cpu;
        if options.prefer_software && software {
            return 0;
        }
        match (kind, options.power_preference) {
            (wgpu::DeviceType::IntegratedGpu, wgpu::PowerPreference::LowPower) => 1,
            (wgpu::DeviceType::DiscreteGpu, _) => 2,
            (wgpu::DeviceType::IntegratedGpu, _) => 3,
            (wgpu::DeviceType::VirtualGpu, _) => 4,
            (wgpu::DeviceType::Other, _) => 5,
            (wgpu::DeviceType::Cpu, _) => 6,
        }
    };
    adapters.sort_by_key(|a| rank(a));
    if !allow_software {
        let names: Vec<String> = adapters.iter().map(|a| a.get_info().name).collect();
        adapters.retain(|a| a.get_info().device_type != wgpu::DeviceType::Cpu);
        if adapters.is_empty() {
            return Err(GpuError::OnlySoftwareAdapters {
                names: names.join(", "),
            });
        }
    }
    Ok(adapters)
}

impl GpuContext {
    /// Opens the best adapter for `options`.
    pub fn new(options: &ContextOptions) -> Result<Self, GpuError> {
        let adapter = ranked_adapters(options)?
            .into_iter()
            .next()
            .ok_or(GpuError::NoAdapter { filter: None })?;
        Self::open(adapter, options)
    }

    /// Opens every adapter that `options` admits (for splitting work across GPUs).
    pub fn all(options: &ContextOptions) -> Result<Vec<Self>, GpuError> {
        ranked_adapters(options)?
            .into_iter()
            .map(|a| Self::open(a, options))
            .collect()
    }

    /// Opens a device on `adapter` with the adapter's own limits (wgpu's defaults would cap a
    /// storage buffer at 128 MiB) and timestamp queries where the adapter has them.
    pub fn open(adapter: wgpu::Adapter, options: &ContextOptions) -> Result<Self, GpuError> {
        let info = adapter.get_info();
        let summary = AdapterSummary::from_info(&info);
        let limits = adapter.limits();
        let wanted =
            wgpu::Features::TIMESTAMP_QUERY | wgpu::Features::TIMESTAMP_QUERY_INSIDE_ENCODERS;
        let features = adapter.features() & wanted;
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("streampf"),
            required_features: features,
            required_limits: limits.clone(),
            experimental_features: wgpu::ExperimentalFeatures::disabled(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        }))
        .map_err(|e| GpuError::RequestDevice {
            adapter: info.name.clone(),
            message: e.to_string(),
        })?;
        let lost = Arc::new(Mutex::new(None));
        let lost_flag = Arc::clone(&lost);
        device.set_device_lost_callback(move |reason, message| {
            if let Ok(mut slot) = lost_flag.lock() {
                *slot = Some(format!("{reason:?}: {message}"));
            }
        });
        Ok(Self {
            device,
            queue,
            summary,
            limits,
            timestamps: features.contains(wanted),
            check_every_kernel: options.check_every_kernel,
            trust_model_kernels: options.trust_model_kernels,
            vulkan: info.backend == wgpu::Backend::Vulkan,
            lost,
            poll_timeout: options.poll_timeout,
        })
    }

    /// The adapter the device runs on.
    pub fn adapter(&self) -> &AdapterSummary {
        &self.summary
    }

    /// The limits the device was opened with (the adapter's own).
    pub fn limits(&self) -> &wgpu::Limits {
        &self.limits
    }

    /// Whether GPU timings come from timestamp queries (else: wall clock).
    pub fn has_timestamps(&self) -> bool {
        self.timestamps
    }

    /// Whether every kernel is built with wgpu's runtime checks: where
    /// [`ContextOptions::check_every_kernel`] asks, and off Vulkan (Metal, DX12 and GL have no
    /// robust buffer access to bound a storage buffer without them).
    pub fn checks_every_kernel(&self) -> bool {
        self.check_every_kernel || !self.vulkan
    }

    /// Whether a plug-in model's kernels are built without wgpu's runtime checks
    /// ([`ContextOptions::trust_model_kernels`]).
    pub fn trusts_model_kernels(&self) -> bool {
        self.trust_model_kernels
    }

    /// Loses the device on purpose, through the same path a driver reset or a removed GPU takes
    /// (wgpu's device-lost callback): every later use of this context is a
    /// [`GpuError::DeviceLost`]. For testing that a run survives a GPU fault with its results.
    pub fn simulate_device_loss(&self) {
        self.device.destroy();
        // Some backends report the loss only at the next poll.
        let _ = self.device.poll(wgpu::PollType::Poll);
        if let Ok(mut slot) = self.lost.lock()
            && slot.is_none()
        {
            *slot = Some("the device was destroyed (a simulated fault)".into());
        }
    }

    /// Errors if the device was lost.
    pub fn check_lost(&self) -> Result<(), GpuError> {
        match self.lost.lock().ok().and_then(|slot| slot.clone()) {
            Some(reason) => Err(GpuError::DeviceLost(reason)),
            None => Ok(()),
        }
    }

    /// Runs `f` inside validation and out-of-memory error scopes and turns what they catch into
    /// typed errors.
    pub fn scoped<R>(&self, what: &str, f: impl FnOnce() -> R) -> Result<R, GpuError> {
        self.check_lost()?;
        let oom = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let validation = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let result = f();
        let validation_error = pollster::block_on(validation.pop());
        let oom_error = pollster::block_on(oom.pop());
        if let Some(e) = validation_error {
            return Err(GpuError::Validation {
                what: what.to_string(),
                message: e.to_string(),
            });
        }
        if let Some(e) = oom_error {
            return Err(GpuError::OutOfMemory {
                what: what.to_string(),
                message: e.to_string(),
            });
        }
        Ok(result)
    }

    /// Blocks until `submission` (or all work) has finished, within the poll timeout.
    pub fn wait(
        &self,
        submission: Option<wgpu::SubmissionIndex>,
        what: &str,
    ) -> Result<(), GpuError> {
        let result = self.device.poll(wgpu::PollType::Wait {
            submission_index: submission,
            timeout: Some(self.poll_timeout),
        });
        self.check_lost()?;
        match result {
            Ok(_) => Ok(()),
            Err(wgpu::PollError::Timeout) => Err(GpuError::Timeout {
                what: what.to_string(),
                seconds: self.poll_timeout.as_secs(),
            }),
            Err(e) => Err(GpuError::DeviceLost(e.to_string())),
        }
    }

    /// Checks a storage buffer of `bytes` against the adapter's limits.
    pub fn check_buffer_size(&self, label: &str, bytes: u64) -> Result<(), GpuError> {
        let checks = [
            (
                self.limits.max_storage_buffer_binding_size,
                "max_storage_buffer_binding_size",
            ),
            (self.limits.max_buffer_size, "max_buffer_size"),
        ];
        for (limit, limit_name) in checks {
            if bytes > limit {
                return Err(GpuError::BufferTooLarge {
                    label: label.to_string(),
                    bytes,
                    limit,
                    limit_name,
                });
            }
        }
        Ok(())
    }
}
