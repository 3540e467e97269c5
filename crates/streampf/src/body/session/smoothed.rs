//! `--smooth` / `--smooth-lag` in a body run: each frame's samples go to the smoother as the
//! frame is written; smoothed.csv gets the rows, and with ground truth the smoothed poses'
//! joint errors and their intervals' coverage are summed for the summary.

use body_tracker::{BodyTracker, Skeleton, mean_joint_error};
use std::path::Path;

use crate::smoothing::{Coverage, LagSmoother, SlotTrack, SmoothArgs, SmoothedRow, Smoother};

/// A body run's smoother and what its rows scored against the truth.
pub(in crate::body) struct BodySmoothing {
    smoother: Smoother,
    angular: Vec<bool>,
    /// Summed joint errors of the smoothed means and of the filtered weighted means of the
    /// same samples.
    errors: [f64; 2],
    compared: usize,
    coverage: [Coverage; 2],
}

impl BodySmoothing {
    /// The run's smoother, when `--smooth` or `--smooth-lag` asks for one: a lag keeps the
    /// filter's lineage whichever way it smooths (a restart, with no ancestors, ends a lag
    /// window), and `--lag-smoother` is resolved for the tracker's annealing. Islands over
    /// several GPUs trade particles and keep no ancestry: refused there.
    pub(in crate::body) fn for_run(
        out: &Path,
        asked: &SmoothArgs,
        tracker: &mut BodyTracker,
        with_truth: bool,
    ) -> anyhow::Result<Option<Self>> {
        let Some(lag) = asked.mode() else {
            return Ok(None);
        };
        let how = asked.lag_smoother_for(tracker.annealing_layers()?);
        if lag.is_some() {
            tracker.keep_lineage()?;
            if how == LagSmoother::Ancestry && tracker.lineage()?.is_none() {
                anyhow::bail!(
                    "--smooth-lag traces the particles' ancestry, which islands over several GPUs do not keep (they trade particles): use --lag-smoother marginal, --smooth full, or one GPU"
                );
            }
        }
        let transition = asked.transition(tracker.transition()?)?;
        let on_gpu = tracker.gpu_context().is_some();
        let on_device = crate::smoothing::keep_lag_on_device((lag, how), on_gpu, "samples", |l| {
            Ok(tracker.keep_lag_window(l, with_truth)?)
        });
        let smoothing = Self::create(
            out,
            (lag, how),
            tracker,
            (transition, asked.by_evidence()),
            with_truth,
        )?;
        Ok(Some(if on_device {
            let angular = smoothing.angular.clone();
            Self {
                smoother: (smoothing.smoother).on_device(angular.len(), angular, with_truth),
                ..smoothing
            }
        } else {
            smoothing
        }))
    }

    /// smoothed.csv in `out`, with `lag` (`None`: the whole run), under `transition`, or at the
    /// motion the evidence chooses when `by_evidence` (`--smooth-motion auto`: on the CPU, so no
    /// GPU smoother is built).
    fn create(
        out: &Path,
        (lag, how): (Option<usize>, crate::smoothing::LagSmoother),
        tracker: &BodyTracker,
        (transition, by_evidence): (pf_core::smooth::GaussianTransition, bool),
        with_truth: bool,
    ) -> anyhow::Result<Self> {
        let names = tracker.skeleton().pose_names();
        let angular = transition.angular.clone();
        let smoother = Smoother::create(
            out,
            lag,
            transition,
            tracker.motion_gain(),
            &names,
            false,
            tracker.gpu_context().filter(|_| !by_evidence),
        )?
        .lagging_by(how);
        let smoother = if by_evidence {
            smoother.choosing_motion_by_evidence()
        } else {
            smoother
        };
        // The filtered summaries are scored beside the smoothed ones only against a truth.
        let smoother = if with_truth {
            smoother.comparing_filtered()
        } else {
            smoother
        };
        Ok(Self {
            smoother,
            angular,
            errors: [0.0; 2],
            compared: 0,
            coverage: Default::default(),
        })
    }

    /// A written frame: the tracker's samples go to the smoother.
    pub(in crate::body) fn add(
        &mut self,
        frame: usize,
        tracker: &BodyTracker,
        truth: Option<&[Vec<f32>]>,
    ) -> anyhow::Result<()> {
        let rows = if self.smoother.is_on_device() {
            // One target, the body, never restarted.
            let tracking = [SlotTrack {
                slot: 0,
                track: 0,
                restarted: false,
            }];
            let mut read = read_from(tracker);
            (self.smoother).add_device_frame(frame, &tracking, tracker.lagged(), &mut read)?
        } else {
            let (_, states, log_weights) = tracker.particles()?;
            let cloud = crate::smoothing::TrackCloud {
                track: 0,
                states,
                log_weights,
                lineage: tracker.lineage()?,
            };
            self.smoother.add_frame(frame, vec![cloud])?
        };
        self.score(tracker.skeleton(), &rows, truth)
    }

    /// Smooths and writes what is still waiting (the run's end, however it ended).
    pub(in crate::body) fn finish(
        &mut self,
        tracker: &BodyTracker,
        truth: Option<&[Vec<f32>]>,
    ) -> anyhow::Result<()> {
        let rows = if self.smoother.is_on_device() {
            self.smoother.finish_device(&mut read_from(tracker))?
        } else {
            self.smoother.finish()?
        };
        self.score(tracker.skeleton(), &rows, truth)
    }

    fn score(
        &mut self,
        skeleton: &Skeleton,
        rows: &[SmoothedRow],
        truth: Option<&[Vec<f32>]>,
    ) -> anyhow::Result<()> {
        let Some(truth) = truth else { return Ok(()) };
        for row in rows {
            let Some(t) = truth.get(row.frame) else {
                continue;
            };
            for (k, values) in [&row.values, &row.filtered].into_iter().enumerate() {
                let pose: Vec<f32> = values.iter().map(|s| s.mean).collect();
                self.errors[k] += f64::from(mean_joint_error(skeleton, &pose, t)?);
                self.coverage[k].add(values, t, &self.angular);
            }
            self.compared += 1;
        }
        Ok(())
    }

    /// The summary's lines for smoothed.csv (and, with ground truth, its errors and coverage).
    pub(in crate::body) fn print(&self) {
        self.smoother.report_fallback();
        self.smoother.report_ancestry();
        self.smoother.report_motion();
        let how = self.smoother.how();
        if self.compared == 0 {
            outln!("smoothed {how}: wrote smoothed.csv");
            return;
        }
        let n = self.compared as f64;
        let share = |k: usize| {
            let p = self.coverage[k].percent();
            p.iter().sum::<f64>() / p.len().max(1) as f64
        };
        outln!(
            "smoothed {how}: mean joint position error: {:.4} m over {} frames (the filter's weighted mean of the same samples: {:.4} m); the 95 % intervals held the truth for {:.0}% of the pose values (the filtered ones: {:.0}%)",
            self.errors[0] / n,
            self.compared,
            self.errors[1] / n,
            share(0),
            share(1)
        );
    }
}

/// Reads the body's frames back from the tracker's lag window (`BodyTracker::lag_frames`).
fn read_from(
    tracker: &BodyTracker,
) -> impl FnMut(
    usize,
    u64,
    usize,
) -> Result<Vec<pf_core::smooth::lag_window::LagFrame>, pf_core::PfError>
+ '_ {
    |_, first_step, count| {
        (tracker.lag_frames(first_step, count)).map_err(|e| pf_core::PfError::Device(e.to_string()))
    }
}
