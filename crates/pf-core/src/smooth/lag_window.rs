//! A lag window of a whole batch, summarised as it slides: each frame's particles, normalised
//! log-weights and lineage go in, and once `lag + 1` frames are in, each target's frame `lag`
//! steps back comes out smoothed from the ancestry ([`super::ancestry`]) and summarised
//! ([`super::summarise`]). The host twin of the GPU's lag window
//! (`pf_gpu::GpuFilter::keep_lag_window`, `shaders/engine/lag_summary.wgsl`), which keeps the
//! frames on the device and reads back only these summaries.

use std::collections::VecDeque;

use super::ancestry::{trace_back, traceable};
use super::{Cloud, Summary, summarise};
use crate::batch::BatchShape;
use crate::error::PfError;
use crate::weights::effective_sample_size;

/// One target's lagged frame, summarised.
#[derive(Debug, Clone, PartialEq)]
pub struct LaggedTarget {
    /// Each value's smoothed mean and 95 % interval (the newest frame's weights traced back).
    pub smoothed: Vec<Summary>,
    /// The same particles under their own (filtered) weights; empty unless asked for.
    pub filtered: Vec<Summary>,
    /// The share of the lagged frame's effective sample size the trace kept (traced over
    /// filtered; path degeneracy takes it towards 0).
    pub kept: f32,
}

/// A lag window's output after a frame: the frame `lag` steps back, per target.
#[derive(Debug, Clone, PartialEq)]
pub struct LaggedSummaries {
    /// How many steps back the summarised frame lies.
    pub lag: usize,
    /// Per target; `None` where a particle on the way has no ancestor (the target restarted
    /// within the window: its frames before the restart are smoothed from the last of them).
    pub targets: Vec<Option<LaggedTarget>>,
}

/// One target's frame in a lag window, read back from a device (`pf_gpu::GpuFilter::
/// download_lag_frames`) to be smoothed on the host.
#[derive(Debug, Clone, PartialEq)]
pub struct LagFrame {
    /// The states, `[d·M + m]`.
    pub states: Vec<f32>,
    /// The normalised log-weights, `[m]`.
    pub log_weights: Vec<f32>,
    /// Each particle's ancestor among the frame before's, `[m]`.
    pub lineage: Vec<u32>,
}

/// One frame of a batch in the window.
#[derive(Debug, Clone)]
struct WindowFrame {
    states: Vec<f32>,
    log_weights: Vec<f32>,
    lineage: Vec<u32>,
}

/// The host's lag window over a batch of `shape`.
#[derive(Debug, Clone)]
pub struct LagWindow {
    shape: BatchShape,
    lag: usize,
    angular: Vec<bool>,
    compare_filtered: bool,
    frames: VecDeque<WindowFrame>,
}

impl LagWindow {
    /// A window of `lag` frames (at least 1) over batches of `shape`, whose dimensions flagged in
    /// `angular` are angles; `compare_filtered` adds each lagged frame's filtered summary.
    pub fn new(
        shape: BatchShape,
        lag: usize,
        angular: Vec<bool>,
        compare_filtered: bool,
    ) -> Result<Self, PfError> {
        if lag == 0 {
            return Err(PfError::InvalidConfig(
                "a lag window of 0 frames: the lag is at least 1".into(),
            ));
        }
        Ok(Self {
            shape,
            lag,
            angular,
            compare_filtered,
            frames: VecDeque::with_capacity(lag + 1),
        })
    }

    /// A frame's states (`[(t·D + d)·M + m]`), normalised log-weights and lineage (`[t·M + m]`,
    /// each particle's ancestor in the frame before). Returns the frame `lag` steps back,
    /// summarised, once the window holds `lag + 1` frames.
    pub fn push(
        &mut self,
        states: &[f32],
        log_weights: &[f32],
        lineage: &[u32],
    ) -> Result<Option<LaggedSummaries>, PfError> {
        let (values, particles) = (self.shape.state_len(), self.shape.particle_len());
        if states.len() != values || log_weights.len() != particles || lineage.len() != particles {
            return Err(PfError::InvalidConfig(format!(
                "a lag window's frame of {} states, {} log-weights and {} lineage entries; the \
                 batch has {values} states and {particles} particles",
                states.len(),
                log_weights.len(),
                lineage.len()
            )));
        }
        if self.frames.len() == self.lag + 1 {
            self.frames.pop_front();
        }
        self.frames.push_back(WindowFrame {
            states: states.to_vec(),
            log_weights: log_weights.to_vec(),
            lineage: lineage.to_vec(),
        });
        if self.frames.len() <= self.lag {
            return Ok(None);
        }
        let targets = (0..self.shape.targets)
            .map(|t| self.lagged_target(t))
            .collect::<Result<_, _>>()?;
        Ok(Some(LaggedSummaries {
            lag: self.lag,
            targets,
        }))
    }

    /// Target `t`'s first frame in the full window, smoothed by the last frame's weights.
    fn lagged_target(&self, t: usize) -> Result<Option<LaggedTarget>, PfError> {
        let (dims, m) = (self.shape.dims, self.shape.particles);
        let lineages: Vec<&[u32]> = (self.frames.iter().skip(1))
            .map(|f| &f.lineage[t * m..(t + 1) * m])
            .collect();
        if !lineages.iter().all(|l| traceable(l)) {
            return Ok(None);
        }
        let cloud_of = |f: &WindowFrame| {
            Cloud::of_target(dims, m, t, &f.states, &f.log_weights, vec![0.0; dims])
        };
        let (Some(first), Some(last)) = (self.frames.front(), self.frames.back()) else {
            return Ok(None);
        };
        let (first, last) = (cloud_of(first)?, cloud_of(last)?);
        let traced = trace_back(&last.weights, &lineages)?;
        let smoothed_weights = traced.first().map(Vec::as_slice).unwrap_or_default();
        let own = effective_sample_size(&first.weights);
        let kept = if own > 0.0 {
            effective_sample_size(smoothed_weights) / own
        } else {
            0.0
        };
        Ok(Some(LaggedTarget {
            smoothed: summarise(&first, smoothed_weights, &self.angular)?,
            filtered: if self.compare_filtered {
                summarise(&first, &first.weights, &self.angular)?
            } else {
                Vec::new()
            },
            kept: kept as f32,
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two targets of two particles, one value: the smoothed frame is the first, weighed by the
    /// last frame's weights carried to their ancestors.
    #[test]
    fn the_first_frame_is_weighed_by_its_descendants() {
        let shape = BatchShape::new(2, 2, 1).unwrap();
        let mut window = LagWindow::new(shape, 1, vec![false], true).unwrap();
        let half = 0.5f32.ln();
        let first = window
            .push(&[1.0, 3.0, -2.0, 2.0], &[half; 4], &[0, 1, 0, 1])
            .unwrap();
        assert!(first.is_none(), "a window of lag 1 needs two frames");
        // Both of target 0's particles descend from its particle 1 (value 3); target 1 restarted.
        let lineage = [1, 1, u32::MAX, u32::MAX];
        let lagged = window
            .push(&[0.0; 4], &[half; 4], &lineage)
            .unwrap()
            .unwrap();
        let target = lagged.targets[0].as_ref().unwrap();
        assert_eq!(target.smoothed[0].mean, 3.0);
        assert_eq!(target.filtered[0].mean, 2.0);
        assert!((target.kept - 0.5).abs() < 1e-6, "{}", target.kept);
        assert!(lagged.targets[1].is_none());
    }

    #[test]
    fn a_bad_frame_or_lag_is_an_error() {
        let shape = BatchShape::new(1, 2, 1).unwrap();
        assert!(LagWindow::new(shape, 0, vec![false], false).is_err());
        let mut window = LagWindow::new(shape, 2, vec![false], false).unwrap();
        assert!(window.push(&[0.0; 3], &[0.0; 2], &[0, 1]).is_err());
        assert!(window.push(&[0.0; 2], &[0.0; 2], &[0]).is_err());
    }
}
