//! `--smooth` / `--smooth-lag` in a face run: each tracked face's particles go to the smoother
//! as its frame is written; smoothed.csv gets the rows, and with ground truth the smoothed
//! estimates' errors and their intervals' coverage are summed for the summary.

use face_tracker::projection::{DIMS, STATE_NAMES};
use face_tracker::tracker::{ANGULAR, pose_errors};
use face_tracker::{FaceEstimate, FaceTracker};
use std::path::Path;

use crate::face::runner::Runner;
use crate::smoothing::{Coverage, SmoothArgs, SmoothedRow, Smoother};

/// A face run's smoother and what its rows scored against the truth.
pub(super) struct FaceSmoothing {
    smoother: Smoother,
    /// Summed errors of the smoothed means, and of the filtered weighted means of the same
    /// particles (the estimate smoothing improves on).
    errors: [(f64, f64); 2],
    compared: usize,
    coverage: [Coverage; 2],
}

impl FaceSmoothing {
    /// The run's smoother, when `--smooth` or `--smooth-lag` asks for one: a lag keeps the
    /// filter's lineage whichever way it smooths (a restart, with no ancestors, ends a lag
    /// window), and `--lag-smoother` is resolved for the tracker's annealing.
    pub(super) fn for_run(
        out: &Path,
        asked: &SmoothArgs,
        runner: &mut Runner,
        with_truth: bool,
    ) -> anyhow::Result<Option<Self>> {
        let Some(lag) = asked.mode() else {
            return Ok(None);
        };
        if lag.is_some() {
            runner.keep_lineage()?;
        }
        let how = asked.lag_smoother_for(runner.tracker().annealing_layers());
        let transition = asked.transition(runner.tracker().transition())?;
        let on_gpu = runner.tracker().gpu_context().is_some();
        let on_device =
            crate::smoothing::keep_lag_on_device((lag, how), on_gpu, "particles", |l| {
                runner.keep_lag_window(l, with_truth)
            });
        let smoothing = Self::create(
            out,
            (lag, how),
            runner.tracker(),
            (transition, asked.by_evidence()),
            with_truth,
        )?;
        Ok(Some(if on_device {
            Self {
                smoother: smoothing
                    .smoother
                    .on_device(DIMS, ANGULAR.to_vec(), with_truth),
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
        tracker: &FaceTracker,
        (transition, by_evidence): (pf_core::smooth::GaussianTransition, bool),
        with_truth: bool,
    ) -> anyhow::Result<Self> {
        let names: Vec<String> = STATE_NAMES.iter().map(|n| n.to_string()).collect();
        let smoother = Smoother::create(
            out,
            lag,
            transition,
            tracker.motion_gain(),
            &names,
            true,
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
            errors: [(0.0, 0.0); 2],
            compared: 0,
            coverage: Default::default(),
        })
    }

    /// A tracked frame: every face being tracked gives the smoother its slot's particles.
    pub(super) fn add(
        &mut self,
        frame: usize,
        tracker: &FaceTracker,
        estimates: &[FaceEstimate],
        truth: Option<&[Vec<[f32; DIMS]>]>,
    ) -> anyhow::Result<()> {
        let rows = if self.smoother.is_on_device() {
            let tracking = tracker.slot_tracks(estimates);
            let mut read = read_from(tracker);
            (self.smoother).add_device_frame(frame, &tracking, tracker.lagged(), &mut read)?
        } else {
            self.smoother
                .add_frame(frame, tracker.track_clouds(estimates)?)?
        };
        self.score(&rows, truth);
        Ok(())
    }

    /// Smooths and writes what is still waiting (the run's end, however it ended).
    pub(super) fn finish(
        &mut self,
        tracker: &FaceTracker,
        truth: Option<&[Vec<[f32; DIMS]>]>,
    ) -> anyhow::Result<()> {
        let rows = if self.smoother.is_on_device() {
            self.smoother.finish_device(&mut read_from(tracker))?
        } else {
            self.smoother.finish()?
        };
        self.score(&rows, truth);
        Ok(())
    }

    fn score(&mut self, rows: &[SmoothedRow], truth: Option<&[Vec<[f32; DIMS]>]>) {
        let Some(truth) = truth else { return };
        for row in rows {
            let Some(t) = truth.get(row.frame).and_then(|f| f.get(row.track)) else {
                continue;
            };
            if !t.iter().all(|v| v.is_finite()) {
                continue;
            }
            for (k, values) in [&row.values, &row.filtered].into_iter().enumerate() {
                let state: [f32; DIMS] = std::array::from_fn(|d| values[d].mean);
                let (te, re) = pose_errors(&state, t);
                self.errors[k].0 += f64::from(te);
                self.errors[k].1 += f64::from(re);
                self.coverage[k].add(values, t, &ANGULAR);
            }
            self.compared += 1;
        }
    }

    /// The summary's line for smoothed.csv (and, with ground truth, its errors and coverage).
    pub(super) fn print(&self) {
        self.smoother.report_fallback();
        self.smoother.report_ancestry();
        self.smoother.report_motion();
        let how = self.smoother.how();
        if self.compared == 0 {
            outln!("smoothed {how}: wrote smoothed.csv");
            return;
        }
        let n = self.compared as f64;
        let coverage = |k: usize| -> String {
            (STATE_NAMES.iter().zip(self.coverage[k].percent()))
                .map(|(name, p)| format!("{name} {p:.0} %"))
                .collect::<Vec<_>>()
                .join(", ")
        };
        let [(st, sr), (ft, fr)] = self.errors;
        outln!(
            "smoothed {how}: mean translation error: {:.2} px, mean rotation error: {:.2} deg ({} face-frames; the filter's weighted mean of the same particles: {:.2} px, {:.2} deg)",
            st / n,
            sr / n,
            self.compared,
            ft / n,
            fr / n
        );
        outln!(
            "the smoothed 95 % intervals held the truth: {} (the filtered ones: {})",
            coverage(0),
            coverage(1)
        );
    }
}

/// Reads a slot's frames back from the tracker's lag window (`FaceTracker::lag_frames`).
fn read_from(
    tracker: &FaceTracker,
) -> impl FnMut(
    usize,
    u64,
    usize,
) -> Result<Vec<pf_core::smooth::lag_window::LagFrame>, pf_core::PfError>
+ '_ {
    |slot, first_step, count| {
        (tracker.lag_frames(slot, first_step, count))
            .map_err(|e| pf_core::PfError::Device(e.to_string()))
    }
}
