//! The Rust Viola–Jones detector against OpenCV's own on real photographs: for each of the four
//! frontal-face Haar cascades of Debian's opencv-data, the faces found must match one to one
//! (IoU ≥ 0.5). OpenCV runs as a test-only reference (`tests/reference/opencv_detect.py`, Python's
//! opencv-python-headless) on the same 8-bit gray frames the Rust detector sees.
//!
//! Needs `cargo xtask fetch-media` (which `cargo xtask test` runs): the photographs in
//! target/media/images, opencv-data's cascades and OpenCV's Python package. Without them the test
//! fails with instructions, unless STREAMPF_NO_MEDIA=1 opts out explicitly.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use face_tracker::GrayImage;
use face_tracker::detect::{Cascade, DetectConfig, Detection};

use common::media::{self, HELP, cascade_path};

const CASCADES: [&str; 4] = [
    "haarcascade_frontalface_alt2.xml",
    "haarcascade_frontalface_alt.xml",
    "haarcascade_frontalface_default.xml",
    "haarcascade_frontalface_alt_tree.xml",
];

/// The inputs, or `None` when the run opted out; a panic with instructions when they are missing.
fn media() -> Option<Vec<PathBuf>> {
    if media::opted_out("the detector against OpenCV") {
        return None;
    }
    let images = media::photographs();
    for c in CASCADES {
        media::cascade_path(c);
    }
    Some(images)
}

/// OpenCV's faces per frame, from the reference script.
fn opencv_faces(cascade: &Path, frames: &[PathBuf], min_size: u32) -> Vec<Vec<[i32; 4]>> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/reference/opencv_detect.py");
    let output = Command::new("python3")
        .arg(script)
        .arg(cascade)
        .arg(min_size.to_string())
        .args(frames)
        .output()
        .unwrap_or_else(|e| panic!("cannot run python3: {e}; {HELP}"));
    assert!(
        output.status.success(),
        "OpenCV's reference failed: {}; {HELP}",
        String::from_utf8_lossy(&output.stderr)
    );
    String::from_utf8_lossy(&output.stdout)
        .lines()
        .map(|line| {
            // {"image": "...", "faces": [[x, y, w, h], ...]}
            let faces = &line[line.find("\"faces\":").expect("a faces field") + 8..];
            let numbers: Vec<i32> = faces
                .split(|c: char| !c.is_ascii_digit() && c != '-')
                .filter(|t| !t.is_empty())
                .map(|t| t.parse().unwrap())
                .collect();
            numbers
                .chunks(4)
                .map(|c| [c[0], c[1], c[2], c[3]])
                .collect()
        })
        .collect()
}

#[test]
fn finds_the_faces_opencv_finds_on_real_photographs() {
    let Some(images) = media() else {
        return;
    };
    let dir = std::env::temp_dir().join(format!("streampf-detect-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // The frames both detectors see: the photographs as the tracker reads them (8-bit gray).
    let frames: Vec<(PathBuf, GrayImage)> = images
        .iter()
        .map(|p| {
            let gray = GrayImage::load(p).unwrap();
            let path = dir.join(p.file_name().unwrap());
            gray.save_png(&path).unwrap();
            (path, gray)
        })
        .collect();
    let paths: Vec<PathBuf> = frames.iter().map(|f| f.0.clone()).collect();
    let config = DetectConfig::default();
    let mut faces_in_astronaut = 0;
    for name in CASCADES {
        let path = cascade_path(name);
        let cascade = Cascade::load(&path).unwrap();
        let reference = opencv_faces(&path, &paths, config.min_size);
        assert_eq!(reference.len(), frames.len());
        for ((frame_path, frame), want) in frames.iter().zip(&reference) {
            let got = cascade.detect(frame, &config).unwrap();
            let image = frame_path.file_name().unwrap().to_string_lossy();
            assert_eq!(
                got.len(),
                want.len(),
                "{name} on {image}: ours {got:?}, OpenCV {want:?}"
            );
            for w in want {
                let w = Detection {
                    x: w[0],
                    y: w[1],
                    width: w[2],
                    height: w[3],
                    neighbors: 0,
                };
                assert!(
                    got.iter().any(|g| g.iou(&w) >= 0.5),
                    "{name} on {image}: OpenCV's {w:?} not among ours {got:?}"
                );
            }
            if image == "astronaut.png" {
                faces_in_astronaut += got.len();
            }
        }
    }
    // The set has a face, and every cascade finds it (not a comparison of empty lists).
    assert!(faces_in_astronaut >= CASCADES.len(), "{faces_in_astronaut}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn all_four_frontal_cascades_parse() {
    if media().is_none() {
        return;
    }
    for name in CASCADES {
        let cascade = Cascade::load(&cascade_path(name)).unwrap();
        assert!(
            cascade.stages.len() >= 20,
            "{name}: {} stages",
            cascade.stages.len()
        );
        assert!(matches!(
            (cascade.width, cascade.height),
            (20, 20) | (24, 24)
        ));
        assert!(!cascade.features.is_empty());
    }
}
