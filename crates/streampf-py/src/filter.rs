//! `streampf.ParticleFilter`: the generic engine for T targets × M particles × D dimensions,
//! with the model as WGSL on the GPU (the plug-in of `pf_gpu::model`) or as a vectorised
//! Python callable on the CPU (`pf_core::batch::BatchFilter`).

use std::sync::{Mutex, TryLockError};

use numpy::PyUntypedArrayMethods;
use pf_core::anneal::Annealing;
use pf_core::batch::{BatchConfig, BatchFilter, BatchShape};
use pf_core::smooth::motion::SmoothMotion;
use pf_core::smooth::{GaussianTransition, Summary};
use pf_core::{PfError, Resampler, ResamplerKind};
use pf_gpu::GpuResampler;
use pf_gpu::model::{ModelSource, RawModelFilter};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyTuple};

use crate::arrays::{check_finite, contiguous, finite_f32, to_numpy};
use crate::backend::{Choice, open};
use crate::errors::{gpu, pf, runtime_error, value_error, whole, whole_opt};

enum Engine {
    /// The model's WGSL, the whole step on the GPU.
    Gpu {
        filter: Box<RawModelFilter>,
        observation_values: usize,
    },
    /// A Python callable weighs the particles; the rest of the step runs in Rust.
    Cpu {
        filter: Box<BatchFilter<Box<dyn Resampler>>>,
        likelihood: Py<PyAny>,
    },
}

/// `smooth=True`'s record: every step's particles (batch layout) and log-weights, and the
/// dynamics' density the smoother reweighs by.
struct History {
    steps: Mutex<Vec<(Vec<f32>, Vec<f32>)>>,
    transition: GaussianTransition,
}

impl History {
    /// The record for `smooth`, refused for a WGSL `propagate` (its density is unknown).
    fn for_filter(smooth: bool, engine: &Engine, config: &BatchConfig) -> PyResult<Option<Self>> {
        if !smooth {
            return Ok(None);
        }
        if let Engine::Gpu { filter, .. } = engine
            && filter.model().propagates()
        {
            return Err(value_error(
                "smooth=True needs the dynamics' density: the random walk's (sigma=) is known, \
                 a WGSL propagate's is not",
            ));
        }
        Ok(Some(Self {
            steps: Mutex::new(Vec::new()),
            transition: GaussianTransition {
                sigma: config.annealing.frame_sigma(&config.sigma),
                angular: config.angular.clone(),
            },
        }))
    }
}

/// A particle filter whose model you supply: see the stub for the arguments.
#[pyclass(module = "streampf._streampf")]
pub struct ParticleFilter {
    engine: Mutex<Engine>,
    /// `smooth=True`: every step's particles, for `smoothed()`.
    history: Option<History>,
    /// `lag=` on the CPU: the host's lag window (on the GPU the engine keeps it).
    cpu_lag: Option<Mutex<pf_core::smooth::lag_window::LagWindow>>,
    shape: BatchShape,
    device: String,
    /// Whether the model is WGSL on the GPU (else a Python likelihood on the CPU).
    on_gpu: bool,
}

/// (T, M, D) row-major → the batch layout `[(t·D + d)·M + m]`.
fn to_batch_layout(values: &[f32], shape: &BatchShape) -> Vec<f32> {
    let (t, m, d) = (shape.targets, shape.particles, shape.dims);
    let mut out = vec![0.0; values.len()];
    for target in 0..t {
        for particle in 0..m {
            for dim in 0..d {
                out[(target * d + dim) * m + particle] = values[(target * m + particle) * d + dim];
            }
        }
    }
    out
}

/// The batch layout → (T, M, D) row-major.
fn from_batch_layout(values: &[f32], shape: &BatchShape) -> Vec<f32> {
    let (t, m, d) = (shape.targets, shape.particles, shape.dims);
    let mut out = vec![0.0; values.len()];
    for target in 0..t {
        for dim in 0..d {
            for particle in 0..m {
                out[(target * m + particle) * d + dim] = values[(target * d + dim) * m + particle];
            }
        }
    }
    out
}

/// `resampler=`: a name of `pf_core::ResamplerKind` that the GPU runs (`GpuResampler::KINDS`).
fn gpu_resampler(name: &str) -> PyResult<GpuResampler> {
    let kind: ResamplerKind = name
        .parse()
        .map_err(|e: pf_core::PfError| value_error(format!("resampler: {e}")))?;
    GpuResampler::for_kind(kind).map_err(|e| value_error(format!("resampler: {e}")))
}

#[pymethods]
impl ParticleFilter {
    #[new]
    #[pyo3(signature = (
        initial, *, sigma, wgsl = None, likelihood = None, observation_size = None,
        constants = None, name = "model", angular = None, bounds = None,
        resampler = "systematic", layers = 1, seed = 1, backend = "auto",
        allow_software = false, smooth = false, lag = None
    ))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        initial: &Bound<'_, PyAny>,
        sigma: Vec<f32>,
        wgsl: Option<String>,
        likelihood: Option<Py<PyAny>>,
        observation_size: Option<i128>,
        constants: Option<&Bound<'_, PyAny>>,
        name: &str,
        angular: Option<Vec<bool>>,
        bounds: Option<(Vec<f32>, Vec<f32>)>,
        resampler: &str,
        layers: i128,
        seed: i128,
        backend: &str,
        allow_software: bool,
        smooth: bool,
        lag: Option<i128>,
    ) -> PyResult<Self> {
        let lag = crate::lagged::lag_arg(lag)?;
        let observation_size: Option<usize> = whole_opt("observation_size", observation_size)?;
        let (dims, values) = finite_f32(initial, &[None, None, None], "initial")?;
        let shape = BatchShape::new(dims[0], dims[1], dims[2]).map_err(pf)?;
        let config = batch_config(shape, sigma, angular, bounds, layers, seed)?;
        let states = to_batch_layout(&values, &shape);
        let choice = Choice::parse(backend)?;
        let (engine, device) = match (wgsl, likelihood) {
            (Some(_), Some(_)) | (None, None) => {
                return Err(value_error(
                    "give the model either as wgsl= (GPU) or as likelihood= (a Python callable, CPU)",
                ));
            }
            (Some(source), None) => {
                let model = ModelSource {
                    name,
                    wgsl: &source,
                };
                let resampler = gpu_resampler(resampler)?;
                let gpu = GpuChoice {
                    choice,
                    allow_software,
                };
                wgsl_engine(
                    py,
                    &config,
                    &states,
                    model,
                    observation_size,
                    constants,
                    resampler,
                    gpu,
                )?
            }
            (None, Some(likelihood)) => {
                python_engine(py, &config, states, likelihood, resampler, choice)?
            }
        };
        let on_gpu = matches!(engine, Engine::Gpu { .. });
        let mut engine = engine;
        let cpu_lag = keep_lag(lag, &mut engine, shape, &config)?;
        Ok(Self {
            cpu_lag,
            history: History::for_filter(smooth, &engine, &config)?,
            on_gpu,
            engine: Mutex::new(engine),
            shape,
            device,
        })
    }

    /// What the filter runs on.
    #[getter]
    fn device(&self) -> &str {
        &self.device
    }

    /// (targets, particles, dimensions).
    #[getter]
    fn shape(&self) -> (usize, usize, usize) {
        (self.shape.targets, self.shape.particles, self.shape.dims)
    }

    /// One step against this frame's observations; returns a dict (see the stub).
    fn step<'py>(
        &self,
        py: Python<'py>,
        observations: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let shape = self.shape;
        let (estimates, spreads, ess, resampled, log_evidence, lagged) = if self.on_gpu {
            let (_, values) =
                finite_f32(observations, &[Some(shape.targets), None], "observations")?;
            py.detach(|| {
                let mut engine = self.engine.lock().map_err(|_| poisoned())?;
                let Engine::Gpu {
                    filter,
                    observation_values,
                } = &mut *engine
                else {
                    return Err(runtime_error("the filter's engine changed"));
                };
                if values.len() != shape.targets * *observation_values {
                    return Err(value_error(format!(
                        "observations must have shape ({}, {observation_values}), one Observation \
                         per target",
                        shape.targets
                    )));
                }
                let report = filter.step(&values).map_err(gpu)?;
                check_statuses(&report.status)?;
                Ok((
                    report.estimates,
                    report.spreads,
                    report.ess,
                    report.resampled,
                    report.log_evidence,
                    report.lagged,
                ))
            })?
        } else {
            let mut engine = self.try_lock()?;
            let Engine::Cpu { filter, likelihood } = &mut *engine else {
                return Err(runtime_error("the filter's engine changed"));
            };
            let callable = likelihood.bind(py);
            let mut raised: Option<PyErr> = None;
            let report = filter.step_batched(|shape, states, out| {
                match call_likelihood(py, callable, shape, states, observations, out) {
                    Ok(()) => Ok(()),
                    Err(e) => {
                        raised = Some(e);
                        Err(PfError::InvalidConfig("the likelihood raised".into()))
                    }
                }
            });
            if let Some(e) = raised {
                return Err(e);
            }
            let report = report.map_err(pf)?;
            check_statuses(&report.status)?;
            let lagged = self.cpu_lagged(filter)?;
            (
                report.estimates,
                report.spreads,
                report.ess,
                report.resampled,
                report.log_evidence,
                lagged,
            )
        };
        let (t, d) = (shape.targets, shape.dims);
        let out = PyDict::new(py);
        out.set_item("estimate", to_numpy(py, estimates, &[t, d])?)?;
        out.set_item("spread", to_numpy(py, spreads, &[t, d])?)?;
        out.set_item("ess", to_numpy(py, ess, &[t])?)?;
        out.set_item("resampled", to_numpy(py, resampled, &[t])?)?;
        out.set_item("log_evidence", to_numpy(py, log_evidence, &[t])?)?;
        let lagged = crate::lagged::lagged_dict(py, lagged.as_ref(), &shape)?;
        out.set_item("lagged", lagged)?;
        self.keep_for_smoothing(py)?;
        Ok(out)
    }

    /// Every step's values smoothed by the steps after it (needs `smooth=True`): a dict of
    /// `mean`, `lower`, `upper` (the 95 % credible interval), each (steps, T, D) float32.
    /// `motion` scales the random walk's σ the smoother reweighs by, or `"auto"` lets the
    /// evidence choose each target's values' scale (`pf_core::smooth::motion`; the dict then
    /// has `motion`, (T, D) float32, the scales chosen).
    #[pyo3(signature = (*, motion = None))]
    fn smoothed<'py>(
        &self,
        py: Python<'py>,
        motion: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let Some(History { steps, transition }) = &self.history else {
            return Err(value_error(
                "smoothed() needs ParticleFilter(..., smooth=True)",
            ));
        };
        let motion = match motion.filter(|m| !m.is_none()) {
            Some(m) => crate::smoothing::motion_argument("motion", m)?,
            None => SmoothMotion::Scale(1.0),
        };
        let transition = &motion.apply(transition.clone()).map_err(pf)?;
        let by_evidence = motion == SmoothMotion::ByEvidence;
        let kept = steps.lock().map_err(|_| poisoned())?.clone();
        let shape = self.shape;
        let (t, d) = (shape.targets, shape.dims);
        let steps = kept.len();
        let mut columns = [
            vec![0.0f32; steps * t * d],
            vec![0.0; steps * t * d],
            vec![0.0; steps * t * d],
        ];
        let per_target = py.detach(|| {
            (0..t)
                .map(|target| {
                    crate::smoothing::smooth_steps(&kept, (shape, target), transition, by_evidence)
                })
                .collect::<Result<Vec<(Vec<Vec<Summary>>, Vec<f32>)>, PfError>>()
        });
        let (per_target, chosen): (Vec<_>, Vec<_>) = per_target.map_err(pf)?.into_iter().unzip();
        for (target, frames) in per_target.into_iter().enumerate() {
            for (step, values) in frames.into_iter().enumerate() {
                for (dim, s) in values.into_iter().enumerate() {
                    let at = (step * t + target) * d + dim;
                    (columns[0][at], columns[1][at], columns[2][at]) = (s.mean, s.lower, s.upper);
                }
            }
        }
        let out = PyDict::new(py);
        for (name, values) in ["mean", "lower", "upper"].into_iter().zip(columns) {
            out.set_item(name, to_numpy(py, values, &[steps, t, d])?)?;
        }
        if by_evidence {
            out.set_item("motion", to_numpy(py, chosen.concat(), &[t, d])?)?;
        }
        Ok(out)
    }

    /// The particles after the last step: `(states, log_weights)`, shapes (T, M, D) and (T, M).
    fn particles<'py>(&self, py: Python<'py>) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
        let shape = self.shape;
        let (states, log_weights) = self.batch_particles(py)?;
        let (t, m, d) = (shape.targets, shape.particles, shape.dims);
        Ok((
            to_numpy(py, from_batch_layout(&states, &shape), &[t, m, d])?,
            to_numpy(py, log_weights, &[t, m])?,
        ))
    }
}

/// Where a WGSL model may run: the backend asked for, and whether a software adapter will do.
struct GpuChoice {
    choice: Choice,
    allow_software: bool,
}

/// The engine of a WGSL model: the whole step on the first GPU; its device's name.
#[allow(clippy::too_many_arguments)]
fn wgsl_engine(
    py: Python<'_>,
    config: &BatchConfig,
    states: &[f32],
    model: ModelSource<'_>,
    observation_size: Option<usize>,
    constants: Option<&Bound<'_, PyAny>>,
    resampler: GpuResampler,
    device: GpuChoice,
) -> PyResult<(Engine, String)> {
    let observation_values = observation_size.ok_or_else(|| {
        value_error("a WGSL model needs observation_size: the 32-bit values of one Observation")
    })?;
    if device.choice == Choice::Cpu {
        return Err(value_error(
            "a WGSL model runs on the GPU: use backend=\"gpu\" (or \"auto\"), or give \
             likelihood= for the CPU",
        ));
    }
    let constants = match constants {
        Some(c) => finite_f32(c, &[None], "constants")?.1,
        None => Vec::new(),
    };
    let mut contexts = open(py, Choice::Gpu, device.allow_software)?;
    let ctx = contexts.remove(0);
    let name = ctx.adapter().name.clone();
    let filter = py
        .detach(|| {
            let (values, constants) = (observation_values, &constants);
            RawModelFilter::new(&ctx, config, resampler, states, model, values, constants)
        })
        .map_err(gpu)?;
    let filter = Box::new(filter);
    Ok((
        Engine::Gpu {
            filter,
            observation_values,
        },
        name,
    ))
}

/// The engine of a Python likelihood: the step on the CPU, the callable weighing each frame.
fn python_engine(
    py: Python<'_>,
    config: &BatchConfig,
    states: Vec<f32>,
    likelihood: Py<PyAny>,
    resampler: &str,
    choice: Choice,
) -> PyResult<(Engine, String)> {
    if !likelihood.bind(py).is_callable() {
        return Err(value_error("likelihood must be callable"));
    }
    if matches!(choice, Choice::Gpu | Choice::AllGpus) {
        return Err(value_error(
            "a Python likelihood runs on the CPU: give wgsl= for the GPU",
        ));
    }
    let kind: ResamplerKind = resampler.parse().map_err(pf)?;
    let filter = Box::new(BatchFilter::new(config, kind.build(), states).map_err(pf)?);
    Ok((Engine::Cpu { filter, likelihood }, "CPU".to_string()))
}

/// The filter's configuration from the constructor's arguments: `layers` annealing layers with
/// the survival rule (1: none), checked.
fn batch_config(
    shape: BatchShape,
    sigma: Vec<f32>,
    angular: Option<Vec<bool>>,
    bounds: Option<(Vec<f32>, Vec<f32>)>,
    layers: i128,
    seed: i128,
) -> PyResult<BatchConfig> {
    let layers: usize = whole("layers", layers)?;
    let mut config = BatchConfig::new(shape, whole("seed", seed)?, sigma);
    if let Some(angular) = angular {
        config.angular = angular;
    }
    config.bounds = bounds;
    config.annealing = match layers {
        0 => return Err(value_error("layers must be at least 1")),
        1 => Annealing::none(),
        n => Annealing::survival(n, 0.5, 0.7),
    };
    config.validate().map_err(pf)?;
    Ok(config)
}

fn poisoned() -> PyErr {
    runtime_error("the filter failed in another thread and cannot go on")
}

impl ParticleFilter {
    /// The particles after the last step in the batch layout, and their log-weights.
    fn batch_particles(&self, py: Python<'_>) -> PyResult<(Vec<f32>, Vec<f32>)> {
        let engine = self.try_lock()?;
        Ok(match &*engine {
            Engine::Cpu { filter, .. } => (filter.states.clone(), filter.log_weights.clone()),
            Engine::Gpu { filter, .. } => py.detach(|| filter.particles()).map_err(gpu)?,
        })
    }

    /// With `smooth=True`, keeps the step's particles for [`Self::smoothed`].
    fn keep_for_smoothing(&self, py: Python<'_>) -> PyResult<()> {
        if let Some(history) = &self.history {
            let particles = self.batch_particles(py)?;
            history
                .steps
                .lock()
                .map_err(|_| poisoned())?
                .push(particles);
        }
        Ok(())
    }

    /// The engine, or an error when another thread is stepping this filter (waiting here while
    /// holding the GIL could deadlock with a Python likelihood that needs it).
    fn try_lock(&self) -> PyResult<std::sync::MutexGuard<'_, Engine>> {
        match self.engine.try_lock() {
            Ok(guard) => Ok(guard),
            Err(TryLockError::WouldBlock) => Err(runtime_error(
                "this ParticleFilter is being stepped by another thread; give each thread its own",
            )),
            Err(TryLockError::Poisoned(_)) => Err(poisoned()),
        }
    }
}

/// `lag=`: the GPU engine keeps its window on the device (None returned); the CPU engine's is the
/// host's twin, returned to be pushed after each step.
fn keep_lag(
    lag: Option<usize>,
    engine: &mut Engine,
    shape: BatchShape,
    config: &BatchConfig,
) -> PyResult<Option<Mutex<pf_core::smooth::lag_window::LagWindow>>> {
    match (lag, engine) {
        (Some(lag), Engine::Gpu { filter, .. }) => {
            filter
                .engine_mut()
                .keep_lag_window(lag, false)
                .map_err(gpu)?;
            Ok(None)
        }
        (Some(lag), Engine::Cpu { .. }) => Ok(Some(crate::lagged::cpu_window(
            shape,
            lag,
            config.angular.clone(),
        )?)),
        (None, _) => Ok(None),
    }
}

impl ParticleFilter {
    /// The CPU filter's step `lag` back from its host window (`lag=`), after a step.
    fn cpu_lagged(
        &self,
        filter: &BatchFilter<Box<dyn Resampler>>,
    ) -> PyResult<Option<pf_core::smooth::lag_window::LaggedSummaries>> {
        let Some(window) = &self.cpu_lag else {
            return Ok(None);
        };
        let mut window = window.lock().map_err(|_| poisoned())?;
        (window.push(&filter.states, &filter.log_weights, filter.lineage())).map_err(pf)
    }
}

/// Each target's status from either engine: an error names the target and what went wrong with
/// its weights.
fn check_statuses(statuses: &[Result<(), PfError>]) -> PyResult<()> {
    for (target, status) in statuses.iter().enumerate() {
        if let Err(e) = status {
            return Err(runtime_error(format!(
                "target {target}: {e}; its weights were left uniform"
            )));
        }
    }
    Ok(())
}

/// Calls the Python likelihood with the particles as a (T, M, D) array and the observations,
/// and copies its (T, M) log-likelihoods into `out`.
fn call_likelihood(
    py: Python<'_>,
    callable: &Bound<'_, PyAny>,
    shape: &BatchShape,
    states: &[f32],
    observations: &Bound<'_, PyAny>,
    out: &mut [f32],
) -> PyResult<()> {
    let (t, m, d) = (shape.targets, shape.particles, shape.dims);
    let particles = to_numpy(py, from_batch_layout(states, shape), &[t, m, d])?;
    let result = callable.call1(PyTuple::new(py, [particles, observations.clone()])?)?;
    let numpy = py.import("numpy")?;
    let kwargs = PyDict::new(py);
    kwargs.set_item("dtype", "float32")?;
    let array = numpy
        .call_method("ascontiguousarray", (result,), Some(&kwargs))
        .map_err(|e| {
            value_error(format!(
                "the likelihood must return a (T, M) array of numbers: {e}"
            ))
        })?;
    let array = contiguous::<f32>(&array, "the likelihood's result", "float32")?;
    crate::arrays::check_shape(
        array.shape(),
        &[Some(t), Some(m)],
        "the likelihood's result",
    )?;
    let values = array
        .as_slice()
        .map_err(|e| value_error(format!("the likelihood's result: {e}")))?;
    // −∞ is a zero likelihood; NaN and +∞ are the callable's mistakes.
    if let Some(i) = values
        .iter()
        .position(|v| v.is_nan() || *v == f32::INFINITY)
    {
        check_finite(&values[i..=i], "the likelihood's result")?;
    }
    out.copy_from_slice(values);
    Ok(())
}
