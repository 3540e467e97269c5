//! Synthetic sequences, depth PNGs and sequence directories: what is rendered lies on the skin,
//! the degradations do what they say, files round-trip, and bad files are clear errors.

use body_tracker::camera::{DepthImage, Intrinsics, read_depth_png, write_depth_png};
use body_tracker::human::human_skeleton;
use body_tracker::likelihood::point_min_distance;
use body_tracker::sequence::{FrameFormat, SequenceDir, write_synthetic};
use body_tracker::synth::{Motion, SynthConfig, pose_at, render};
use nalgebra::Vector3;
use proptest::prelude::*;

fn clean(frames: usize) -> SynthConfig {
    SynthConfig {
        depth_noise: 0.0,
        dropout: 0.0,
        outliers: 0.0,
        ..SynthConfig::small(frames).unwrap()
    }
}

fn scratch(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("streampf-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn clean_points_lie_on_the_visible_skin() {
    let skeleton = human_skeleton(48).unwrap();
    for motion in [Motion::Walk, Motion::Wave, Motion::WalkWave] {
        let config = SynthConfig {
            motion,
            ..clean(40)
        };
        for frame in [0, 13, 39] {
            let theta = pose_at(&skeleton, &config, frame).unwrap();
            let capsules = skeleton.capsules(&theta).unwrap();
            let points = render(&skeleton, &theta, &config, frame).unwrap().points;
            assert!(
                points.len() > 300,
                "{motion:?} frame {frame}: {}",
                points.len()
            );
            for p in &points {
                // Each point is the first hit of its own ray (up to the 1 mm depth quantum).
                let depth = p.norm();
                let d = point_min_distance(&capsules, &Vector3::zeros(), &(p / depth), depth, 0.1);
                assert!(
                    d < 2e-3,
                    "{motion:?} frame {frame}: point {p:?} is {d} m off the skin"
                );
            }
        }
    }
}

#[test]
fn the_motion_moves_and_respects_the_joint_limits() {
    let skeleton = human_skeleton(19).unwrap();
    let (lo, hi) = skeleton.limits();
    let config = clean(60);
    let first = pose_at(&skeleton, &config, 0).unwrap();
    let mut moved: f32 = 0.0;
    for frame in 0..60 {
        let theta = pose_at(&skeleton, &config, frame).unwrap();
        for d in 0..theta.len() {
            assert!(
                theta[d] >= lo[d] && theta[d] <= hi[d],
                "frame {frame} value {d}"
            );
        }
        let joints = skeleton.tracked_joint_positions(&theta).unwrap();
        let start = skeleton.tracked_joint_positions(&first).unwrap();
        moved = moved.max(
            joints
                .iter()
                .zip(&start)
                .map(|(a, b)| (a - b).norm())
                .fold(0.0, f32::max),
        );
    }
    assert!(moved > 0.5, "the fastest joint moved only {moved} m");
}

#[test]
fn dropout_and_outliers_take_their_fractions() {
    let skeleton = human_skeleton(19).unwrap();
    let base = clean(1);
    let theta = pose_at(&skeleton, &base, 0).unwrap();
    let all = render(&skeleton, &theta, &base, 0).unwrap().points.len() as f32;
    let dropped = SynthConfig {
        dropout: 0.3,
        ..base.clone()
    };
    let kept = render(&skeleton, &theta, &dropped, 0).unwrap().points.len() as f32;
    let sd = (all * 0.3 * 0.7).sqrt();
    assert!((kept - 0.7 * all).abs() < 5.0 * sd, "kept {kept} of {all}");

    let noisy = SynthConfig {
        outliers: 0.2,
        ..base.clone()
    };
    let capsules = skeleton.capsules(&theta).unwrap();
    let points = render(&skeleton, &theta, &noisy, 0).unwrap().points;
    let off = points
        .iter()
        .filter(|p| {
            let depth = p.norm();
            point_min_distance(&capsules, &Vector3::zeros(), &(*p / depth), depth, 0.1) > 0.01
        })
        .count() as f32;
    // An outlier may land on the skin by chance (its depth is uniform along the ray): a few
    // percent of them.
    let n = points.len() as f32;
    assert!(
        off > 0.15 * n && off < 0.25 * n,
        "{off} of {n} points off the skin"
    );
}

#[test]
fn synthetic_sequences_round_trip_through_ply_and_depth_png() {
    let skeleton = human_skeleton(19).unwrap();
    let config = SynthConfig::small(3).unwrap();
    for format in [FrameFormat::Ply, FrameFormat::DepthPng] {
        let dir = scratch(&format!("{format:?}"));
        let mut seen = Vec::new();
        write_synthetic(&dir, &skeleton, &config, format, |f| seen.push(f)).unwrap();
        assert_eq!(seen, vec![0, 1, 2]);
        let sequence = SequenceDir::open(&dir).unwrap();
        assert_eq!(sequence.format, format);
        assert_eq!(sequence.frames.len(), 3);
        assert_eq!(sequence.skeleton().unwrap().unwrap(), skeleton);
        let truth = sequence.ground_truth(&skeleton).unwrap().unwrap();
        for (frame, truth) in truth.iter().enumerate() {
            let want = pose_at(&skeleton, &config, frame).unwrap();
            for (a, b) in truth.iter().zip(&want) {
                assert!((a - b).abs() <= 1e-6 * (1.0 + b.abs()));
            }
            let rendered = render(&skeleton, &want, &config, frame).unwrap().points;
            let read = sequence.read_frame(frame).unwrap();
            assert_eq!(read.len(), rendered.len());
            for (a, b) in read.iter().zip(&rendered) {
                assert!(
                    (a - b).norm() < 1e-5,
                    "{format:?} frame {frame}: {a:?} vs {b:?}"
                );
            }
        }
        assert!(sequence.read_frame(3).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

#[test]
fn depth_pngs_of_the_wrong_format_are_clear_errors() {
    let dir = scratch("bad-depth");
    let eight_bit = dir.join("gray8.png");
    image::GrayImage::new(4, 3).save(&eight_bit).unwrap();
    let rgb16 = dir.join("rgb16.png");
    image::ImageBuffer::<image::Rgb<u16>, Vec<u16>>::new(4, 3)
        .save(&rgb16)
        .unwrap();
    let truncated = dir.join("truncated.png");
    let good = DepthImage {
        width: 4,
        height: 3,
        depth: (0..12).map(|i| i * 1000).collect(),
    };
    write_depth_png(&truncated, &good).unwrap();
    let bytes = std::fs::read(&truncated).unwrap();
    std::fs::write(&truncated, &bytes[..bytes.len() / 2]).unwrap();
    let text = dir.join("text.png");
    std::fs::write(&text, "not an image").unwrap();
    for (path, expect) in [
        (&eight_bit, "16-bit single-channel"),
        (&rgb16, "16-bit single-channel"),
        (&truncated, "decode"),
        (&text, "PNG"),
        (&dir.join("missing.png"), "missing.png"),
    ] {
        let err = read_depth_png(path).unwrap_err().to_string();
        assert!(err.contains(expect), "{}: {err}", path.display());
    }
    // A depth image that does not match the camera.
    let camera = Intrinsics::with_fov(5, 3, 60.0).unwrap();
    assert!(good.to_points(&camera).is_err());
    assert!(Intrinsics::with_fov(0, 3, 60.0).is_err());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_sequence_directories_are_clear_errors() {
    let dir = scratch("bad-sequence");
    assert!(
        SequenceDir::open(&dir)
            .unwrap_err()
            .to_string()
            .contains("no frames")
    );
    std::fs::write(dir.join("depth_0.png"), "x").unwrap();
    assert!(
        SequenceDir::open(&dir)
            .unwrap_err()
            .to_string()
            .contains("camera.json")
    );
    std::fs::write(dir.join("camera.json"), "{\"width\": 3}").unwrap();
    assert!(
        SequenceDir::open(&dir)
            .unwrap_err()
            .to_string()
            .contains("camera.json")
    );
    let skeleton = human_skeleton(19).unwrap();
    write_synthetic(
        &dir,
        &skeleton,
        &SynthConfig::small(1).unwrap(),
        FrameFormat::Ply,
        |_| {},
    )
    .unwrap();
    std::fs::write(dir.join("ground_truth.csv"), "frame,a\n0,1\n").unwrap();
    let sequence = SequenceDir::open(&dir).unwrap();
    assert!(
        sequence
            .ground_truth(&skeleton)
            .unwrap_err()
            .to_string()
            .contains("columns")
    );
    let mut row = vec!["0".to_string(); skeleton.dofs() + 1];
    row[3] = "oops".into();
    let header = vec!["h"; skeleton.dofs() + 1].join(",");
    std::fs::write(
        dir.join("ground_truth.csv"),
        format!("{header}\n{}\n", row.join(",")),
    )
    .unwrap();
    assert!(
        sequence
            .ground_truth(&skeleton)
            .unwrap_err()
            .to_string()
            .contains("line 2")
    );
    let missing = SequenceDir::open(std::path::Path::new("/nonexistent-streampf")).unwrap_err();
    assert!(missing.to_string().contains("nonexistent-streampf"));
    std::fs::remove_dir_all(&dir).unwrap();
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, failure_persistence: None, ..ProptestConfig::default() })]

    /// Depth images survive PNG, and back-projection inverts projection.
    #[test]
    fn depth_png_round_trip_and_back_projection(
        width in 1u32..40,
        height in 1u32..30,
        seed in any::<u64>(),
        fov in 20.0f32..120.0,
    ) {
        let mut rng = pf_core::RandomStreams::new(seed).stream(0, pf_core::Stage::Model(0));
        let depth: Vec<u16> = (0..width * height)
            .map(|_| if rng.uniform() < 0.2 { 0 } else { (rng.uniform() * 65535.0) as u16 })
            .collect();
        let image = DepthImage { width, height, depth };
        let dir = scratch(&format!("depth-prop-{seed}"));
        let path = dir.join("d.png");
        write_depth_png(&path, &image).unwrap();
        let back = read_depth_png(&path).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        prop_assert_eq!(&back, &image);
        let camera = Intrinsics::with_fov(width, height, fov).unwrap();
        let points = image.to_points(&camera).unwrap();
        prop_assert_eq!(points.len(), image.depth.iter().filter(|&&d| d > 0).count());
        let measured = (0..width * height).filter(|&i| image.depth[i as usize] > 0);
        for (p, i) in points.iter().zip(measured) {
            let (u, v) = camera.project(p).unwrap();
            prop_assert!((u - (i % width) as f32).abs() < 1e-3 && (v - (i / width) as f32).abs() < 1e-3);
            prop_assert!((p.z - f32::from(image.depth[i as usize]) * 0.001).abs() < 1e-3);
        }
    }
}
