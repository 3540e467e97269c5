//! The detector a tracker runs, on the CPU or on a GPU, with the GPU's fallback to the CPU.

use super::{Cascade, DetectConfig, Detection, GpuCascade};
use crate::error::FaceError;
use crate::image::GrayImage;

/// The detector a tracker runs: the cascade on the CPU's cores, or on a GPU. A GPU detector
/// that fails (its device lost or reset) hands over to the same cascade on the CPU for the rest
/// of the run, so that tracking goes on and no result is lost; [`FaceDetector::fallback`] says
/// why.
#[derive(Debug)]
pub enum FaceDetector {
    Cpu(Cascade),
    Gpu {
        gpu: Box<GpuCascade>,
        /// Why the GPU was given up, once it was.
        fallback: std::sync::Mutex<Option<String>>,
    },
}

impl FaceDetector {
    /// The faces in `frame`.
    pub fn detect(
        &self,
        frame: &GrayImage,
        config: &DetectConfig,
    ) -> Result<Vec<Detection>, FaceError> {
        let (gpu, fallback) = match self {
            Self::Cpu(cascade) => return cascade.detect(frame, config),
            Self::Gpu { gpu, fallback } => (gpu, fallback),
        };
        let lock = || {
            fallback
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
        };
        if lock().is_none() {
            match gpu.detect(frame, config) {
                Err(FaceError::Gpu(e)) => *lock() = Some(e.to_string()),
                done => return done,
            }
        }
        gpu.cascade().detect(frame, config)
    }

    /// Where it runs, in words ("CPU" or the GPU's name).
    pub fn device_name(&self) -> String {
        match self {
            Self::Cpu(_) => "CPU".into(),
            Self::Gpu { gpu, .. } => format!("GPU: {}", gpu.context().adapter().name),
        }
    }

    /// Why a GPU detector went over to the CPU, if it did.
    pub fn fallback(&self) -> Option<String> {
        match self {
            Self::Cpu(_) => None,
            Self::Gpu { fallback, .. } => fallback
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
                .clone(),
        }
    }
}

impl From<Cascade> for FaceDetector {
    fn from(cascade: Cascade) -> Self {
        Self::Cpu(cascade)
    }
}

impl From<GpuCascade> for FaceDetector {
    fn from(gpu: GpuCascade) -> Self {
        Self::Gpu {
            gpu: Box::new(gpu),
            fallback: std::sync::Mutex::new(None),
        }
    }
}
