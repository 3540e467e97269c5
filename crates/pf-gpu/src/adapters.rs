//! Finding the GPU adapters of this machine.

use crate::error::GpuError;

/// What `streampf devices` prints about one adapter.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AdapterSummary {
    /// The adapter's name as the driver reports it.
    pub name: String,
    /// "discrete GPU", "integrated GPU", "virtual GPU", "CPU (software)" or "other".
    pub device_type: &'static str,
    /// The graphics API (Vulkan, Metal, DX12, GL).
    pub backend: String,
    /// The driver's name.
    pub driver: String,
    /// The driver's version string.
    pub driver_info: String,
}

impl AdapterSummary {
    pub(crate) fn from_info(info: &wgpu::AdapterInfo) -> Self {
        let device_type = match info.device_type {
            wgpu::DeviceType::DiscreteGpu => "discrete GPU",
            wgpu::DeviceType::IntegratedGpu => "integrated GPU",
            wgpu::DeviceType::VirtualGpu => "virtual GPU",
            wgpu::DeviceType::Cpu => "CPU (software)",
            wgpu::DeviceType::Other => "other",
        };
        Self {
            name: info.name.clone(),
            device_type,
            backend: info.backend.to_string(),
            driver: info.driver.clone(),
            driver_info: info.driver_info.clone(),
        }
    }

    /// True for software rasterisers such as Mesa's lavapipe.
    pub fn is_software(&self) -> bool {
        self.device_type == "CPU (software)"
    }
}

/// A wgpu instance configured from the environment (`WGPU_BACKEND`, `WGPU_VALIDATION`, ...),
/// with the primary backends (Vulkan, Metal, DX12) unless `WGPU_BACKEND` says otherwise.
pub fn instance_from_env() -> wgpu::Instance {
    let mut descriptor = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
    descriptor.backends = wgpu::Backends::from_env().unwrap_or(wgpu::Backends::PRIMARY);
    wgpu::Instance::new(descriptor)
}

/// Every adapter of the backends `WGPU_BACKEND` allows (by default the primary ones: Vulkan,
/// Metal, DX12; OpenGL has no compute worth using here), whose name contains
/// `WGPU_ADAPTER_NAME` when that is set (case-insensitive).
///
/// Errors with [`GpuError::NoAdapter`], whose message says what to install, when the list would
/// be empty.
pub fn list_adapters() -> Result<Vec<AdapterSummary>, GpuError> {
    let instance = instance_from_env();
    let backends = wgpu::Backends::from_env().unwrap_or(wgpu::Backends::PRIMARY);
    let name_filter = std::env::var("WGPU_ADAPTER_NAME").ok();
    let adapters: Vec<AdapterSummary> = pollster::block_on(instance.enumerate_adapters(backends))
        .iter()
        .map(|a| AdapterSummary::from_info(&a.get_info()))
        .filter(|s| matches_name(s, name_filter.as_deref()))
        .collect();
    if adapters.is_empty() {
        return Err(GpuError::NoAdapter {
            filter: name_filter.map(|n| format!("WGPU_ADAPTER_NAME={n}")),
        });
    }
    Ok(adapters)
}

fn matches_name(summary: &AdapterSummary, filter: Option<&str>) -> bool {
    filter.is_none_or(|f| summary.name.to_lowercase().contains(&f.to_lowercase()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn name_filter_is_a_case_insensitive_substring() {
        let s = AdapterSummary {
            name: "NVIDIA H100 80GB HBM3".into(),
            device_type: "discrete GPU",
            backend: "vulkan".into(),
            driver: String::new(),
            driver_info: String::new(),
        };
        assert!(matches_name(&s, None));
        assert!(matches_name(&s, Some("h100")));
        assert!(!matches_name(&s, Some("llvmpipe")));
        assert!(!s.is_software());
    }

    #[test]
    fn no_adapter_message_says_what_to_install() {
        let msg = GpuError::NoAdapter {
            filter: Some("WGPU_ADAPTER_NAME=foo".into()),
        }
        .to_string();
        assert!(msg.contains("mesa-vulkan-drivers"), "{msg}");
        assert!(msg.contains("WGPU_ADAPTER_NAME=foo"), "{msg}");
    }
}
