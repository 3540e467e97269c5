//! `backend=` as the command line's `--backend`, and `devices()`.

use body_tracker::Backend;
use face_tracker::FaceBackend;
use pf_gpu::{ContextOptions, GpuContext, GpuError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::errors::{gpu, runtime_error, value_error};

/// Where a tracker runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Choice {
    /// A hardware GPU when there is one, else the CPU.
    Auto,
    Cpu,
    Gpu,
    AllGpus,
}

impl Choice {
    pub fn parse(name: &str) -> PyResult<Self> {
        match name {
            "auto" => Ok(Self::Auto),
            "cpu" => Ok(Self::Cpu),
            "gpu" => Ok(Self::Gpu),
            "all-gpus" => Ok(Self::AllGpus),
            other => Err(value_error(format!(
                "backend must be \"auto\", \"cpu\", \"gpu\" or \"all-gpus\", got {other:?}"
            ))),
        }
    }
}

fn options(allow_software: bool) -> ContextOptions {
    ContextOptions {
        allow_software,
        ..ContextOptions::default()
    }
}

/// The library's error in this package's words.
fn opening_error(err: GpuError) -> PyErr {
    match err {
        GpuError::OnlySoftwareAdapters { names } => runtime_error(format!(
            "only software adapters were found ({names}): they are far too slow to track with; \
             pass allow_software=True to use one anyway"
        )),
        other => gpu(other),
    }
}

/// The GPUs `choice` asks for: none for the CPU (and for `auto` without a usable GPU).
pub fn open(py: Python<'_>, choice: Choice, allow_software: bool) -> PyResult<Vec<GpuContext>> {
    py.detach(|| match choice {
        Choice::Cpu => Ok(Vec::new()),
        Choice::Gpu => GpuContext::new(&options(allow_software)).map(|c| vec![c]),
        Choice::AllGpus => GpuContext::all(&options(allow_software)),
        Choice::Auto => Ok(GpuContext::new(&options(allow_software))
            .map(|c| vec![c])
            .unwrap_or_default()),
    })
    .map_err(opening_error)
}

/// The face tracker's backend: on `all-gpus`, as many GPUs as `max_faces` faces under `config`
/// pay for (`face_tracker`'s `gpus_for_load`, as `face track` uses).
pub fn face_backend(
    contexts: Vec<GpuContext>,
    choice: Choice,
    max_faces: usize,
    config: &face_tracker::FaceTrackerConfig,
) -> FaceBackend {
    let mut contexts = contexts;
    let paid = face_tracker::tracker::shards::gpus_for_load(max_faces, config, contexts.len());
    contexts.truncate(paid.max(1));
    match (choice, contexts.len()) {
        (_, 0) => FaceBackend::Cpu,
        (Choice::AllGpus, n) if n > 1 => FaceBackend::Gpus(contexts),
        _ => FaceBackend::Gpu(Box::new(contexts.remove(0))),
    }
}

pub fn body_backend(contexts: Vec<GpuContext>, choice: Choice) -> Backend {
    let mut contexts = contexts;
    match (choice, contexts.len()) {
        (_, 0) => Backend::Cpu,
        (Choice::AllGpus, _) => Backend::SplitGpus(contexts),
        _ => Backend::Gpu(Box::new(contexts.remove(0))),
    }
}

/// The GPU adapters wgpu can use, as dicts (name, device_type, backend, driver, driver_info,
/// software), best first as the trackers rank them; an empty list when there is none.
#[pyfunction]
pub fn devices(py: Python<'_>) -> PyResult<Vec<Bound<'_, PyDict>>> {
    let adapters = match py.detach(pf_gpu::list_adapters) {
        Ok(adapters) => adapters,
        Err(GpuError::NoAdapter { .. }) => Vec::new(),
        Err(other) => return Err(gpu(other)),
    };
    adapters
        .into_iter()
        .map(|a| {
            let d = PyDict::new(py);
            d.set_item("name", &a.name)?;
            d.set_item("device_type", a.device_type)?;
            d.set_item("backend", &a.backend)?;
            d.set_item("driver", &a.driver)?;
            d.set_item("driver_info", &a.driver_info)?;
            d.set_item("software", a.is_software())?;
            Ok(d)
        })
        .collect()
}
