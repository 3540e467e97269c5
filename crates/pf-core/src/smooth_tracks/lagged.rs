//! Tracks smoothed L frames behind from summaries a device made ([`LaggedTracks`]): a filter
//! that keeps its lag window on the GPU (`pf_gpu::GpuFilter::keep_lag_window`) hands back, after
//! each frame, every slot's frame L steps back already smoothed from the ancestry and
//! summarised, so no particle crosses to the host. What the host keeps is which track ran in
//! which slot over the window: a slot whose track ran all L + 1 frames without a restart takes
//! the device's row; a track that ends or restarts within its window has its waiting frames
//! read back ([`LagFrame`]) and smoothed from the last of them here, as
//! [`super::TrackSmoother`] does with `LagSmoother::Ancestry` (the same rows, up to the device's
//! f32 sums).

use std::collections::{BTreeMap, VecDeque};

use super::{AncestryHealth, SmoothedRow};
use crate::error::PfError;
use crate::smooth::ancestry::trace_back;
use crate::smooth::lag_window::{LagFrame, LaggedSummaries};
use crate::smooth::{Cloud, summarise};

/// A slot's track at a frame, as the tracker reports it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SlotTrack {
    /// The filter's target (slot) the track runs in.
    pub slot: usize,
    /// The track.
    pub track: usize,
    /// Whether the slot's particles were restarted before this frame (its lineage names no
    /// ancestors): the frames before cannot be traced from this one.
    pub restarted: bool,
}

/// Reads back a slot's frames from the device's window: `(slot, first_step, count)`, oldest
/// first, steps numbered from 1 (the first frame given to [`LaggedTracks::add_frame`]; the
/// device counts the steps its window recorded the same way, and keeps one step more than the
/// window, so a device a step ahead of the host still has the host's frames).
pub type ReadFrames<'a> = dyn FnMut(usize, u64, usize) -> Result<Vec<LagFrame>, PfError> + 'a;

/// The frames a slot's track waits in, oldest first (contiguous, the last the latest stepped).
#[derive(Debug, Clone)]
struct SlotWindow {
    track: usize,
    frames: VecDeque<usize>,
}

/// Frames a track waited in that could not be smoothed: the device's window could not be read
/// back at the run's end (a lost device keeps its memory).
#[derive(Debug, Clone, PartialEq)]
pub struct Unsmoothed {
    /// The track.
    pub track: usize,
    /// Its first and last waiting frame.
    pub frames: (usize, usize),
    /// Why the window could not be read.
    pub reason: String,
}

/// Tracks smoothed from the ancestry a lag behind, from a device's summaries (see the module).
#[derive(Debug, Clone)]
pub struct LaggedTracks {
    lag: usize,
    dims: usize,
    angular: Vec<bool>,
    compare_filtered: bool,
    windows: BTreeMap<usize, SlotWindow>,
    health: AncestryHealth,
    /// Frames given so far (the step number of the latest).
    stepped: u64,
    /// Waiting frames of ended tracks whose window could not be read back.
    unsmoothed: Vec<Unsmoothed>,
}

impl LaggedTracks {
    /// Rows `lag` frames behind for tracks of `dims` values (those flagged in `angular` angles),
    /// with each row's filtered summary too when `compare_filtered` (the device must summarise
    /// it as well).
    pub fn new(lag: usize, dims: usize, angular: Vec<bool>, compare_filtered: bool) -> Self {
        Self {
            lag,
            dims,
            angular,
            compare_filtered,
            windows: BTreeMap::new(),
            health: AncestryHealth::default(),
            stepped: 0,
            unsmoothed: Vec::new(),
        }
    }

    /// The lag.
    pub fn lag(&self) -> usize {
        self.lag
    }

    /// What the traces kept of the rows smoothed a full lag back.
    pub fn health(&self) -> AncestryHealth {
        self.health
    }

    /// Frame `frame` stepped with the tracks `tracking`, and the device's summaries of frame
    /// `frame − lag` (`None` before its window filled). Returns the rows smoothed: the frame a
    /// lag back of every track that ran through the window, and every waiting frame of a track
    /// that ended or restarted (read back with `read`).
    pub fn add_frame(
        &mut self,
        frame: usize,
        tracking: &[SlotTrack],
        lagged: Option<&LaggedSummaries>,
        read: &mut ReadFrames<'_>,
    ) -> Result<Vec<SmoothedRow>, PfError> {
        let continues = |slot: usize, w: &SlotWindow| {
            (tracking.iter()).any(|s| s.slot == slot && s.track == w.track && !s.restarted)
        };
        let ended: Vec<usize> = (self.windows.iter())
            .filter(|(slot, w)| !continues(**slot, w))
            .map(|(slot, _)| *slot)
            .collect();
        self.stepped += 1;
        let mut rows = Vec::new();
        for slot in ended {
            if let Some(window) = self.windows.remove(&slot) {
                // Its frames end a step before this one.
                let count = window.frames.len();
                let read_back = read(slot, self.stepped - count as u64, count);
                rows.extend(self.rows_or_unsmoothed(&window, read_back));
            }
        }
        for s in tracking {
            let window = self.windows.entry(s.slot).or_insert_with(|| SlotWindow {
                track: s.track,
                frames: VecDeque::with_capacity(self.lag + 1),
            });
            window.frames.push_back(frame);
        }
        let full: Vec<usize> = (self.windows.iter())
            .filter(|(_, w)| w.frames.len() > self.lag)
            .map(|(slot, _)| *slot)
            .collect();
        for slot in full {
            rows.push(self.lagged_row(slot, lagged, read)?);
        }
        Ok(rows)
    }

    /// Every frame still waiting, smoothed from the last frame stepped (the run's end), and every
    /// track's waiting frames that could not be read back (a lost device), at the run's end or
    /// when the track ended: every track that can be read is smoothed whatever happened to the
    /// others.
    pub fn finish(
        &mut self,
        read: &mut ReadFrames<'_>,
    ) -> Result<(Vec<SmoothedRow>, Vec<Unsmoothed>), PfError> {
        let windows = std::mem::take(&mut self.windows);
        let mut rows = Vec::new();
        for (slot, window) in windows {
            let count = window.frames.len();
            let read_back = read(slot, self.stepped + 1 - count as u64, count);
            rows.extend(self.rows_or_unsmoothed(&window, read_back));
        }
        Ok((rows, std::mem::take(&mut self.unsmoothed)))
    }

    /// `window`'s rows from its frames read back, or none and the frames named as unsmoothed.
    fn rows_or_unsmoothed(
        &mut self,
        window: &SlotWindow,
        read_back: Result<Vec<LagFrame>, PfError>,
    ) -> Vec<SmoothedRow> {
        match read_back.and_then(|frames| self.host_rows(window, frames)) {
            Ok(rows) => rows,
            Err(e) => {
                if let (Some(&first), Some(&last)) = (window.frames.front(), window.frames.back()) {
                    self.unsmoothed.push(Unsmoothed {
                        track: window.track,
                        frames: (first, last),
                        reason: e.to_string(),
                    });
                }
                Vec::new()
            }
        }
    }

    /// A full window's first frame: the device's row where it traced the slot, else the slot's
    /// window read back and traced here.
    fn lagged_row(
        &mut self,
        slot: usize,
        lagged: Option<&LaggedSummaries>,
        read: &mut ReadFrames<'_>,
    ) -> Result<SmoothedRow, PfError> {
        let missing = || PfError::InvalidConfig(format!("slot {slot}: no lag window"));
        let window = self.windows.get(&slot).ok_or_else(missing)?;
        let (track, first) = (window.track, *window.frames.front().ok_or_else(missing)?);
        let on_device = lagged
            .filter(|l| l.lag == self.lag)
            .and_then(|l| l.targets.get(slot))
            .and_then(Option::as_ref);
        let row = match on_device {
            Some(target) => {
                self.health.add_share(f64::from(target.kept));
                SmoothedRow {
                    frame: first,
                    track,
                    values: target.smoothed.clone(),
                    filtered: if self.compare_filtered {
                        target.filtered.clone()
                    } else {
                        Vec::new()
                    },
                }
            }
            None => {
                let frames = read(slot, self.stepped - self.lag as u64, self.lag + 1)?;
                let clouds = self.clouds(&frames)?;
                let weights = self.traced(&clouds, &frames)?;
                let (cloud, traced) = (clouds.first(), weights.first());
                let (Some(cloud), Some(traced)) = (cloud, traced) else {
                    return Err(missing());
                };
                self.health.add(traced, &cloud.weights);
                self.row(first, track, cloud, traced)?
            }
        };
        if let Some(window) = self.windows.get_mut(&slot) {
            window.frames.pop_front();
        }
        Ok(row)
    }

    /// Every frame of `window` (whose particles are `frames`) smoothed from its last.
    fn host_rows(
        &self,
        window: &SlotWindow,
        frames: Vec<LagFrame>,
    ) -> Result<Vec<SmoothedRow>, PfError> {
        if frames.len() != window.frames.len() {
            return Err(PfError::InvalidConfig(format!(
                "track {}: {} frames read back for {} waiting",
                window.track,
                frames.len(),
                window.frames.len()
            )));
        }
        let clouds = self.clouds(&frames)?;
        let weights = self.traced(&clouds, &frames)?;
        (window.frames.iter().zip(&clouds).zip(&weights))
            .map(|((&frame, cloud), w)| self.row(frame, window.track, cloud, w))
            .collect()
    }

    fn clouds(&self, frames: &[LagFrame]) -> Result<Vec<Cloud>, PfError> {
        let dims = self.dims;
        (frames.iter())
            .map(|f| {
                let m = f.log_weights.len();
                Cloud::of_target(dims, m, 0, &f.states, &f.log_weights, vec![0.0; dims])
            })
            .collect()
    }

    /// Each frame's weights traced back from the last frame's (the first's lineage unused).
    fn traced(&self, clouds: &[Cloud], frames: &[LagFrame]) -> Result<Vec<Vec<f64>>, PfError> {
        let Some(last) = clouds.last() else {
            return Ok(Vec::new());
        };
        let lineages: Vec<&[u32]> = frames
            .iter()
            .skip(1)
            .map(|f| f.lineage.as_slice())
            .collect();
        trace_back(&last.weights, &lineages)
    }

    fn row(
        &self,
        frame: usize,
        track: usize,
        cloud: &Cloud,
        weights: &[f64],
    ) -> Result<SmoothedRow, PfError> {
        Ok(SmoothedRow {
            frame,
            track,
            values: summarise(cloud, weights, &self.angular)?,
            filtered: if self.compare_filtered {
                summarise(cloud, &cloud.weights, &self.angular)?
            } else {
                Vec::new()
            },
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::batch::BatchShape;
    use crate::smooth::GaussianTransition;
    use crate::smooth::ancestry::NO_ANCESTOR;
    use crate::smooth::lag_window::LagWindow;
    use crate::smooth_tracks::{LagSmoother, TrackCloud, TrackSmoother};
    use proptest::prelude::*;

    /// A run: per frame, each slot's (track, restarted) or free; the particles drawn at random.
    #[derive(Debug, Clone)]
    struct Run {
        shape: BatchShape,
        lag: usize,
        angular: Vec<bool>,
        schedule: Vec<Vec<Option<(usize, bool)>>>,
        seed: u64,
    }

    /// Each slot's track over the frames: kept, ended (free), restarted, or a new track, drawn
    /// from `events` (one byte per frame and slot); every slot starts with a track.
    fn schedule(slots: usize, events: &[u8]) -> Vec<Vec<Option<(usize, bool)>>> {
        let mut next = slots;
        let mut now: Vec<Option<usize>> = (0..slots).map(Some).collect();
        let mut new_track = |now: &mut Option<usize>| {
            next += 1;
            *now = Some(next);
            Some((next, true))
        };
        let frames = events.len() / slots;
        (0..frames)
            .map(|f| {
                (0..slots)
                    .map(|s| match (f, events[f * slots + s] % 12, now[s]) {
                        (0, _, track) => track.map(|t| (t, true)),
                        (_, 9, _) => {
                            now[s] = None;
                            None
                        }
                        (_, 10, Some(track)) => Some((track, true)),
                        (_, 10 | 11, _) => new_track(&mut now[s]),
                        (_, _, Some(track)) => Some((track, false)),
                        (_, event, None) if event < 4 => new_track(&mut now[s]),
                        (_, _, None) => None,
                    })
                    .collect()
            })
            .collect()
    }

    fn run() -> impl Strategy<Value = Run> {
        (1usize..=3, 1usize..=40, 1usize..=3, 1usize..=4, 3usize..=14)
            .prop_flat_map(|(slots, particles, dims, lag, frames)| {
                (
                    Just((slots, particles, dims, lag)),
                    proptest::collection::vec(any::<u8>(), slots * frames),
                    proptest::collection::vec(any::<bool>(), dims),
                    any::<u64>(),
                )
            })
            .prop_map(
                |((slots, particles, dims, lag), events, angular, seed)| Run {
                    shape: BatchShape::new(slots, particles, dims).unwrap(),
                    lag,
                    angular,
                    schedule: schedule(slots, &events),
                    seed,
                },
            )
    }

    /// A frame's particles: random states and weights, lineages into the frame before (none for
    /// a restarted slot).
    fn frame_particles(run: &Run, f: usize) -> BatchFrame {
        let mut rng = crate::random::RandomStream::from_key(run.seed ^ (f as u64) << 48);
        let (m, shape) = (run.shape.particles, run.shape);
        let mut uniform = || rng.uniform() as f32;
        let states: Vec<f32> = (0..shape.state_len())
            .map(|_| 6.0 * uniform() - 3.0)
            .collect();
        let mut log_weights = Vec::with_capacity(shape.particle_len());
        let mut lineage = Vec::with_capacity(shape.particle_len());
        for slot in 0..shape.targets {
            let raw: Vec<f32> = (0..m).map(|_| 4.0 * uniform()).collect();
            let total = raw.iter().map(|x| x.exp()).sum::<f32>().ln();
            log_weights.extend(raw.iter().map(|x| x - total));
            let restarted = run.schedule[f][slot].is_none_or(|(_, r)| r);
            lineage.extend((0..m).map(|_| {
                if restarted {
                    NO_ANCESTOR
                } else {
                    (uniform() * m as f32) as u32 % m as u32
                }
            }));
        }
        (states, log_weights, lineage)
    }

    /// A frame of the batch as the device keeps it: states, log-weights, lineage.
    type BatchFrame = (Vec<f32>, Vec<f32>, Vec<u32>);

    /// Slot `slot`'s steps `first ..` (`n` of them, numbered from 1) of `ring`, as a device with
    /// a window of `lag` reads them back: only its last lag + 2 steps.
    fn read_ring(
        ring: &[BatchFrame],
        (slot, first, n): (usize, u64, usize),
        (dims, m): (usize, usize),
        lag: usize,
    ) -> Result<Vec<LagFrame>, PfError> {
        let start = (first as usize).saturating_sub(1);
        if first == 0 || start + lag + 2 < ring.len() || start + n > ring.len() {
            return Err(PfError::InvalidConfig(format!(
                "steps {first} to {} read back; the window holds the last {} of {}",
                start + n,
                lag + 2,
                ring.len()
            )));
        }
        Ok((ring[start..start + n].iter())
            .map(|(s, w, l)| LagFrame {
                states: s[slot * dims * m..(slot + 1) * dims * m].to_vec(),
                log_weights: w[slot * m..(slot + 1) * m].to_vec(),
                lineage: l[slot * m..(slot + 1) * m].to_vec(),
            })
            .collect())
    }

    fn sorted(mut rows: Vec<SmoothedRow>) -> Vec<SmoothedRow> {
        rows.sort_by_key(|r| (r.frame, r.track));
        rows
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

        /// Fed by a device that summarises as the GPU does (the twin `LagWindow`), the rows are
        /// the host smoother's from every frame's particles, whatever starts, ends and restarts.
        #[test]
        fn device_summaries_give_the_host_smoothers_rows(run in run()) {
            let (shape, lag) = (run.shape, run.lag);
            let (dims, m) = (shape.dims, shape.particles);
            let mut device = LagWindow::new(shape, lag, run.angular.clone(), true).unwrap();
            let mut ring: Vec<BatchFrame> = Vec::new();
            let mut lagged_tracks = LaggedTracks::new(lag, dims, run.angular.clone(), true);
            let transition = GaussianTransition { sigma: vec![0.1; dims], angular: run.angular.clone() };
            let mut host = TrackSmoother::new(Some(lag), transition, 0.0)
                .lagging_by(LagSmoother::Ancestry)
                .comparing_filtered();
            let (mut ours, mut theirs) = (Vec::new(), Vec::new());
            for f in 0..run.schedule.len() {
                let (states, log_weights, lineage) = frame_particles(&run, f);
                let summaries = device.push(&states, &log_weights, &lineage).unwrap();
                ring.push((states.clone(), log_weights.clone(), lineage.clone()));
                let tracking: Vec<SlotTrack> = (run.schedule[f].iter().enumerate())
                    .filter_map(|(slot, s)| s.map(|(track, restarted)| SlotTrack { slot, track, restarted }))
                    .collect();
                let clouds: Vec<TrackCloud> = tracking.iter().map(|s| TrackCloud {
                    track: s.track,
                    states: states[s.slot * dims * m..(s.slot + 1) * dims * m].to_vec(),
                    log_weights: log_weights[s.slot * m..(s.slot + 1) * m].to_vec(),
                    lineage: Some(lineage[s.slot * m..(s.slot + 1) * m].to_vec()),
                }).collect();
                let mut read = |slot: usize, first: u64, n: usize| read_ring(&ring, (slot, first, n), (dims, m), lag);
                ours.extend(lagged_tracks.add_frame(f, &tracking, summaries.as_ref(), &mut read).unwrap());
                theirs.extend(host.add_frame(f, clouds).unwrap());
            }
            let mut read = |slot: usize, first: u64, n: usize| read_ring(&ring, (slot, first, n), (dims, m), lag);
            let (rest, unsmoothed) = lagged_tracks.finish(&mut read).unwrap();
            prop_assert!(unsmoothed.is_empty());
            ours.extend(rest);
            theirs.extend(host.finish().unwrap());
            let (ours, theirs) = (sorted(ours), sorted(theirs));
            prop_assert_eq!(ours.len(), theirs.len());
            for (a, b) in ours.iter().zip(&theirs) {
                prop_assert_eq!((a.frame, a.track), (b.frame, b.track));
                prop_assert_eq!(&a.values, &b.values, "frame {} track {}", a.frame, a.track);
                prop_assert_eq!(&a.filtered, &b.filtered);
            }
            let (ours, theirs) = (lagged_tracks.health(), host.ancestry_health().unwrap());
            prop_assert_eq!(ours.rows, theirs.rows);
            prop_assert!((ours.mean_kept - theirs.mean_kept).abs() < 1e-5);
        }
    }
}
