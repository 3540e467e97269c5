//! The marginal backward smoother on the GPU (`shaders/engine/smooth.wgsl`): every frame of
//! many tracks reweighed by the frames after it, one value at a time (the blocked smoother the
//! trackers' `--smooth` runs), O(M²) pairs per frame and value, all tracks and values of a
//! backward step in one dispatch of each of its two kernels.
//!
//! CPU twin: `pf_core::smooth::smooth_all` over `GaussianTransition::block(&[d])` for each value
//! d (`pf_core::smooth::smooth_values`). The GPU works in f32 where the twin works in f64;
//! `tests/gpu_smooth.rs` holds the two to the tolerance it states.

use bytemuck::{Pod, Zeroable};
use pf_core::PfError;
use pf_core::smooth::{
    Cloud, CpuSmoother, GaussianTransition, Summary, ValueSmoother, summarise_value,
};

use crate::context::GpuContext;
use crate::error::GpuError;
use crate::kernels::Kernel;
use crate::stream::{DeviceStream, uniform_buffer};

/// The smoothing kernels' source.
pub const SHADER: &str = include_str!("../../../shaders/engine/smooth.wgsl");

/// `SmoothParams` of `smooth.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct SmoothParams {
    particles: u32,
    dims: u32,
    _pad0: u32,
    _pad1: u32,
}

/// `SmoothEntry` of `smooth.wgsl`: one value of one track's backward step.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct SmoothEntry {
    current: u32,
    next: u32,
    dim: u32,
    angular: u32,
    inv_sigma: f32,
    _pad: [u32; 3],
}

/// Every track's smoothed weights, frame by frame and value by value (each value's weights are
/// that value's block of the blocked smoother), normalised.
#[derive(Debug, Clone)]
pub struct SmoothedWeights {
    particles: usize,
    dims: usize,
    /// Each track's first frame in `weights` and its number of frames.
    tracks: Vec<(usize, usize)>,
    /// `[(f·D + d)·M + m]` over every track's frames in turn.
    weights: Vec<f32>,
}

impl SmoothedWeights {
    /// The weights of value `dim` at frame `frame` of track `track` (they sum to 1).
    pub fn get(&self, track: usize, frame: usize, dim: usize) -> Option<&[f32]> {
        let &(first, len) = self.tracks.get(track)?;
        if frame >= len || dim >= self.dims {
            return None;
        }
        let slot = (first + frame) * self.dims + dim;
        self.weights
            .get(slot * self.particles..(slot + 1) * self.particles)
    }

    /// Every frame's smoothed summary of track `track` (`[frame][value]`): what
    /// `pf_core::smooth::smooth_values` gives on the CPU. `frames` are the track's clouds.
    pub fn summaries(
        &self,
        track: usize,
        frames: &[Cloud],
        angular: &[bool],
    ) -> Result<Vec<Vec<Summary>>, GpuError> {
        (frames.iter().enumerate())
            .map(|(f, cloud)| self.frame_summary(track, f, cloud, angular))
            .collect()
    }

    /// Frame `frame`'s smoothed summary of track `track` (`[value]`); `cloud` is that frame's.
    pub fn frame_summary(
        &self,
        track: usize,
        frame: usize,
        cloud: &Cloud,
        angular: &[bool],
    ) -> Result<Vec<Summary>, GpuError> {
        (0..self.dims)
            .map(|d| {
                let w = self.get(track, frame, d).ok_or_else(|| {
                    GpuError::InvalidConfig(format!(
                        "track {track} has no smoothed frame {frame} (value {d})"
                    ))
                })?;
                let w: Vec<f64> = w.iter().map(|&v| f64::from(v)).collect();
                summarise_value(cloud, &w, angular, d)
                    .map_err(|e| GpuError::InvalidConfig(e.to_string()))
            })
            .collect()
    }
}

/// The smoother's two kernels, built once.
pub struct GpuSmoother {
    predictive: Kernel,
    reweigh: Kernel,
}

/// What the device is given: every track's frames laid out one after another.
struct Flattened {
    states: Vec<f32>,
    log_weights: Vec<f32>,
    drift: Vec<f32>,
    /// The initial smoothed weights: the filtered ones where a slot is final from the start
    /// (every track's last frame, and every frame of a value that does not move).
    smoothed: Vec<f32>,
    tracks: Vec<(usize, usize)>,
}

fn flatten(
    tracks: &[&[Cloud]],
    particles: usize,
    dims: usize,
    sigma: &[f32],
) -> Result<Flattened, GpuError> {
    let frames: usize = tracks.iter().map(|t| t.len()).sum();
    let mut flat = Flattened {
        states: Vec::with_capacity(frames * dims * particles),
        log_weights: Vec::with_capacity(frames * particles),
        drift: Vec::with_capacity(frames * dims),
        smoothed: vec![0.0; frames * dims * particles],
        tracks: Vec::with_capacity(tracks.len()),
    };
    for track in tracks {
        let first = flat.log_weights.len() / particles.max(1);
        flat.tracks.push((first, track.len()));
        for (f, cloud) in track.iter().enumerate() {
            if cloud.weights.len() != particles
                || cloud.states.len() != dims * particles
                || cloud.drift.len() != dims
            {
                return Err(GpuError::InvalidConfig(format!(
                    "smoothing clouds of {particles} particles x {dims} values: one has {} weights, {} states and {} drift values",
                    cloud.weights.len(),
                    cloud.states.len(),
                    cloud.drift.len()
                )));
            }
            flat.states.extend_from_slice(&cloud.states);
            flat.log_weights
                .extend(cloud.weights.iter().map(|&w| (w as f32).ln()));
            flat.drift.extend_from_slice(&cloud.drift);
            let last = f + 1 == track.len();
            for (d, &s) in sigma.iter().enumerate() {
                if last || s == 0.0 {
                    let slot = (first + f) * dims + d;
                    for (m, &w) in cloud.weights.iter().enumerate() {
                        flat.smoothed[slot * particles + m] = w as f32;
                    }
                }
            }
        }
    }
    Ok(flat)
}

/// Each backward step's entries: step s smooths frame len − 2 − s of every track long enough,
/// for every value that moves.
fn steps(tracks: &[(usize, usize)], transition: &GaussianTransition) -> Vec<Vec<SmoothEntry>> {
    let longest = tracks.iter().map(|t| t.1).max().unwrap_or(0);
    (0..longest.saturating_sub(1))
        .map(|s| {
            let mut entries = Vec::new();
            for &(first, len) in tracks.iter().filter(|t| t.1 > s + 1) {
                let current = (first + len - 2 - s) as u32;
                for (d, &sigma) in transition.sigma.iter().enumerate() {
                    if sigma > 0.0 {
                        entries.push(SmoothEntry {
                            current,
                            next: current + 1,
                            dim: d as u32,
                            angular: u32::from(transition.angular[d]),
                            inv_sigma: 1.0 / sigma,
                            _pad: [0; 3],
                        });
                    }
                }
            }
            entries
        })
        .collect()
}

impl GpuSmoother {
    /// Builds the kernels.
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        Ok(Self {
            predictive: Kernel::trusted(ctx, "smoother predictive", SHADER, "predictive")?,
            reweigh: Kernel::trusted(ctx, "smoother reweigh", SHADER, "reweigh")?,
        })
    }

    /// Smooths every track (its clouds, frame by frame; all of `particles` particles and the
    /// transition's values) value by value: every backward step of every track and value is
    /// recorded before one wait, and the smoothed weights come back in one download.
    pub fn smooth(
        &self,
        ctx: &GpuContext,
        tracks: &[&[Cloud]],
        transition: &GaussianTransition,
    ) -> Result<SmoothedWeights, GpuError> {
        let dims = transition.sigma.len();
        let particles = tracks
            .iter()
            .flat_map(|t| t.first())
            .map(|c| c.weights.len())
            .next()
            .unwrap_or(0);
        if transition.angular.len() != dims
            || transition
                .sigma
                .iter()
                .any(|s| !(s.is_finite() && *s >= 0.0))
        {
            return Err(GpuError::InvalidConfig(format!(
                "smoothing needs one finite sigma >= 0 and one angle flag per value ({} sigmas, {} flags)",
                dims,
                transition.angular.len()
            )));
        }
        let flat = flatten(tracks, particles, dims, &transition.sigma)?;
        let mut out = SmoothedWeights {
            particles,
            dims,
            tracks: flat.tracks.clone(),
            weights: Vec::new(),
        };
        if particles == 0 || flat.log_weights.is_empty() {
            return Ok(out);
        }
        let steps = steps(&flat.tracks, transition);
        let smoothed = DeviceStream::from_slice(ctx, "smoothed weights", &flat.smoothed)?;
        self.run_steps(ctx, &flat, &steps, &smoothed, particles, dims)?;
        out.weights = smoothed.download(ctx)?;
        normalise_slots(&mut out.weights, particles);
        Ok(out)
    }

    /// Records and submits every backward step, in order, and waits.
    fn run_steps(
        &self,
        ctx: &GpuContext,
        flat: &Flattened,
        steps: &[Vec<SmoothEntry>],
        smoothed: &DeviceStream<f32>,
        particles: usize,
        dims: usize,
    ) -> Result<(), GpuError> {
        let widest = steps.iter().map(Vec::len).max().unwrap_or(0);
        if widest == 0 {
            return Ok(());
        }
        let buffers = StepBuffers::upload(ctx, flat, steps, widest, particles, dims)?;
        let groups = particles.div_ceil(64) as u32;
        // A few hundred steps a submission, so that no command buffer grows without bound.
        for chunk in (0..steps.len()).collect::<Vec<_>>().chunks(256) {
            let bind_groups = chunk
                .iter()
                .map(|&s| self.bind_step(ctx, &buffers, smoothed, s, steps[s].len()))
                .collect::<Result<Vec<_>, _>>()?;
            let mut encoder = ctx
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                    label: Some("smoother steps"),
                });
            {
                let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("smoother steps"),
                    timestamp_writes: None,
                });
                for (predict, reweigh, count) in &bind_groups {
                    self.predictive
                        .record(&mut pass, predict, [groups, *count, 1]);
                    self.reweigh.record(&mut pass, reweigh, [groups, *count, 1]);
                }
            }
            let index = ctx.scoped("smoothing", || ctx.queue.submit([encoder.finish()]))?;
            ctx.wait(Some(index), "the smoother")?;
        }
        Ok(())
    }

    /// The two kernels' bind groups for step `step` (its `count` entries), and the count.
    fn bind_step(
        &self,
        ctx: &GpuContext,
        b: &StepBuffers,
        smoothed: &DeviceStream<f32>,
        step: usize,
        count: usize,
    ) -> Result<(wgpu::BindGroup, wgpu::BindGroup, u32), GpuError> {
        let entry_bytes = std::mem::size_of::<SmoothEntry>();
        let slice = wgpu::BindingResource::Buffer(wgpu::BufferBinding {
            buffer: b.entries.buffer(),
            offset: (step * b.stride * entry_bytes) as u64,
            size: wgpu::BufferSize::new((count * entry_bytes) as u64),
        });
        let bind = |kernel: &Kernel, with_smoothed: bool| {
            let mut list = vec![
                (0, b.params.as_entire_binding()),
                (1, slice.clone()),
                (2, b.states.binding()),
                (3, b.log_weights.binding()),
                (4, b.drift.binding()),
                (6, b.predictive.binding()),
            ];
            if with_smoothed {
                list.push((5, smoothed.binding()));
            }
            kernel.bind(ctx, &list)
        };
        Ok((
            bind(&self.predictive, false)?,
            bind(&self.reweigh, true)?,
            count as u32,
        ))
    }
}

/// The device buffers of a smoothing run but the smoothed weights.
struct StepBuffers {
    params: wgpu::Buffer,
    states: DeviceStream<f32>,
    log_weights: DeviceStream<f32>,
    drift: DeviceStream<f32>,
    predictive: DeviceStream<f32>,
    /// Every step's entries, step s from entry s·stride (an offset the adapter can bind).
    entries: DeviceStream<SmoothEntry>,
    stride: usize,
}

impl StepBuffers {
    fn upload(
        ctx: &GpuContext,
        flat: &Flattened,
        steps: &[Vec<SmoothEntry>],
        widest: usize,
        particles: usize,
        dims: usize,
    ) -> Result<Self, GpuError> {
        let params = SmoothParams {
            particles: particles as u32,
            dims: dims as u32,
            _pad0: 0,
            _pad1: 0,
        };
        let entry_bytes = std::mem::size_of::<SmoothEntry>();
        let align = ctx.limits().min_storage_buffer_offset_alignment as usize;
        let stride = (widest * entry_bytes).next_multiple_of(align) / entry_bytes;
        let mut all = vec![SmoothEntry::zeroed(); stride * steps.len()];
        for (s, entries) in steps.iter().enumerate() {
            all[s * stride..s * stride + entries.len()].copy_from_slice(entries);
        }
        Ok(Self {
            params: uniform_buffer(ctx, "smoother params", &params)?,
            states: DeviceStream::from_slice(ctx, "smoother states", &flat.states)?,
            log_weights: DeviceStream::from_slice(ctx, "smoother log-weights", &flat.log_weights)?,
            drift: DeviceStream::from_slice(ctx, "smoother drift", &flat.drift)?,
            predictive: DeviceStream::zeroed(ctx, "log predictive", widest * particles)?,
            entries: DeviceStream::from_slice(ctx, "smoother entries", &all)?,
            stride,
        })
    }
}

/// Each slot's weights divided by their sum (the kernels leave them unnormalised); a slot whose
/// weights are all zero stays so.
fn normalise_slots(weights: &mut [f32], particles: usize) {
    for slot in weights.chunks_mut(particles) {
        let total: f64 = slot.iter().map(|&w| f64::from(w)).sum();
        if total > 0.0 && total.is_finite() {
            for w in slot {
                *w = (f64::from(*w) / total) as f32;
            }
        }
    }
}

/// A GPU smoothing tracks for `pf_core::smooth_tracks::TrackSmoother` (`TrackSmoother::on`): the
/// trackers' `--smooth` on a GPU backend. A track the device cannot smooth (lost, out of memory)
/// is smoothed on the CPU instead, so that a run that meets a device fault still writes every
/// row it had tracked; [`OnGpu::fell_back`] tells whether that happened.
pub struct OnGpu {
    ctx: GpuContext,
    smoother: GpuSmoother,
    fell_back: std::sync::atomic::AtomicBool,
}

impl OnGpu {
    /// The smoother's kernels built on `ctx` (the filter's GPU).
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        Ok(Self {
            ctx: ctx.clone(),
            smoother: GpuSmoother::new(ctx)?,
            fell_back: std::sync::atomic::AtomicBool::new(false),
        })
    }

    /// Whether a track was smoothed on the CPU because the device failed.
    pub fn fell_back(&self) -> bool {
        self.fell_back.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// Every track smoothed in one call on the device, each summarised by `summary(weights,
    /// track, its frames)`.
    fn on_device<T>(
        &self,
        tracks: &[&[Cloud]],
        transition: &GaussianTransition,
        summary: impl Fn(&SmoothedWeights, usize, &[Cloud]) -> Result<T, GpuError>,
    ) -> Result<Vec<T>, GpuError> {
        if tracks.is_empty() {
            return Ok(Vec::new());
        }
        let weights = self.smoother.smooth(&self.ctx, tracks, transition)?;
        (tracks.iter().enumerate())
            .map(|(r, frames)| summary(&weights, r, frames))
            .collect()
    }

    /// `on_device`, or the CPU's `cpu` where the device failed (bad input is refused the same
    /// on the CPU; a device fault is not the tracks').
    fn or_on_cpu<T>(
        &self,
        on_device: Result<Vec<T>, GpuError>,
        cpu: impl FnOnce() -> Result<Vec<T>, PfError>,
    ) -> Result<Vec<T>, PfError> {
        match on_device {
            Ok(values) => Ok(values),
            Err(GpuError::InvalidConfig(message)) => Err(PfError::InvalidConfig(message)),
            Err(_) => {
                self.fell_back
                    .store(true, std::sync::atomic::Ordering::Relaxed);
                cpu()
            }
        }
    }
}

impl ValueSmoother for OnGpu {
    fn smooth_values(
        &self,
        frames: &[Cloud],
        transition: &GaussianTransition,
    ) -> Result<Vec<Vec<Summary>>, PfError> {
        let mut one = self.smooth_many(&[frames], transition)?;
        Ok(one.pop().unwrap_or_default())
    }

    fn smooth_many(
        &self,
        tracks: &[&[Cloud]],
        transition: &GaussianTransition,
    ) -> Result<Vec<Vec<Vec<Summary>>>, PfError> {
        let angular = &transition.angular;
        let on_device = self.on_device(tracks, transition, |w, r, frames| {
            w.summaries(r, frames, angular)
        });
        self.or_on_cpu(on_device, || CpuSmoother.smooth_many(tracks, transition))
    }

    fn smooth_first_many(
        &self,
        tracks: &[&[Cloud]],
        transition: &GaussianTransition,
    ) -> Result<Vec<Vec<Summary>>, PfError> {
        let angular = &transition.angular;
        let on_device = self.on_device(tracks, transition, |w, r, frames| {
            let first = frames
                .first()
                .ok_or_else(|| GpuError::InvalidConfig("smoothing an empty window".into()))?;
            w.frame_summary(r, 0, first, angular)
        });
        self.or_on_cpu(on_device, || {
            CpuSmoother.smooth_first_many(tracks, transition)
        })
    }
}
