//! The detector on the GPU: the launcher of `shaders/face/detect.wgsl` ([`super::SHADER`]), whose
//! CPU twin is [`Cascade::window_hits`] (`scan` and `run_at` in this module's parent).
//!
//! The host shrinks the frame to the pyramid's levels (the CPU detector's own bilinear resize,
//! so both see the same pixels) and uploads them, 8-bit, four to a word; one submission then
//! builds every level's integral tables, classifies every window (an invocation each), and scans
//! each row of windows with OpenCV's skip rule; only the faces come back. A detection at
//! 1024×768 is millions of windows: a CPU core takes a third of a second for it, and the tracker
//! of a video with detection on was bound by that work.
//!
//! The features and stage sums are f32 on the GPU (f64 on the CPU): a window whose stage sum lies
//! within rounding of a threshold can go the other way, which changes a raw hit now and then but
//! not the grouped faces (`tests/gpu_face_detection.rs` bounds both).

use std::sync::{Mutex, PoisonError};

use bytemuck::{Pod, Zeroable};
use pf_gpu::kernels::Kernel;
use pf_gpu::stream::uniform_buffer;
use pf_gpu::{DeviceStream, GpuContext, GpuError, Readback, wgpu};
use rayon::prelude::*;

use super::{Cascade, DetectConfig, Detection, PyramidLevel, group, resize_into};
use crate::error::FaceError;
use crate::image::GrayImage;

use super::SHADER as SOURCE;

/// Invocations per workgroup of every pass (`@workgroup_size` in the shader).
const WORKGROUP: u32 = 64;
/// Workgroups per row of a dispatch grid: a flat index is x + y · 65 536.
const GROUPS_PER_ROW: u32 = 1024;
/// Raw hits the GPU keeps (a frame of four faces gives a few hundred); more fall back to the CPU.
const MAX_HITS: u32 = 8192;

/// `Level` in the shader.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct LevelLayout {
    width: u32,
    height: u32,
    step: u32,
    pixel_word: u32,
    table: u32,
    window_first: u32,
    columns: u32,
    rows: u32,
    pixel_row_first: u32,
    table_column_first: u32,
    window_row_first: u32,
    _pad: u32,
}

/// `Params` in the shader.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct Params {
    levels: u32,
    window_width: u32,
    window_height: u32,
    stages: u32,
    pixel_rows: u32,
    table_columns: u32,
    windows: u32,
    window_rows: u32,
    grid_width: u32,
    max_hits: u32,
    stages_at: u32,
    trees_at: u32,
    nodes_at: u32,
    leaves_at: u32,
    rects_at: u32,
    feature_starts_at: u32,
}

/// The cascade as the shader reads it: one array of words, and where each section starts.
struct CascadeWords {
    words: Vec<u32>,
    /// (stages, trees, nodes, leaves, rectangles, feature starts), in words.
    sections: [u32; 6],
}

impl CascadeWords {
    fn new(cascade: &Cascade) -> Result<Self, FaceError> {
        let (mut stages, mut trees, mut nodes, mut leaves) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for stage in &cascade.stages {
            let first = trees.len() / 2;
            for weak in &stage.classifiers {
                trees.extend([(nodes.len() / 4) as u32, leaves.len() as u32]);
                for n in &weak.nodes {
                    nodes.extend([
                        n.feature as u32,
                        n.threshold.to_bits(),
                        n.left as u32,
                        n.right as u32,
                    ]);
                }
                leaves.extend(weak.leaves.iter().map(|l| l.to_bits()));
            }
            stages.extend([
                stage.threshold.to_bits(),
                first as u32,
                (trees.len() / 2) as u32,
                0,
            ]);
        }
        let (mut rects, mut starts) = (Vec::new(), vec![0u32]);
        for feature in &cascade.features {
            for r in feature {
                if [r.x, r.y, r.width, r.height].iter().any(|&v| v > 255) {
                    return Err(FaceError::InvalidInput(format!(
                        "the GPU detector takes feature rectangles within 255 pixels, got {r:?}"
                    )));
                }
                rects.extend([
                    r.x | r.y << 8 | r.width << 16 | r.height << 24,
                    r.weight.to_bits(),
                ]);
            }
            starts.push((rects.len() / 2) as u32);
        }
        let mut words = Vec::new();
        let mut sections = [0u32; 6];
        for (i, section) in [stages, trees, nodes, leaves, rects, starts]
            .into_iter()
            .enumerate()
        {
            sections[i] = words.len() as u32;
            words.extend(section);
        }
        Ok(Self { words, sections })
    }
}

/// The four passes, in order.
struct Passes {
    integral_rows: Kernel,
    integral_columns: Kernel,
    classify_windows: Kernel,
    collect_faces: Kernel,
}

/// The buffers for one pyramid (one frame size and settings), reused while they stay the same.
struct PyramidBuffers {
    levels: Vec<PyramidLevel>,
    /// Each level's first word in `pixels`.
    pixel_words: Vec<usize>,
    /// The levels' pixels as uploaded, four to a word: kept between frames of one size.
    pixel_upload: Vec<u32>,
    pixels: DeviceStream<u32>,
    hits: DeviceStream<u32>,
    readback: Readback<u32>,
    /// (bind group, workgroups) per pass, in order.
    dispatches: Vec<(wgpu::BindGroup, [u32; 3])>,
    // Held for the bind groups.
    _params: wgpu::Buffer,
    _tables: [DeviceStream<u32>; 4],
}

impl PyramidBuffers {
    /// Each level of `frame`, resized by the CPU detector's own bilinear resize, written straight
    /// into its place in the upload (levels in parallel).
    fn resize_levels(&mut self, frame: &GrayImage) {
        let bytes: &mut [u8] = bytemuck::cast_slice_mut(&mut self.pixel_upload);
        let mut places = Vec::with_capacity(self.levels.len());
        let mut rest = bytes;
        let mut at = 0;
        for (level, &first) in self.levels.iter().zip(&self.pixel_words) {
            let (width, height) = level.scaled;
            let len = width as usize * height as usize;
            let (_, tail) = std::mem::take(&mut rest).split_at_mut(4 * first - at);
            let (place, tail) = tail.split_at_mut(len);
            places.push((level.scaled, place));
            rest = tail;
            at = 4 * first + len;
        }
        places
            .into_par_iter()
            .for_each(|((width, height), place)| resize_into(frame, width, height, place));
    }
}

/// The Viola–Jones detector on a GPU: [`Cascade::detect`]'s faces, from a submission per frame.
pub struct GpuCascade {
    cascade: Cascade,
    ctx: GpuContext,
    passes: Passes,
    cascade_words: DeviceStream<u32>,
    sections: [u32; 6],
    buffers: Mutex<Option<PyramidBuffers>>,
}

impl std::fmt::Debug for GpuCascade {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuCascade")
            .field("adapter", &self.ctx.adapter().name)
            .field("stages", &self.cascade.stages.len())
            .finish_non_exhaustive()
    }
}

/// Workgroups for `invocations` on the shader's flat grid.
fn grid(invocations: usize) -> [u32; 3] {
    let groups = (invocations as u32).div_ceil(WORKGROUP).max(1);
    [
        groups.min(GROUPS_PER_ROW),
        groups.div_ceil(GROUPS_PER_ROW),
        1,
    ]
}

impl GpuCascade {
    /// The cascade on `ctx`'s device (the tracker's own, or one of its own on the same GPU).
    pub fn new(ctx: GpuContext, cascade: Cascade) -> Result<Self, FaceError> {
        if cascade.width < 3 || cascade.height < 3 || cascade.stages.is_empty() {
            return Err(FaceError::InvalidInput(format!(
                "a cascade needs a window of at least 3×3 and a stage (got {}×{}, {} stages)",
                cascade.width,
                cascade.height,
                cascade.stages.len()
            )));
        }
        let CascadeWords { words, sections } = CascadeWords::new(&cascade)?;
        let kernel =
            |entry: &str| Kernel::trusted(&ctx, &format!("haar cascade {entry}"), SOURCE, entry);
        let passes = Passes {
            integral_rows: kernel("integral_rows")?,
            integral_columns: kernel("integral_columns")?,
            classify_windows: kernel("classify_windows")?,
            collect_faces: kernel("collect_faces")?,
        };
        let cascade_words = DeviceStream::from_slice(&ctx, "haar cascade", &words)?;
        Ok(Self {
            cascade,
            ctx,
            passes,
            cascade_words,
            sections,
            buffers: Mutex::new(None),
        })
    }

    /// The cascade it runs.
    pub fn cascade(&self) -> &Cascade {
        &self.cascade
    }

    /// The device it runs on.
    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }

    /// The faces in `frame` (grouped as [`Cascade::detect`] groups them).
    pub fn detect(
        &self,
        frame: &GrayImage,
        config: &DetectConfig,
    ) -> Result<Vec<Detection>, FaceError> {
        Ok(group(
            &self.window_hits(frame, config)?,
            config.min_neighbors,
        ))
    }

    /// Every window that passes the cascade, ungrouped, in [`Cascade::window_hits`]'s order.
    pub fn window_hits(
        &self,
        frame: &GrayImage,
        config: &DetectConfig,
    ) -> Result<Vec<Detection>, FaceError> {
        config.validate()?;
        let levels = self.cascade.pyramid((frame.width, frame.height), config);
        if levels.is_empty() {
            return Ok(Vec::new());
        }
        let mut kept = self.buffers.lock().unwrap_or_else(PoisonError::into_inner);
        if kept.as_ref().is_some_and(|b| b.levels != levels) {
            // Dropped first: a new frame size should not hold both sets on the device.
            *kept = None;
        }
        let buffers: &mut PyramidBuffers = match &mut *kept {
            Some(buffers) => buffers,
            empty => empty.insert(self.buffers_for(levels)?),
        };
        buffers.resize_levels(frame);
        let found = self.run(buffers)?;
        match found {
            Some(hits) => Ok(hits),
            // More raw hits than the GPU keeps: the CPU finds them all.
            None => self.cascade.window_hits(frame, config),
        }
    }

    /// One submission: upload, the four passes, the hits read back (`None`: too many).
    fn run(&self, buffers: &PyramidBuffers) -> Result<Option<Vec<Detection>>, GpuError> {
        let ctx = &self.ctx;
        buffers.pixels.upload(ctx, &buffers.pixel_upload)?;
        buffers.hits.upload_at(ctx, 0, &[0])?;
        let submission = ctx.scoped("detecting faces on the GPU", || {
            let mut encoder = ctx.device.create_command_encoder(&Default::default());
            {
                let mut pass = encoder.begin_compute_pass(&Default::default());
                let kernels = [
                    &self.passes.integral_rows,
                    &self.passes.integral_columns,
                    &self.passes.classify_windows,
                    &self.passes.collect_faces,
                ];
                for (kernel, (group, groups)) in kernels.iter().zip(&buffers.dispatches) {
                    kernel.record(&mut pass, group, *groups);
                }
            }
            buffers.readback.record_copy(&mut encoder, &buffers.hits);
            ctx.queue.submit([encoder.finish()])
        })?;
        let hits = buffers.readback.read(ctx, Some(submission))?;
        let count = hits[0] as usize;
        if count > MAX_HITS as usize {
            return Ok(None);
        }
        let mut found: Vec<[u32; 3]> = hits[1..1 + 4 * count]
            .chunks_exact(4)
            .map(|h| [h[0], h[2], h[1]])
            .collect();
        // The CPU's order: level, row, column.
        found.sort_unstable();
        Ok(Some(
            found
                .iter()
                .map(|&[level, y, x]| {
                    buffers.levels[level as usize].detection(x as usize, y as usize)
                })
                .collect(),
        ))
    }

    /// The tables, grids and bind groups for a pyramid.
    fn buffers_for(&self, levels: Vec<PyramidLevel>) -> Result<PyramidBuffers, FaceError> {
        let ctx = &self.ctx;
        let window = (self.cascade.width as usize, self.cascade.height as usize);
        let (table, pixel_words, sizes) = level_layouts(&levels, window);
        if sizes.values > u32::MAX as usize {
            // A limit of this device's layout, not a bad frame: a tracker's detector goes on on
            // the CPU (FaceDetector falls back on GPU errors).
            return Err(GpuError::InvalidConfig(format!(
                "a {}×{} frame is too large for the GPU detector",
                levels[0].scaled.0, levels[0].scaled.1
            ))
            .into());
        }
        let params = self.params(levels.len(), window, &sizes);
        let params_buffer = uniform_buffer(ctx, "haar cascade params", &params)?;
        let level_words: &[u32] = bytemuck::cast_slice(&table);
        let hit_words = 1 + 4 * MAX_HITS as usize;
        let streams = PyramidStreams {
            levels: DeviceStream::from_slice(ctx, "pyramid levels", level_words)?,
            pixels: DeviceStream::zeroed(ctx, "pyramid pixels", sizes.words)?,
            integral: DeviceStream::zeroed(ctx, "pyramid integral", sizes.values)?,
            squares: DeviceStream::zeroed(ctx, "pyramid squared integral", sizes.values)?,
            verdicts: DeviceStream::zeroed(ctx, "window verdicts", sizes.windows)?,
            hits: DeviceStream::zeroed(ctx, "detector hits", hit_words)?,
        };
        let dispatches = self.dispatches(&params_buffer, &streams, &sizes)?;
        let PyramidStreams {
            levels: level_stream,
            pixels,
            integral,
            squares,
            verdicts,
            hits,
        } = streams;
        Ok(PyramidBuffers {
            levels,
            pixel_words,
            pixel_upload: vec![0; sizes.words],
            pixels,
            hits,
            readback: Readback::new(ctx, "detector hits", hit_words)?,
            dispatches,
            _params: params_buffer,
            _tables: [level_stream, integral, squares, verdicts],
        })
    }

    /// The shader's parameters for a pyramid of `levels` levels of `sizes`.
    fn params(&self, levels: usize, (w, h): (usize, usize), sizes: &PyramidSizes) -> Params {
        let [
            stages_at,
            trees_at,
            nodes_at,
            leaves_at,
            rects_at,
            feature_starts_at,
        ] = self.sections;
        Params {
            levels: levels as u32,
            window_width: w as u32,
            window_height: h as u32,
            stages: self.cascade.stages.len() as u32,
            pixel_rows: sizes.pixel_rows as u32,
            table_columns: sizes.table_columns as u32,
            windows: sizes.windows as u32,
            window_rows: sizes.window_rows as u32,
            grid_width: GROUPS_PER_ROW * WORKGROUP,
            max_hits: MAX_HITS,
            stages_at,
            trees_at,
            nodes_at,
            leaves_at,
            rects_at,
            feature_starts_at,
        }
    }

    /// Each pass's bind group and grid, in order: integral rows, integral columns, classify
    /// windows, collect faces.
    fn dispatches(
        &self,
        params: &wgpu::Buffer,
        streams: &PyramidStreams,
        sizes: &PyramidSizes,
    ) -> Result<Vec<(wgpu::BindGroup, [u32; 3])>, FaceError> {
        let (ctx, passes, s) = (&self.ctx, &self.passes, streams);
        let p = || params.as_entire_binding();
        Ok(vec![
            (
                passes.integral_rows.bind(
                    ctx,
                    &[
                        (0, p()),
                        (1, s.levels.binding()),
                        (2, s.pixels.binding()),
                        (3, s.integral.binding()),
                        (4, s.squares.binding()),
                    ],
                )?,
                grid(sizes.pixel_rows),
            ),
            (
                passes.integral_columns.bind(
                    ctx,
                    &[
                        (0, p()),
                        (1, s.levels.binding()),
                        (3, s.integral.binding()),
                        (4, s.squares.binding()),
                    ],
                )?,
                grid(sizes.table_columns),
            ),
            (
                passes.classify_windows.bind(
                    ctx,
                    &[
                        (0, p()),
                        (1, s.levels.binding()),
                        (3, s.integral.binding()),
                        (4, s.squares.binding()),
                        (5, s.verdicts.binding()),
                        (7, self.cascade_words.binding()),
                    ],
                )?,
                grid(sizes.windows),
            ),
            (
                passes.collect_faces.bind(
                    ctx,
                    &[
                        (0, p()),
                        (1, s.levels.binding()),
                        (5, s.verdicts.binding()),
                        (6, s.hits.binding()),
                    ],
                )?,
                grid(sizes.window_rows),
            ),
        ])
    }
}

/// A pyramid's device streams, before they are handed to its [`PyramidBuffers`].
struct PyramidStreams {
    levels: DeviceStream<u32>,
    pixels: DeviceStream<u32>,
    integral: DeviceStream<u32>,
    squares: DeviceStream<u32>,
    verdicts: DeviceStream<u32>,
    hits: DeviceStream<u32>,
}

/// A pyramid's sizes summed over its levels: what its streams and grids hold.
#[derive(Default)]
struct PyramidSizes {
    /// Pixel words (four 8-bit pixels each).
    words: usize,
    /// Integral-table values.
    values: usize,
    windows: usize,
    pixel_rows: usize,
    table_columns: usize,
    window_rows: usize,
}

/// Each level's layout in the shared streams (the CPU's scan: x in 0..width − w and y in
/// 0..height − h by the level's step, for a `(w, h)` window), each level's first pixel word,
/// and the totals.
fn level_layouts(
    levels: &[PyramidLevel],
    (w, h): (usize, usize),
) -> (Vec<LevelLayout>, Vec<usize>, PyramidSizes) {
    let mut table = Vec::with_capacity(levels.len());
    let mut pixel_words = Vec::with_capacity(levels.len());
    let mut at = PyramidSizes::default();
    for level in levels {
        let (width, height) = (level.scaled.0 as usize, level.scaled.1 as usize);
        let step = level.step();
        let (columns, rows) = ((width - w).div_ceil(step), (height - h).div_ceil(step));
        table.push(LevelLayout {
            width: width as u32,
            height: height as u32,
            step: step as u32,
            pixel_word: at.words as u32,
            table: at.values as u32,
            window_first: at.windows as u32,
            columns: columns as u32,
            rows: rows as u32,
            pixel_row_first: at.pixel_rows as u32,
            table_column_first: at.table_columns as u32,
            window_row_first: at.window_rows as u32,
            _pad: 0,
        });
        pixel_words.push(at.words);
        at.words += (width * height).div_ceil(4);
        at.values += (width + 1) * (height + 1);
        at.windows += columns * rows;
        at.pixel_rows += height;
        at.table_columns += width + 1;
        at.window_rows += rows;
    }
    (table, pixel_words, at)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_shader_parses_and_its_structs_mirror_rusts() {
        pf_gpu::kernels::validate_wgsl(SOURCE).unwrap_or_else(|m| panic!("{m}"));
        for (name, size) in [
            ("Level", std::mem::size_of::<LevelLayout>()),
            ("Params", std::mem::size_of::<Params>()),
        ] {
            let (wgsl_size, members) = pf_gpu::kernels::wgsl_struct_layout(SOURCE, name).unwrap();
            assert_eq!(wgsl_size as usize, size, "{name}");
            // Every member is a u32 in declaration order, as the Rust fields are.
            for (i, (_, offset)) in members.iter().enumerate() {
                assert_eq!(*offset as usize, 4 * i, "{name} member {i}");
            }
        }
    }
}
