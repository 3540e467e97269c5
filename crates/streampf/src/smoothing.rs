//! `--smooth full` and `--smooth-lag L`: every tracked frame smoothed by the frames after it,
//! written to smoothed.csv with each value's smoothed mean and 95 % credible interval. `full`
//! smooths each track over the whole run when it ends (or the run does) by the marginal smoother
//! (`pf_core::smooth`), each value as its own block (a blocked smoother, Finke & Singh 2017: the
//! particles' filtered weights carry what the values share, and the backward weights of many
//! values at once collapse). `--smooth-lag L` writes frame t − L once frame t is tracked, smoothed
//! from the particles' ancestry (`pf_core::smooth::ancestry`: the weights of each particle's
//! descendants L frames on, traced through the engine's lineage; on a GPU, in a lag window kept
//! there, `pf_gpu::GpuFilter::keep_lag_window`, whose summaries `LaggedTracks` turns into rows).
//! A run that is interrupted or fails smooths and writes what it had tracked.

use std::path::Path;

use clap::Args;
use pf_core::smooth::GaussianTransition;
use pf_core::smooth::motion::{EvidenceMotion, SmoothMotion};
pub use pf_core::smooth_tracks::{
    Coverage, LagSmoother, LaggedTracks, ReadFrames, SlotTrack, SmoothedRow, TrackCloud,
    TrackSmoother,
};

use crate::run_output::CsvStream;

/// The file the smoothed values go to.
pub const SMOOTHED_FILE: &str = "smoothed.csv";

#[derive(Debug, Clone, Default, Args)]
pub struct SmoothArgs {
    /// Also write smoothed.csv: every tracked frame's values smoothed over the whole run (each
    /// track's when it ends), with 95 % credible intervals. Keeps every frame's particles in
    /// memory (particles × values × 4 bytes a track a frame) and reads them back from a GPU.
    #[arg(long, value_parser = ["full"], conflicts_with = "smooth_lag", group = "smoother")]
    pub smooth: Option<String>,
    /// Also write smoothed.csv online: frame t − L smoothed by the frames up to t (by its
    /// particles' descendants at frame t), written once frame t is tracked. From the ancestry on
    /// a GPU the last L + 2 frames stay on the GPU and only each frame's summaries come back;
    /// otherwise the host keeps L frames' particles a track (read back from a GPU each frame).
    #[arg(
        long,
        value_name = "L",
        value_parser = clap::value_parser!(u32).range(1..=1000),
        group = "smoother"
    )]
    pub smooth_lag: Option<u32>,
    /// How `--smooth-lag` smooths: `ancestry` (by each particle's descendants L frames on:
    /// cheap, online; an annealed tracker's many resamplings leave few descendants, which narrows
    /// the intervals), `marginal` (the marginal smoother over the window: L backward passes of
    /// particles² a value, track and frame, on the tracker's GPU where it has one), or `auto`
    /// (ancestry for a filter that resamples once a frame, marginal for an annealed one).
    #[arg(long, value_enum, default_value = "auto", requires = "smooth_lag")]
    pub lag_smoother: LagSmootherArg,
    /// How far the marginal smoother lets a value move from one frame to the next, as a share
    /// of the tracker's own diffusion over a frame (its annealing layers' random walks composed,
    /// the default 1): below 1 it holds the track to slower motion, steadier and with narrower
    /// intervals, and lags a head that turns (docs/ACCURACY.md, "Smoothing against the mesh's
    /// jitter"). From 0.001 to 1000. `auto`: each track's values each get the share the
    /// evidence favours among 1, 1/2 ... 1/64 (the filter re-weighted to each; on the CPU's
    /// cores, wherever the tracker runs): over the whole track with --smooth full, over the
    /// track's frames so far with --smooth-lag. The ancestry smoother has no motion to scale.
    #[arg(
        long,
        value_name = "SCALE|auto",
        value_parser = smooth_motion,
        allow_negative_numbers = true,
        requires = "smoother"
    )]
    pub smooth_motion: Option<SmoothMotion>,
}

/// `--smooth-motion`: `auto` or a number in `pf_core::smooth::MOTION_SCALES`.
fn smooth_motion(text: &str) -> Result<SmoothMotion, String> {
    SmoothMotion::parse(text).map_err(|e| e.to_string())
}

/// `--lag-smoother`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum LagSmootherArg {
    #[default]
    Auto,
    Ancestry,
    Marginal,
}

impl LagSmootherArg {
    /// The smoother for a filter of `layers` annealing layers: `auto` traces the ancestry only
    /// through one resampling a frame (measured: the annealed trackers' ancestry keeps a few per
    /// cent of a frame's effective sample size one frame back; the face's intervals held the
    /// truth 53-70 % of the time at a lag of 8, the body's 56 % at a lag of 1), and only when no
    /// motion was asked for (`moving`: `--smooth-motion`, which only the marginal smoother has).
    pub fn resolve(self, layers: usize, moving: bool) -> LagSmoother {
        match self {
            Self::Auto if layers > 1 || moving => LagSmoother::Marginal,
            Self::Auto | Self::Ancestry => LagSmoother::Ancestry,
            Self::Marginal => LagSmoother::Marginal,
        }
    }
}

impl SmoothArgs {
    /// Refuses what the arguments alone show cannot be smoothed as asked, before a run touches
    /// its output: `--smooth-motion` with `--lag-smoother ancestry`, which has no motion. (With
    /// `--smooth-lag`, `--smooth-motion auto` chooses by the evidence of every frame of a track
    /// so far: `pf_core::smooth::motion::OnlineMotion`.)
    pub fn check(&self) -> anyhow::Result<()> {
        if self.smooth_motion.is_some() && self.lag_smoother == LagSmootherArg::Ancestry {
            anyhow::bail!(
                "--smooth-motion scales the marginal smoother's motion; --lag-smoother ancestry has none: use --lag-smoother marginal (or auto)"
            );
        }
        Ok(())
    }

    /// The lag smoother for a filter of `layers` annealing layers (`--lag-smoother`).
    pub fn lag_smoother_for(&self, layers: usize) -> LagSmoother {
        self.lag_smoother
            .resolve(layers, self.smooth_motion.is_some())
    }

    /// The tracker's transition with `--smooth-motion`'s scale applied to every σ (the parser
    /// kept the scale in range; `auto` chooses per value as the tracks are smoothed).
    pub fn transition(&self, tracker: GaussianTransition) -> anyhow::Result<GaussianTransition> {
        match self.smooth_motion {
            Some(motion) => Ok(motion.apply(tracker)?),
            None => Ok(tracker),
        }
    }

    /// Whether `--smooth-motion auto` asks the evidence to choose each value's motion.
    pub fn by_evidence(&self) -> bool {
        self.smooth_motion == Some(SmoothMotion::ByEvidence)
    }

    /// `None`: no smoothing; `Some(None)`: the whole run; `Some(Some(L))`: a lag of L frames.
    pub fn mode(&self) -> Option<Option<usize>> {
        match (&self.smooth, self.smooth_lag) {
            (_, Some(lag)) => Some(Some(lag as usize)),
            (Some(_), None) => Some(None),
            (None, None) => None,
        }
    }
}

/// Whether a run's lag window is kept on its tracker's GPU: smoothing from the ancestry with a
/// lag, on a GPU, where `keep` (the tracker's `keep_lag_window`) succeeds. A GPU that refuses it
/// (its workgroup memory cannot hold a target's `what`) leaves the run reading them back each
/// frame and smoothing on the host, said on stderr.
pub fn keep_lag_on_device(
    (lag, how): (Option<usize>, LagSmoother),
    on_gpu: bool,
    what: &str,
    keep: impl FnOnce(usize) -> anyhow::Result<()>,
) -> bool {
    let Some(lag) = lag else { return false };
    if how != LagSmoother::Ancestry || !on_gpu {
        return false;
    }
    match keep(lag) {
        Ok(()) => true,
        Err(e) => {
            errln!("note: smoothing on the host, reading the {what} back each frame ({e:#})");
            false
        }
    }
}

/// The smoother of a run: a [`TrackSmoother`] whose rows go to smoothed.csv, or, smoothing from
/// the ancestry on the tracker's GPU, a [`LaggedTracks`] turning its summaries into rows.
pub struct Smoother {
    tracks: TrackSmoother,
    /// The rows of a lag window the tracker's GPU keeps ([`Smoother::on_device`]).
    device: Option<LaggedTracks>,
    lag: Option<usize>,
    how: LagSmoother,
    /// The GPU smoother, when the backward passes run on a GPU (for its fallback report).
    on_gpu: Option<std::sync::Arc<pf_gpu::smooth::OnGpu>>,
    /// The evidence's choices of motion, when it chooses them (`--smooth-motion auto`).
    by_evidence: Option<std::sync::Arc<EvidenceMotion>>,
    /// The values' names, for the report of the motion chosen.
    names: Vec<String>,
    file: CsvStream,
    with_track: bool,
}

impl Smoother {
    /// smoothed.csv in `out` (created, or truncated: a resumed run re-tracks every frame) with
    /// `frame`, `track` (when `with_track`), then `NAME`, `NAME_lo`, `NAME_hi` for each value.
    /// With `gpu`, the backward passes run on that GPU (`pf_gpu::smooth::OnGpu`; the tracker's
    /// own), else on the CPU's cores.
    pub fn create(
        out: &Path,
        lag: Option<usize>,
        transition: GaussianTransition,
        gain: f32,
        names: &[String],
        with_track: bool,
        gpu: Option<&pf_gpu::GpuContext>,
    ) -> anyhow::Result<Self> {
        let columns: Vec<String> = (names.iter())
            .map(|n| format!("{n},{n}_lo,{n}_hi"))
            .collect();
        let lead = if with_track { "frame,track" } else { "frame" };
        let header = format!("{lead},{}", columns.join(","));
        let mut tracks = TrackSmoother::new(lag, transition, gain);
        let on_gpu = match gpu {
            Some(ctx) => Some(std::sync::Arc::new(
                pf_gpu::smooth::OnGpu::new(ctx)
                    .map_err(|e| anyhow::anyhow!("building the GPU smoother: {e}"))?,
            )),
            None => None,
        };
        if let Some(on_gpu) = &on_gpu {
            tracks = tracks.on(on_gpu.clone());
        }
        Ok(Self {
            tracks,
            device: None,
            lag,
            how: LagSmoother::default(),
            on_gpu,
            by_evidence: None,
            names: names.to_vec(),
            file: CsvStream::create(&out.join(SMOOTHED_FILE), &header)?,
            with_track,
        })
    }

    /// The same smoother with each track's values' motion chosen by the evidence
    /// (`--smooth-motion auto`: `pf_core::smooth::motion::EvidenceMotion`, on the CPU's cores;
    /// create it without a GPU).
    pub fn choosing_motion_by_evidence(mut self) -> Self {
        let chooser = std::sync::Arc::new(EvidenceMotion::default());
        self.tracks = self.tracks.choosing_motion_by_evidence(chooser.clone());
        self.by_evidence = Some(chooser);
        self
    }

    /// The motion the evidence chose (`--smooth-motion auto`), on stdout: each value's median
    /// share of the tracker's motion over the tracks smoothed.
    pub fn report_motion(&self) {
        let Some(chooser) = &self.by_evidence else {
            return;
        };
        let Some(medians) = chooser.median_scales(self.names.len()) else {
            return;
        };
        let values: Vec<String> = (self.names.iter().zip(medians))
            .map(|(name, scale)| format!("{name} {scale}"))
            .collect();
        outln!(
            "the evidence chose the smoother's motion, as a share of the tracker's (median over {} tracks): {}",
            chooser.choices().len(),
            values.join(", ")
        );
    }

    /// The same smoother giving each row the filtered summary too (to score both against a
    /// truth).
    pub fn comparing_filtered(mut self) -> Self {
        self.tracks = self.tracks.comparing_filtered();
        self
    }

    /// The same smoother with its lag windows smoothed by `how`.
    pub fn lagging_by(mut self, how: LagSmoother) -> Self {
        self.tracks = self.tracks.lagging_by(how);
        self.how = how;
        self
    }

    /// The same smoother taking its lag rows from a lag window on the tracker's GPU (smoothing
    /// from the ancestry: [`Smoother::add_device_frame`]), for values flagged `angular`, with the
    /// filtered summaries beside them when `compare_filtered` (the GPU must make them too).
    pub fn on_device(mut self, dims: usize, angular: Vec<bool>, compare_filtered: bool) -> Self {
        if let Some(lag) = self.lag {
            self.device = Some(LaggedTracks::new(lag, dims, angular, compare_filtered));
            self.how = LagSmoother::Ancestry;
        }
        self
    }

    /// Whether the lag rows come from the tracker's GPU ([`Smoother::on_device`]).
    pub fn is_on_device(&self) -> bool {
        self.device.is_some()
    }

    /// How this run smooths, for its summary: "over the whole run" or "with a lag of L frames
    /// (from the ancestry)".
    pub fn how(&self) -> String {
        match (self.lag, self.how) {
            (Some(lag), _) if self.device.is_some() => {
                format!("with a lag of {lag} frames (from the ancestry, on the GPU)")
            }
            (None, _) => "over the whole run".to_string(),
            (Some(lag), LagSmoother::Ancestry) => {
                format!("with a lag of {lag} frames (from the ancestry)")
            }
            (Some(lag), LagSmoother::Marginal) => {
                format!("with a lag of {lag} frames (the marginal smoother)")
            }
        }
    }

    /// What smoothing from the ancestry kept of the lagged frames' effective sample size, on
    /// stdout (path degeneracy: the less, the narrower the intervals).
    pub fn report_ancestry(&self) {
        let health = match &self.device {
            Some(device) => Some(device.health()),
            None => self.tracks.ancestry_health(),
        };
        let Some(health) = health else {
            return;
        };
        if health.rows == 0 {
            return;
        }
        outln!(
            "smoothing from the ancestry kept {:.0} % of each lagged frame's effective sample size on average ({} of {} rows under 10 %)",
            100.0 * health.mean_kept,
            health.below_a_tenth,
            health.rows
        );
    }

    /// Says so on stderr if the GPU smoother failed and handed tracks to the CPU (their rows
    /// are written all the same).
    pub fn report_fallback(&self) {
        if self.on_gpu.as_ref().is_some_and(|g| g.fell_back()) {
            errln!(
                "warning: the GPU smoother failed (a device fault); the tracks it could not smooth were smoothed on the CPU"
            );
        }
    }

    /// [`TrackSmoother::add_frame`], its rows written.
    pub fn add_frame(
        &mut self,
        frame: usize,
        clouds: Vec<TrackCloud>,
    ) -> anyhow::Result<Vec<SmoothedRow>> {
        let rows = (self.tracks.add_frame(frame, clouds))
            .map_err(|e| anyhow::anyhow!("smoothing frame {frame}: {e}"))?;
        self.write(&rows)?;
        Ok(rows)
    }

    /// [`LaggedTracks::add_frame`] (a lag window on the tracker's GPU), its rows written.
    pub fn add_device_frame(
        &mut self,
        frame: usize,
        tracking: &[SlotTrack],
        lagged: Option<&pf_core::smooth::lag_window::LaggedSummaries>,
        read: &mut ReadFrames<'_>,
    ) -> anyhow::Result<Vec<SmoothedRow>> {
        let device = (self.device.as_mut())
            .ok_or_else(|| anyhow::anyhow!("no lag window on the GPU to smooth from"))?;
        let rows = (device.add_frame(frame, tracking, lagged, read))
            .map_err(|e| anyhow::anyhow!("smoothing frame {frame}: {e}"))?;
        self.write(&rows)?;
        Ok(rows)
    }

    /// Smooths and writes every frame still waiting in the GPU's lag window (the run's end).
    /// Frames whose window could not be read back (a lost device) are named on stderr: the rows
    /// before them are written, and states.csv has every frame tracked.
    pub fn finish_device(&mut self, read: &mut ReadFrames<'_>) -> anyhow::Result<Vec<SmoothedRow>> {
        let (rows, unsmoothed) = match self.device.as_mut() {
            Some(device) => (device.finish(read))
                .map_err(|e| anyhow::anyhow!("smoothing the tracks at the run's end: {e}"))?,
            None => (Vec::new(), Vec::new()),
        };
        self.write(&rows)?;
        for lost in unsmoothed {
            let (first, last) = lost.frames;
            errln!(
                "warning: track {}'s frames {first}-{last} were not smoothed: their lag window on the GPU could not be read back ({}); smoothed.csv stops before them, states.csv has them",
                lost.track,
                lost.reason
            );
        }
        Ok(rows)
    }

    /// [`TrackSmoother::finish`], its rows written.
    pub fn finish(&mut self) -> anyhow::Result<Vec<SmoothedRow>> {
        let rows = (self.tracks.finish())
            .map_err(|e| anyhow::anyhow!("smoothing the tracks at the run's end: {e}"))?;
        self.write(&rows)?;
        Ok(rows)
    }

    fn write(&mut self, rows: &[SmoothedRow]) -> anyhow::Result<()> {
        for row in rows {
            let numbers: Vec<String> = (row.values.iter())
                .map(|s| format!("{},{},{}", s.mean, s.lower, s.upper))
                .collect();
            let lead = if self.with_track {
                format!("{},{}", row.frame, row.track)
            } else {
                row.frame.to_string()
            };
            self.file.row(&format!("{lead},{}", numbers.join(",")))?;
        }
        self.file.end_frame()
    }
}
