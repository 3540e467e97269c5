//! The experiments, one figure each. Every experiment knows how many measurements it will make
//! (for the progress bar) and makes them with the run's timing plan, on the run's GPU when there
//! is one; CPU baselines run in the same process on the same host.

mod accuracy;
mod body_speed;
mod face_speed;
mod posterior;
mod resamplers;

use indicatif::ProgressBar;
use pf_gpu::GpuContext;

use crate::record::Figure;
use crate::timing::TimingPlan;

/// What an experiment is given.
pub struct Run<'a> {
    pub quick: bool,
    pub plan: TimingPlan,
    /// The adapter for the GPU series (hardware, or software in quick mode / when allowed).
    pub gpu: Option<&'a GpuContext>,
    pub progress: &'a ProgressBar,
    /// The body likelihood against points, measured once for Fig. 5 and Fig. 6.
    pub(crate) body_points: Option<body_speed::PointsAxis>,
}

impl<'a> Run<'a> {
    pub fn new(
        quick: bool,
        plan: TimingPlan,
        gpu: Option<&'a GpuContext>,
        progress: &'a ProgressBar,
    ) -> Self {
        Self {
            quick,
            plan,
            gpu,
            progress,
            body_points: None,
        }
    }

    /// The GPU for tracking runs: a hardware adapter only (on a software one the CPU path is
    /// faster and gives the same accuracy).
    pub fn hardware_gpu(&self) -> Option<&'a GpuContext> {
        self.gpu.filter(|c| !c.adapter().is_software())
    }

    pub fn step(&self, what: &str) {
        self.progress.set_message(what.to_string());
        self.progress.inc(1);
    }
}

/// One figure's experiment.
pub struct Experiment {
    /// The figure's name (`--only`, file stem).
    pub name: &'static str,
    pub about: &'static str,
    /// Measurements it will make (the progress bar's share).
    pub steps: fn(quick: bool) -> u64,
    pub run: fn(&mut Run) -> anyhow::Result<Figure>,
}

/// Every experiment, in the report's order.
pub const EXPERIMENTS: [Experiment; 8] = [
    Experiment {
        name: "face-fig6",
        about: "face paper Fig. 6: weighting time against particles",
        steps: face_speed::fig6_steps,
        run: face_speed::fig6,
    },
    Experiment {
        name: "face-fig7",
        about: "face paper Fig. 7: the whole step against faces",
        steps: face_speed::fig7_steps,
        run: face_speed::fig7,
    },
    Experiment {
        name: "body-fig5",
        about: "body paper Fig. 5: likelihood time against points and against samples",
        steps: body_speed::fig5_steps,
        run: body_speed::fig5,
    },
    Experiment {
        name: "body-fig6",
        about: "body paper Fig. 6: speed-up over one CPU thread (Listing 1.2) against points",
        steps: body_speed::fig6_steps,
        run: body_speed::fig6,
    },
    Experiment {
        name: "accuracy-face",
        about: "per-frame face pose error on the synthetic four-face video, with the flat baseline",
        steps: accuracy::face_steps,
        run: accuracy::face,
    },
    Experiment {
        name: "accuracy-body",
        about: "per-frame and per-joint body error on the synthetic walk-wave, with the flat baseline",
        steps: accuracy::body_steps,
        run: accuracy::body,
    },
    Experiment {
        name: "posterior",
        about: "smoothed trajectories with 95 % intervals: a random walk against RTS, a face's yaw",
        steps: posterior::steps,
        run: posterior::run,
    },
    Experiment {
        name: "resamplers",
        about: "resamplers: time against N and spread of offspring counts, CPU and GPU",
        steps: resamplers::steps,
        run: resamplers::run,
    },
];

/// The number of CPU threads of the all-cores series, for their names.
pub(crate) fn cores() -> usize {
    rayon::current_num_threads()
}

/// A pool of one thread for the one-thread baselines.
pub(crate) fn one_thread() -> anyhow::Result<rayon::ThreadPool> {
    Ok(rayon::ThreadPoolBuilder::new().num_threads(1).build()?)
}
