//! `pf_gpu::GrayTexture` read through the texture unit's bilinear filter against its CPU twin
//! (bilinear interpolation with the weights rounded by `pf_gpu::image::quantised_weight`), at
//! random points of random frames: pixel centres, cell edges, the last row and column.
//!
//! Bound: within 2·range/256 + 1 level of the twin, range being the largest minus the smallest
//! level of the sample's cell: the twin's weights lie within 1/512 of the exact ones, a unit's
//! (rounding or truncating to 8 bits) within 1/256, each weight moves the value by at most the
//! range per axis, and one level more covers a unit that returns 8-bit results (lavapipe). A
//! sample off by a quarter pixel moves by up to a quarter of the range and fails.

mod common;

use pf_gpu::image::quantised_weight;
use pf_gpu::{DeviceStream, GrayTexture, Kernel};
use proptest::prelude::*;
use proptest::test_runner::TestRunner;

const SAMPLE: &str = r"
@group(0) @binding(0) var frame: texture_2d<f32>;
@group(0) @binding(1) var frame_sampler: sampler;
@group(0) @binding(2) var<storage, read> points: array<vec2<f32>>;
@group(0) @binding(3) var<storage, read_write> levels: array<f32>;

@compute @workgroup_size(64)
fn sample(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    if (i >= arrayLength(&points)) {
        return;
    }
    let size = vec2<f32>(textureDimensions(frame));
    let at = (points[i] + vec2<f32>(0.5, 0.5)) / size;
    levels[i] = 255.0 * textureSampleLevel(frame, frame_sampler, at, 0.0).r;
}
";

/// The CPU twin: bilinear at (x, y) in [0, w−1] × [0, h−1] with 8-bit weights, and the bound.
fn twin(levels: &[u8], width: u32, height: u32, x: f32, y: f32) -> (f32, f32) {
    let at = |x: u32, y: u32| f32::from(levels[(y * width + x) as usize]);
    let (x0, y0) = ((x as u32).min(width - 2), (y as u32).min(height - 2));
    let (fx, fy) = (
        quantised_weight(x - x0 as f32),
        quantised_weight(y - y0 as f32),
    );
    let cell = [
        at(x0, y0),
        at(x0 + 1, y0),
        at(x0, y0 + 1),
        at(x0 + 1, y0 + 1),
    ];
    let top = cell[0] * (1.0 - fx) + cell[1] * fx;
    let bottom = cell[2] * (1.0 - fx) + cell[3] * fx;
    let range = cell.iter().cloned().fold(f32::MIN, f32::max)
        - cell.iter().cloned().fold(f32::MAX, f32::min);
    (top * (1.0 - fy) + bottom * fy, 2.0 * range / 256.0 + 1.0)
}

#[test]
fn texture_sampling_matches_cpu_within_tolerance() {
    let Some(ctx) = common::gpu_context("texture sampling") else {
        return;
    };
    let kernel = Kernel::new(&ctx, "texture sample", SAMPLE, "sample").unwrap();
    let mut runner = TestRunner::new(common::property::config(12));
    let strategy = (any::<u64>(), 2u32..300, 2u32..200, 1usize..2000);
    let worst = std::cell::Cell::new(0.0f32);
    runner
        .run(&strategy, |(seed, width, height, count)| {
            let mut rng = pf_core::RandomStreams::new(seed).stream(0, pf_core::Stage::Model(9));
            let levels: Vec<u8> = (0..width * height)
                .map(|_| (rng.uniform() * 256.0) as u8)
                .collect();
            // Anywhere, on pixel centres, on cell edges, on the last row and column.
            let (w1, h1) = ((width - 1) as f32, (height - 1) as f32);
            let points: Vec<[f32; 2]> = (0..count)
                .map(|i| {
                    let (u, v) = (rng.uniform() as f32, rng.uniform() as f32);
                    match i % 4 {
                        0 => [u * w1, v * h1],
                        1 => [(u * w1).floor(), (v * h1).floor()],
                        2 => [w1, v * h1],
                        _ => [(u * w1).floor() + 0.5, h1],
                    }
                })
                .collect();
            let texture = GrayTexture::new(&ctx, "frame", width, height).unwrap();
            texture.upload(&ctx, &levels).unwrap();
            let at = DeviceStream::from_slice(&ctx, "points", &points).unwrap();
            let out = DeviceStream::<f32>::zeroed(&ctx, "levels", count).unwrap();
            let group = kernel
                .bind(
                    &ctx,
                    &[
                        (0, texture.binding()),
                        (1, texture.sampler_binding()),
                        (2, at.binding()),
                        (3, out.binding()),
                    ],
                )
                .unwrap();
            let mut encoder = ctx.device.create_command_encoder(&Default::default());
            {
                let mut pass = encoder.begin_compute_pass(&Default::default());
                kernel.record(&mut pass, &group, [count.div_ceil(64) as u32, 1, 1]);
            }
            ctx.queue.submit([encoder.finish()]);
            let got = out.download(&ctx).unwrap();
            for (p, g) in points.iter().zip(&got) {
                let (want, bound) = twin(&levels, width, height, p[0], p[1]);
                worst.set(worst.get().max((g - want).abs()));
                prop_assert!(
                    (g - want).abs() <= bound,
                    "{width}x{height} at {p:?}: GPU {g} vs CPU {want} (bound {bound})"
                );
            }
            Ok(())
        })
        .unwrap_or_else(common::property::report);
    eprintln!(
        "texture sampling: largest |GPU − CPU twin| {} levels",
        worst.get()
    );
}

#[test]
fn a_frame_larger_than_the_adapter_allows_is_an_error() {
    let Some(ctx) = common::gpu_context("texture limits") else {
        return;
    };
    let limit = ctx.device.limits().max_texture_dimension_2d;
    let error = GrayTexture::new(&ctx, "frame", limit + 1, 2).unwrap_err();
    assert!(error.to_string().contains(&limit.to_string()), "{error}");
    assert!(GrayTexture::new(&ctx, "frame", 0, 2).is_err());
    let texture = GrayTexture::new(&ctx, "frame", 4, 3).unwrap();
    assert_eq!(texture.size(), (4, 3));
    assert!(texture.upload(&ctx, &[0; 11]).is_err());
    assert!(texture.upload(&ctx, &[0; 12]).is_ok());
}
