//! Samples as islands over several GPUs: [`Islands`], one [`Filter`] per GPU, each a whole
//! filter over its share of every target's samples with its own random numbers, stepped at
//! once; only their estimates come to the host, where `pf_core::islands` combines them and,
//! every few frames, restarts the islands that lost a target from the ones that kept it
//! ([`exchange`]). Island 0 keeps the configuration's seed, so one island is the plain filter.
//!
//! Why islands and not one filter spread over GPUs: a filter's layers need every sample's
//! weight before the next layer, a round trip per layer between GPUs; islands need nothing from
//! each other within a frame.

use pf_core::batch::BatchConfig;
use pf_core::islands::{
    Combined, IslandEstimate, combine, exchange_due, island_sizes, island_sources, resampled,
};
use pf_core::random::part_seed;

use super::{EngineReport, Filter, FilterEngine, Model};
use crate::context::GpuContext;
use crate::error::GpuError;
use crate::filter::GpuResampler;

/// A frame's results over the islands.
#[derive(Debug, Clone)]
pub struct IslandReport {
    /// The islands combined, per target (estimates, spreads, ESS, island weights).
    pub combined: Combined,
    /// Each island's own report, in island order.
    pub islands: Vec<EngineReport>,
    /// When the islands exchanged after this frame: each target's sources (`[t][g]`: the island
    /// that island g restarted from, g itself when it kept its particles).
    pub exchanged: Option<Vec<Vec<u32>>>,
}

/// One model's samples split into islands, one filter each (normally one per GPU).
pub struct Islands<M: Model> {
    filters: Vec<Filter<M>>,
    angular: Vec<bool>,
    seed: u64,
    exchange_every: u64,
    frames: u64,
    weights: Vec<f64>,
}

impl<M> Islands<M>
where
    M: Model + Send,
    M::Error: Send,
{
    /// The batch of `config` with its samples split over `contexts`, one island each:
    /// `model(ctx, island_config)` builds each island's model, `start(island_config)` its
    /// initial states; islands exchange every `exchange_every` frames (0: never).
    pub fn on_gpus(
        contexts: Vec<GpuContext>,
        config: &BatchConfig,
        resampler: GpuResampler,
        mut start: impl FnMut(&BatchConfig) -> Vec<f32>,
        mut model: impl FnMut(&GpuContext, &BatchConfig) -> Result<M, M::Error>,
        exchange_every: u64,
    ) -> Result<Self, M::Error> {
        config.validate().map_err(GpuError::from)?;
        let sizes = island_sizes(config.shape.particles, contexts.len()).map_err(GpuError::from)?;
        let mut filters = Vec::with_capacity(sizes.len());
        for (g, (ctx, particles)) in contexts.into_iter().zip(sizes).enumerate() {
            let mut island = config.clone();
            island.shape.particles = particles;
            island.seed = part_seed(config.seed, g);
            island.best = island.best.min(particles);
            let model = model(&ctx, &island)?;
            let states = start(&island);
            filters.push(Filter::on_gpu(ctx, &island, resampler, &states, model)?);
        }
        Ok(Self {
            filters,
            angular: config.angular.clone(),
            seed: config.seed,
            exchange_every,
            frames: 0,
            weights: Vec::new(),
        })
    }

    /// One frame on every island at once (a thread each); `island_log_weight(g, report)` weighs
    /// island g for each target (`[t]`: the log-likelihood of its estimate, or its evidence).
    pub fn step(
        &mut self,
        frame: &M::Frame<'_>,
        island_log_weight: impl Fn(usize, &EngineReport) -> Result<Vec<f64>, M::Error>,
    ) -> Result<IslandReport, M::Error>
    where
        for<'f> M::Frame<'f>: Sync,
    {
        let islands = step_all(&mut self.filters, frame)?;
        let (count, shape) = (islands.len(), self.filters[0].shape());
        let mut log_weights = vec![0.0; shape.targets * count];
        for (g, report) in islands.iter().enumerate() {
            let per_target = island_log_weight(g, report)?;
            if per_target.len() != shape.targets {
                return Err(GpuError::LengthMismatch {
                    what: "island log-weights (one per target)".into(),
                    expected: shape.targets,
                    got: per_target.len(),
                }
                .into());
            }
            for (t, w) in per_target.into_iter().enumerate() {
                log_weights[t * count + g] = w;
            }
        }
        let estimates: Vec<IslandEstimate<'_>> = (islands.iter())
            .map(|r| IslandEstimate {
                estimates: r.point_estimates(),
                spreads: &r.spreads,
                ess: &r.ess,
            })
            .collect();
        let combined =
            combine(&estimates, &log_weights, shape.dims, &self.angular).map_err(GpuError::from)?;
        self.frames += 1;
        self.weights = combined.weights.clone();
        let exchanged = match exchange_due(self.exchange_every, self.frames) {
            true => {
                let mut engines: Vec<_> = self.filters.iter_mut().map(|f| f.engine_mut()).collect();
                Some(exchange(
                    &mut engines,
                    &combined.weights,
                    self.seed ^ self.frames,
                )?)
            }
            false => None,
        };
        Ok(IslandReport {
            combined,
            islands,
            exchanged,
        })
    }

    /// The islands' particles as one batch (`pf_core::islands::joined_particles`): the states
    /// (`[(t·D + d)·M + m]`) and log-weights, each island's weighed by its last island weight.
    pub fn particles(&self) -> Result<(Vec<f32>, Vec<f32>), M::Error> {
        let parts = (self.filters.iter())
            .map(|f| f.engine().particles())
            .collect::<Result<Vec<_>, _>>()?;
        let (_, states, log_weights) =
            pf_core::islands::joined_particles(&parts, &self.weights).map_err(GpuError::from)?;
        Ok((states, log_weights))
    }

    /// The island filters, in order.
    pub fn filters(&self) -> &[Filter<M>] {
        &self.filters
    }
}

/// Steps every filter on `frame` at once, one thread each (in place with one filter); the
/// reports in filter order.
pub fn step_all<M>(
    filters: &mut [Filter<M>],
    frame: &M::Frame<'_>,
) -> Result<Vec<EngineReport>, M::Error>
where
    M: Model + Send,
    M::Error: Send,
    for<'f> M::Frame<'f>: Sync,
{
    if let [filter] = filters {
        return Ok(vec![filter.step(frame)?]);
    }
    std::thread::scope(|scope| {
        let running: Vec<_> = (filters.iter_mut())
            .map(|filter| scope.spawn(move || filter.step(frame)))
            .collect();
        running
            .into_iter()
            .map(|r| {
                r.join().map_err(|_| {
                    M::Error::from(GpuError::InvalidConfig(
                        "an island's thread panicked".into(),
                    ))
                })?
            })
            .collect()
    })
}

/// The islands' selection after a frame, target by target: island g takes island `a_g`, drawn by
/// systematic resampling of the island weights (`weights[t·G + g]`, a uniform from `seed`); an
/// island that draws another restarts that target from a resample of the other's particles, at
/// its own size. Returns each target's sources.
pub fn exchange(
    engines: &mut [&mut FilterEngine],
    weights: &[f64],
    seed: u64,
) -> Result<Vec<Vec<u32>>, GpuError> {
    let count = engines.len();
    let targets = engines.first().map_or(0, |e| e.shape().targets);
    if weights.len() != targets * count {
        return Err(GpuError::LengthMismatch {
            what: "island weights".into(),
            expected: targets * count,
            got: weights.len(),
        });
    }
    let mut downloaded = vec![None; count];
    let mut all = Vec::with_capacity(targets);
    for t in 0..targets {
        let target_seed = seed ^ ((t as u64) << 32);
        let sources = island_sources(&weights[t * count..(t + 1) * count], target_seed)?;
        for (g, &source) in sources.iter().enumerate() {
            let source = source as usize;
            if source == g {
                continue;
            }
            if downloaded[source].is_none() {
                downloaded[source] = Some(engines[source].particles()?);
            }
            let Some((shape, states, log_weights)) = &downloaded[source] else {
                unreachable!("downloaded just above");
            };
            let size = engines[g].shape().particles;
            let restart = resampled(shape, states, log_weights, t, size, target_seed ^ g as u64)?;
            engines[g].reset_target(t, &restart)?;
        }
        all.push(sources);
    }
    Ok(all)
}
