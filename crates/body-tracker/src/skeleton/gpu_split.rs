//! The body likelihood of a host-held filter's samples split over several GPUs
//! ([`SplitBodyLikelihood`]): each context weighs a contiguous share with its own
//! [`BodyLikelihoodGpu`], all submitted before any is read back. (The tracker's own several-GPU
//! path is islands, `crate::tracker::islands`; this is kept as a library piece.)

use std::ops::Range;

use pf_gpu::{GpuContext, GpuError};

use super::gpu::{BodyLikelihoodConfig, BodyLikelihoodGpu};

/// The samples of a host-held filter split over several GPUs, one contiguous share each.
pub struct SplitBodyLikelihood {
    /// (context index, sample range, that context's likelihood).
    parts: Vec<(usize, Range<usize>, BodyLikelihoodGpu)>,
    contexts: usize,
    dims: usize,
    samples: usize,
}

impl SplitBodyLikelihood {
    /// One share per context, as equal as possible (a context gets none when samples < contexts).
    pub fn new(
        contexts: &[GpuContext],
        config: &BodyLikelihoodConfig,
        samples: usize,
    ) -> Result<Self, GpuError> {
        if contexts.is_empty() {
            return Err(GpuError::InvalidConfig(
                "splitting samples needs at least one GPU context".into(),
            ));
        }
        let mut parts = Vec::new();
        let n = contexts.len();
        for (i, ctx) in contexts.iter().enumerate() {
            let range = samples * i / n..samples * (i + 1) / n;
            if range.is_empty() {
                continue;
            }
            let share = BodyLikelihoodGpu::new(ctx, config.clone(), range.len())?;
            parts.push((i, range, share));
        }
        if parts.is_empty() {
            return Err(GpuError::InvalidConfig(
                "the split body likelihood needs at least one sample".into(),
            ));
        }
        Ok(Self {
            parts,
            contexts: n,
            dims: config.dims,
            samples,
        })
    }

    /// The sample range each context evaluates, by context index (empty when it got none).
    pub fn shares(&self) -> Vec<Range<usize>> {
        let mut shares = vec![0..0; self.contexts];
        for (i, range, _) in &self.parts {
            shares[*i] = range.clone();
        }
        shares
    }

    fn check_contexts(&self, contexts: &[GpuContext]) -> Result<(), GpuError> {
        if contexts.len() == self.contexts {
            Ok(())
        } else {
            Err(GpuError::LengthMismatch {
                what: "GPU contexts of the split likelihood".into(),
                expected: self.contexts,
                got: contexts.len(),
            })
        }
    }

    /// This frame's rays, to every GPU.
    pub fn upload_rays(
        &mut self,
        contexts: &[GpuContext],
        rays: &[[f32; 4]],
    ) -> Result<(), GpuError> {
        self.check_contexts(contexts)?;
        for (i, _, part) in &mut self.parts {
            part.upload_rays(&contexts[*i], rays)?;
        }
        Ok(())
    }

    /// M_j for every pose (`[d·J + j]`): every GPU is submitted its share before any is read.
    pub fn evaluate(&self, contexts: &[GpuContext], poses: &[f32]) -> Result<Vec<f64>, GpuError> {
        self.check_contexts(contexts)?;
        if poses.len() != self.samples * self.dims {
            return Err(GpuError::LengthMismatch {
                what: "pose samples".into(),
                expected: self.samples * self.dims,
                got: poses.len(),
            });
        }
        let mut submissions = Vec::with_capacity(self.parts.len());
        for (i, range, part) in &self.parts {
            let mut share = Vec::with_capacity(range.len() * self.dims);
            for d in 0..self.dims {
                let row = d * self.samples;
                share.extend_from_slice(&poses[row + range.start..row + range.end]);
            }
            submissions.push(part.submit_poses(&contexts[*i], &share)?);
        }
        let mut sums = Vec::with_capacity(self.samples);
        for ((i, _, part), submission) in self.parts.iter().zip(submissions) {
            sums.extend(part.read_sums(&contexts[*i], submission)?);
        }
        Ok(sums)
    }
}
