//! Viola–Jones detection time per frame (opencv-data's frontal alt2 cascade, OpenCV's default
//! settings: scale factor 1.1, three neighbours), on the synthetic four-face frame at the paper's
//! 1024×768 and at 640×480, and on scikit-image's astronaut photograph (512×512) when
//! `cargo xtask fetch-media` has fetched it: on the CPU (one detection spreads over all cores:
//! its levels and rows run in parallel) and on the GPU (`GpuCascade`: the host resizes the
//! pyramid on all cores, one submission does the rest). This is the detector's cost per frame it
//! is handed.

use std::path::{Path, PathBuf};

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use face_tracker::GrayImage;
use face_tracker::detect::{Cascade, DetectConfig, GpuCascade};
use face_tracker::model::FaceModel;
use face_tracker::synth::{FaceSynthConfig, render_frame};
use pf_gpu::{ContextOptions, GpuContext};

/// Where the cascades are: $STREAMPF_CASCADES, else opencv-data's directory.
fn cascade_path() -> PathBuf {
    std::env::var_os("STREAMPF_CASCADES")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("/usr/share/opencv4/haarcascades"))
        .join("haarcascade_frontalface_alt2.xml")
}

/// Where fetch-media put the photographs: $STREAMPF_MEDIA, else target/media.
fn media_dir() -> PathBuf {
    std::env::var_os("STREAMPF_MEDIA")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("target/media"))
}

fn bench(c: &mut Criterion) {
    let cascade = Cascade::load(&cascade_path()).unwrap_or_else(|e| {
        panic!("{e}: run `cargo xtask fetch-media` (it installs Debian's opencv-data)")
    });
    let model = FaceModel::generic(129).unwrap();
    let mut frames: Vec<(String, GrayImage)> = [(1024, 768), (640, 480)]
        .into_iter()
        .map(|(width, height)| {
            let video = FaceSynthConfig {
                width,
                height,
                half_width: 60.0 * width as f32 / 1024.0,
                ..FaceSynthConfig::paper(1)
            };
            (
                format!("synthetic_{width}x{height}"),
                render_frame(&video, &model, 0).unwrap(),
            )
        })
        .collect();
    let astronaut = media_dir().join("images/astronaut.png");
    if let Ok(photo) = GrayImage::load(&astronaut) {
        frames.push(("astronaut_512x512".into(), photo));
    } else {
        eprintln!(
            "{} not fetched: run `cargo xtask fetch-media` to time a photograph too",
            astronaut.display()
        );
    }
    let gpu = GpuContext::new(&ContextOptions::default())
        .or_else(|_| GpuContext::new(&ContextOptions::for_tests()))
        .unwrap_or_else(|e| panic!("the detection bench times the GPU too and needs one: {e}"));
    let a = gpu.adapter();
    eprintln!("GPU adapter: {} ({}, {})", a.name, a.device_type, a.backend);
    let gpu = GpuCascade::new(gpu, cascade.clone()).unwrap();
    let mut group = c.benchmark_group("face_detection");
    group.sample_size(10);
    for min_size in [30u32, 60] {
        let config = DetectConfig {
            min_size,
            ..DetectConfig::default()
        };
        for (name, frame) in &frames {
            let found = cascade.detect(frame, &config).unwrap();
            let found_on_gpu = gpu.detect(frame, &config).unwrap();
            eprintln!(
                "{name}, smallest face {min_size} px: {} faces on the CPU, {} on the GPU",
                found.len(),
                found_on_gpu.len()
            );
            group.bench_with_input(
                BenchmarkId::new(format!("min_{min_size}px"), name),
                frame,
                |b, frame| b.iter(|| cascade.detect(frame, &config).unwrap()),
            );
            group.bench_with_input(
                BenchmarkId::new(format!("gpu_min_{min_size}px"), name),
                frame,
                |b, frame| b.iter(|| gpu.detect(frame, &config).unwrap()),
            );
        }
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
