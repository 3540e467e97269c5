//! A model's targets split over several GPUs: [`Sharded`], for any [`Model`] whose frame is a
//! slice of per-target values (`[T]`, K values a target: the WGSL plug-ins, `Plugin`, a user's
//! model). The face tracker, whose frame also carries each slot's template, splits its slots the
//! same way in its own `tracker/shards.rs`.
//!
//! Targets are independent filters, so a batch splits into contiguous shards of targets, one per
//! GPU, each a whole [`Filter`] for its share. Each shard numbers its targets as in the whole
//! batch ([`Filter::number_targets_from`]), so they draw the random numbers they draw on one GPU
//! and the results are those of one GPU, bit for bit, where the GPUs compute alike. A frame is
//! submitted to every GPU before any is waited for, so that they work at once; two frames may be
//! in flight on each.

use std::ops::Range;

use pf_core::batch::{BatchConfig, BatchShape};

use super::{EngineReport, Filter, InFlight, Model};
use crate::context::GpuContext;
use crate::error::GpuError;
use crate::filter::{GpuResampler, LaggedSummaries, LikelihoodReadbacks};

/// One GPU's share of the targets.
struct Shard<M: Model> {
    targets: Range<usize>,
    filter: Filter<M>,
}

/// A model's filter whose targets are split over several GPUs (one shard of targets each).
pub struct Sharded<M: Model> {
    shards: Vec<Shard<M>>,
    shape: BatchShape,
}

/// A frame submitted to every shard ([`Sharded::submit`]), not yet read back.
#[must_use = "a submitted frame must be finished (Sharded::finish)"]
pub struct ShardedPending {
    pending: Vec<InFlight>,
}

/// Contiguous ranges of `targets` over at most `parts` shards, their sizes differing by at most
/// one (no empty shard).
pub fn shard_ranges(targets: usize, parts: usize) -> Vec<Range<usize>> {
    let parts = parts.min(targets).max(1);
    let mut start = 0;
    (0..parts)
        .map(|i| {
            let len = targets / parts + usize::from(i < targets % parts);
            let range = start..start + len;
            start += len;
            range
        })
        .collect()
}

impl<T, M> Sharded<M>
where
    M: for<'f> Model<Frame<'f> = [T]>,
{
    /// The batch of `config` split over `contexts` (one shard each; with fewer targets than
    /// contexts, the extra contexts are not used): `model(ctx, part)` builds each shard's model
    /// for its part of the configuration. `initial_states` in the whole batch's layout
    /// (`[(t·D + d)·M + m]`).
    pub fn on_gpus(
        contexts: Vec<GpuContext>,
        config: &BatchConfig,
        resampler: GpuResampler,
        initial_states: &[f32],
        mut model: impl FnMut(&GpuContext, &BatchConfig) -> Result<M, M::Error>,
    ) -> Result<Self, M::Error> {
        config.validate().map_err(GpuError::from)?;
        let shape = config.shape;
        if contexts.is_empty() {
            return Err(GpuError::InvalidConfig(
                "a sharded filter needs at least one GPU context".into(),
            )
            .into());
        }
        if initial_states.len() != shape.state_len() {
            return Err(GpuError::LengthMismatch {
                what: "initial states".into(),
                expected: shape.state_len(),
                got: initial_states.len(),
            }
            .into());
        }
        let block = shape.dims * shape.particles;
        let ranges = shard_ranges(shape.targets, contexts.len());
        let mut shards = Vec::with_capacity(ranges.len());
        for (ctx, targets) in contexts.into_iter().zip(ranges) {
            let mut part = config.clone();
            part.shape = BatchShape::new(targets.len(), shape.particles, shape.dims)
                .map_err(GpuError::from)?;
            let states = &initial_states[targets.start * block..targets.end * block];
            let shard_model = model(&ctx, &part)?;
            let mut filter = Filter::on_gpu(ctx, &part, resampler, states, shard_model)?;
            filter.number_targets_from(targets.start)?;
            shards.push(Shard { targets, filter });
        }
        Ok(Self { shards, shape })
    }

    /// The whole batch's shape.
    pub fn shape(&self) -> &BatchShape {
        &self.shape
    }

    /// Each shard's targets and filter, in order.
    pub fn shards(&self) -> impl Iterator<Item = (Range<usize>, &Filter<M>)> {
        self.shards.iter().map(|s| (s.targets.clone(), &s.filter))
    }

    /// One frame against `frame` (the whole batch's values, the same number for every target),
    /// every GPU at once.
    pub fn step(&mut self, frame: &[T]) -> Result<EngineReport, M::Error> {
        let pending = self.submit(frame)?;
        self.finish(pending)
    }

    /// Submits a frame to every shard without waiting (at most two frames in flight).
    pub fn submit(&mut self, frame: &[T]) -> Result<ShardedPending, M::Error> {
        let targets = self.shape.targets;
        if frame.is_empty() || !frame.len().is_multiple_of(targets) {
            return Err(GpuError::LengthMismatch {
                what: format!(
                    "observations (the same number of values for each of {targets} targets)"
                ),
                expected: targets,
                got: frame.len(),
            }
            .into());
        }
        let per_target = frame.len() / targets;
        let mut pending = Vec::with_capacity(self.shards.len());
        for shard in &mut self.shards {
            let seen = &frame[shard.targets.start * per_target..shard.targets.end * per_target];
            match shard.filter.submit(seen) {
                Ok(step) => pending.push(step),
                Err(e) => {
                    // Leave no shard with a step in flight: finish those already submitted.
                    for (shard, step) in self.shards.iter_mut().zip(pending) {
                        let _ = shard.filter.finish(step);
                    }
                    return Err(e);
                }
            }
        }
        Ok(ShardedPending { pending })
    }

    /// Waits for the oldest frame in flight on every shard; the results in the whole batch's
    /// target order. The GPU time is the slowest shard's (the GPUs work at once).
    pub fn finish(&mut self, frame: ShardedPending) -> Result<EngineReport, M::Error> {
        let (t, d) = (self.shape.targets, self.shape.dims);
        let mut report = EngineReport {
            estimates: Vec::with_capacity(t * d),
            best_estimates: Vec::new(),
            spreads: Vec::with_capacity(t * d),
            ess: Vec::with_capacity(t),
            resampled: Vec::with_capacity(t),
            beta: Vec::with_capacity(t),
            log_evidence: Vec::with_capacity(t),
            status: Vec::with_capacity(t),
            gpu_time: None,
            likelihood: LikelihoodReadbacks::default(),
            lagged: None,
        };
        // Every shard is waited for even when one fails, so that none is left in flight.
        let parts: Vec<_> = (self.shards.iter_mut().zip(frame.pending))
            .map(|(shard, pending)| shard.filter.finish(pending))
            .collect();
        let mut lagged: Option<Vec<_>> = Some(Vec::with_capacity(t));
        let mut lag = 0;
        for part in parts {
            let part = part?;
            // The shards' lagged targets in order, where every shard summarised its window.
            lagged = match (lagged, part.lagged) {
                (Some(mut all), Some(more)) => {
                    lag = more.lag;
                    all.extend(more.targets);
                    Some(all)
                }
                _ => None,
            };
            report.estimates.extend(part.estimates);
            report.best_estimates.extend(part.best_estimates);
            report.spreads.extend(part.spreads);
            report.ess.extend(part.ess);
            report.resampled.extend(part.resampled);
            report.beta.extend(part.beta);
            report.log_evidence.extend(part.log_evidence);
            report.status.extend(part.status);
            report.gpu_time = match (report.gpu_time, part.gpu_time) {
                (Some(a), Some(b)) if a.duration() >= b.duration() => Some(a),
                (a, b) => b.or(a),
            };
        }
        report.lagged = lagged.map(|targets| LaggedSummaries { lag, targets });
        Ok(report)
    }

    /// Restarts target `t` of the whole batch from `states` (`[d·M + m]`) with equal weights.
    pub fn reset_target(&mut self, t: usize, states: &[f32]) -> Result<(), M::Error> {
        let (filter, local) = self.filter_of(t)?;
        filter.reset_target(local, states)
    }

    /// Sets target `t` of the whole batch moving (`Filter::set_target_motion`).
    pub fn set_target_motion(
        &mut self,
        t: usize,
        estimate: &[f32],
        motion: &[f32],
    ) -> Result<(), M::Error> {
        let (filter, local) = self.filter_of(t)?;
        filter.set_target_motion(local, estimate, motion)
    }

    /// The filter that holds target `t` of the whole batch, and `t`'s index there.
    fn filter_of(&mut self, t: usize) -> Result<(&mut Filter<M>, usize), M::Error> {
        let targets = self.shape.targets;
        let shard = (self.shards.iter_mut())
            .find(|s| s.targets.contains(&t))
            .ok_or_else(|| {
                GpuError::InvalidConfig(format!("target {t} of a batch of {targets}"))
            })?;
        Ok((&mut shard.filter, t - shard.targets.start))
    }

    /// The whole batch's particle states (`[(t·D + d)·M + m]`; tests and debugging).
    pub fn download_states(&self) -> Result<Vec<f32>, M::Error> {
        let mut states = Vec::with_capacity(self.shape.state_len());
        for shard in &self.shards {
            states.extend(shard.filter.particles()?.0);
        }
        Ok(states)
    }
}

#[cfg(test)]
mod tests {
    use super::shard_ranges;

    #[test]
    fn shards_are_contiguous_even_and_never_empty() {
        assert_eq!(shard_ranges(10, 3), vec![0..4, 4..7, 7..10]);
        assert_eq!(shard_ranges(2, 4), vec![0..1, 1..2]);
        assert_eq!(shard_ranges(5, 1), vec![0..5]);
        for targets in 1..40 {
            for parts in 1..9 {
                let ranges = shard_ranges(targets, parts);
                assert_eq!(ranges.first().unwrap().start, 0);
                assert_eq!(ranges.last().unwrap().end, targets);
                assert!(ranges.windows(2).all(|w| w[0].end == w[1].start));
                let lens: Vec<usize> = ranges.iter().map(|r| r.len()).collect();
                assert!(lens.iter().all(|&l| l > 0));
                assert!(lens.iter().max().unwrap() - lens.iter().min().unwrap() <= 1);
            }
        }
    }
}
