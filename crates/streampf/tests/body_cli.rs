//! `streampf body synth` and `streampf body track` as a user runs them.

mod common;

use common::{failure, number_after, ok, scratch, streampf};
use std::path::Path;

const SMALL: [&str; 10] = [
    "--frames",
    "6",
    "--capsules",
    "19",
    "--width",
    "96",
    "--height",
    "72",
    "--sequence-seed",
    "3",
];

fn lines(path: &Path) -> Vec<String> {
    std::fs::read_to_string(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .lines()
        .map(str::to_string)
        .collect()
}

#[test]
fn synth_then_track_a_directory_of_ply_and_of_depth_pngs() {
    for format in ["ply", "depth-png"] {
        let data = scratch(&format!("data-{format}"));
        let out = scratch(&format!("out-{format}"));
        let d = data.to_str().unwrap();
        let o = out.to_str().unwrap();
        let mut args = vec!["body", "synth", "--out", d, "--format", format];
        args.extend(SMALL);
        let text = ok(&streampf(&args));
        assert!(text.contains("wrote 6 frames"), "{text}");
        // The summary names the format and the motion as the command line spells them.
        assert!(
            text.contains(&format!("({format}, 19 capsules, walk-wave)")),
            "{text}"
        );
        let text = ok(&streampf(&[
            "body",
            "track",
            d,
            "--out",
            o,
            "--particles",
            "200",
            "--backend",
            "cpu",
            "--quiet",
        ]));
        let error = number_after(&text, "mean joint position error:");
        assert!(error > 0.0 && error < 0.15, "{format}: {text}");
        // One header and one row per frame; every pose has the skeleton's 38 values, their 38
        // spreads, the ESS, the log evidence and the confidence.
        let poses = lines(&out.join("poses.csv"));
        assert_eq!(poses.len(), 7);
        assert!(poses[0].starts_with("frame,root_tx,root_ty,root_tz,root_rx"));
        assert!(
            poses[0].contains(",sd_root_tx,") && poses[0].ends_with(",ess,log_evidence,confidence")
        );
        assert!(
            poses
                .iter()
                .all(|l| l.split(',').count() == 1 + 38 + 38 + 3)
        );
        for row in &poses[1..] {
            let values: Vec<f64> = row.split(',').map(|v| v.parse().unwrap()).collect();
            assert!(values[39..77].iter().all(|&sd| sd >= 0.0), "{row}");
            assert!(values[77] >= 1.0 && values[77] <= 200.0, "ESS in {row}");
            assert!(values[78].is_finite(), "log evidence in {row}");
            assert!((0.0..=1.0).contains(&values[79]), "confidence in {row}");
        }
        assert_eq!(lines(&out.join("joints.csv")).len(), 7);
        assert_eq!(lines(&out.join("errors.csv")).len(), 7);
        std::fs::remove_dir_all(&data).unwrap();
        std::fs::remove_dir_all(&out).unwrap();
    }
}

#[test]
fn track_synthetic_prints_the_joint_error_and_the_frame_rate() {
    let out = scratch("synthetic");
    let mut args = vec![
        "body",
        "track",
        "--synthetic",
        "--out",
        out.to_str().unwrap(),
        "--particles",
        "200",
        "--backend",
        "cpu",
    ];
    args.extend(SMALL);
    let text = ok(&streampf(&args));
    assert!(
        text.contains("tracking 6 frames, 19 capsules, 200 particles on CPU"),
        "{text}"
    );
    assert!(
        number_after(&text, "mean joint position error:") < 0.15,
        "{text}"
    );
    assert!(text.contains("frames/s"), "{text}");
    // The share of pose values whose truth lay within ±2 reported sd: a percentage.
    let label = "truth within ±2 reported sd: ";
    let after = &text[text.find(label).expect("the coverage line") + label.len()..];
    let coverage: f64 = after.split('%').next().unwrap().parse().unwrap();
    assert!((0.0..=100.0).contains(&coverage), "{text}");
    std::fs::remove_dir_all(&out).unwrap();
}

#[test]
fn bad_body_inputs_are_clear_errors() {
    let data = scratch("bad");
    let d = data.to_str().unwrap();
    // A directory that does not exist, and one without frames.
    let err = failure(&streampf(&["body", "track", d]));
    assert!(err.contains(d), "{err}");
    std::fs::create_dir_all(&data).unwrap();
    let err = failure(&streampf(&["body", "track", d]));
    assert!(err.contains("no frames"), "{err}");
    // A corrupt PLY frame.
    std::fs::write(
        data.join("frame_0.ply"),
        "ply\nformat ascii 1.0\nelement vertex 2\n",
    )
    .unwrap();
    let err = failure(&streampf(&["body", "track", d, "--backend", "cpu"]));
    assert!(
        err.contains("frame_0.ply") && !err.contains("invalid input"),
        "{err}"
    );
    assert_eq!(
        err.matches("frame_0.ply").count(),
        1,
        "the file named once: {err}"
    );
    std::fs::remove_file(data.join("frame_0.ply")).unwrap();
    // An 8-bit PNG where a 16-bit depth image belongs.
    let mut args = vec!["body", "synth", "--out", d, "--format", "depth-png"];
    args.extend(SMALL);
    ok(&streampf(&args));
    let eight_bit: Vec<u8> = {
        // The smallest valid 8-bit gray PNG, 1x1.
        let mut png = Vec::new();
        let encoder = image::codecs::png::PngEncoder::new(&mut png);
        image::ImageEncoder::write_image(encoder, &[0u8], 1, 1, image::ExtendedColorType::L8)
            .unwrap();
        png
    };
    std::fs::write(data.join("depth_00002.png"), eight_bit).unwrap();
    // Skipped with a warning by default; with --strict the run stops there, keeping frames 0-1.
    let out = data.join("out");
    let o = out.to_str().unwrap();
    let run = streampf(&[
        "body",
        "track",
        d,
        "--backend",
        "cpu",
        "--quiet",
        "--out",
        o,
    ]);
    let text = ok(&run);
    let warning = String::from_utf8_lossy(&run.stderr);
    assert!(
        warning.contains("skipping frame 2") && warning.contains("16-bit single-channel"),
        "{warning}"
    );
    assert!(text.contains("1 unreadable frame skipped (2"), "{text}");
    let err = failure(&streampf(&[
        "body",
        "track",
        d,
        "--backend",
        "cpu",
        "--quiet",
        "--out",
        o,
        "--strict",
    ]));
    assert!(
        err.contains("16-bit single-channel") && err.contains("frame 2"),
        "{err}"
    );
    let poses = std::fs::read_to_string(out.join("poses.csv")).unwrap();
    assert_eq!(
        poses.lines().count(),
        3,
        "a header and frames 0 and 1:\n{poses}"
    );
    assert!(
        !out.join("skipped.csv").exists(),
        "the old run's skipped.csv was removed"
    );
    // A starting pose of the wrong width, and bad numbers.
    let pose = data.join("pose.csv");
    std::fs::write(&pose, "frame,a\n0,1\n").unwrap();
    let err = failure(&streampf(&[
        "body",
        "track",
        "--synthetic",
        "--init-pose",
        pose.to_str().unwrap(),
    ]));
    assert!(err.contains("columns"), "{err}");
    for tau in ["0", "-0.1", "nan", "inf"] {
        let err = failure(&streampf(&[
            "body",
            "track",
            "--synthetic",
            "--backend",
            "cpu",
            &format!("--tau={tau}"),
        ]));
        assert!(err.contains("tau"), "--tau {tau}: {err}");
    }
    for bad in [
        vec!["body", "track", "--synthetic", "--capsules", "200"],
        vec!["body", "track", "--synthetic", "--dropout", "1.5"],
        vec!["body", "track", "--synthetic", "--motion", "dance"],
        vec!["body", "track", "--synthetic", "--fov", "0"],
        vec!["body", "track", "--synthetic", "--particles", "0"],
        vec!["body", "track"],
        vec!["body", "synth", "--out", d, "--frames", "0"],
    ] {
        let err = failure(&streampf(&bad));
        assert!(err.len() > 10, "{bad:?}: {err}");
    }
    std::fs::remove_dir_all(&data).unwrap();
}

/// On a GPU with no particles read back, a run keeps two frames in flight; `--save-particles`
/// reads them every frame, so it steps one frame at a time. Both write the same files and
/// overlay frames, byte for byte.
#[test]
fn track_synthetic_on_the_gpu() {
    let out = scratch("gpu");
    let one_at_a_time = scratch("gpu-one-at-a-time");
    let particles = scratch("gpu-particles");
    let run = |out: &Path, extra: &[&str]| {
        let overlay = out.join("overlay");
        let mut args = vec![
            "body",
            "track",
            "--synthetic",
            "--out",
            out.to_str().unwrap(),
            "--overlay",
            overlay.to_str().unwrap(),
            "--particles",
            "200",
            "--backend",
            "gpu",
            "--allow-software",
        ];
        args.extend(SMALL);
        args.extend(extra);
        streampf(&args)
    };
    let result = run(&out, &[]);
    let err = String::from_utf8_lossy(&result.stderr);
    if !result.status.success() && common::skipped_for_no_gpu(&err) {
        return;
    }
    let text = ok(&result);
    assert!(text.contains("on GPU: "), "{text}");
    assert!(text.contains("(two frames in flight)"), "{text}");
    assert!(
        number_after(&text, "mean joint position error:") < 0.15,
        "{text}"
    );
    let alone = ok(&run(
        &one_at_a_time,
        &["--save-particles", particles.to_str().unwrap()],
    ));
    assert!(!alone.contains("in flight"), "{alone}");
    let read = |dir: &Path, file: &str| std::fs::read(dir.join(file)).unwrap();
    for file in ["poses.csv", "joints.csv", "errors.csv"] {
        assert_eq!(read(&out, file), read(&one_at_a_time, file), "{file}");
    }
    assert_eq!(lines(&out.join("poses.csv")).len(), 1 + 6);
    for frame in 0..6 {
        let file = format!("overlay/overlay_{frame:05}.png");
        assert_eq!(read(&out, &file), read(&one_at_a_time, &file), "{file}");
    }
    for dir in [out, one_at_a_time, particles] {
        std::fs::remove_dir_all(dir).unwrap();
    }
}

#[test]
fn max_frames_stops_a_body_run_early() {
    let out = scratch("max-frames");
    let o = out.to_str().unwrap();
    let mut args = vec![
        "body",
        "track",
        "--synthetic",
        "--out",
        o,
        "--particles",
        "100",
        "--layers",
        "1",
        "--backend",
        "cpu",
        "--quiet",
        "--max-frames",
        "2",
    ];
    args.extend(SMALL);
    let text = ok(&streampf(&args));
    assert!(text.contains("over 2 frames"), "{text}");
    // A header and the two frames tracked.
    assert_eq!(lines(&out.join("poses.csv")).len(), 3);
    let zero = failure(&streampf(&[
        "body",
        "track",
        "--synthetic",
        "--max-frames",
        "0",
    ]));
    assert!(zero.contains("--max-frames"), "{zero}");
}

/// Whether an overlay pixel was drawn on by the estimate (fill, edge or bone), as opposed to the
/// gray depth view or the truth's green outline.
fn estimate_colour(pixel: [u8; 3]) -> bool {
    use body_tracker::overlay::{BONE, ESTIMATE_EDGE};
    // The fill blends orange over gray: red clearly above blue.
    pixel == BONE || pixel == ESTIMATE_EDGE || pixel[0] as i32 - pixel[2] as i32 > 60
}

#[test]
fn an_overlay_frame_has_the_estimate_where_the_ground_truth_body_is() {
    use body_tracker::sequence::SequenceDir;
    let data = scratch("overlay-data");
    let out = scratch("overlay-out");
    let (d, o) = (data.to_str().unwrap(), out.to_str().unwrap());
    let mut args = vec!["body", "synth", "--out", d];
    args.extend([
        "--frames",
        "4",
        "--capsules",
        "19",
        "--width",
        "320",
        "--height",
        "240",
    ]);
    ok(&streampf(&args));
    let overlay = out.join("frames");
    let text = ok(&streampf(&[
        "body",
        "track",
        d,
        "--out",
        o,
        "--particles",
        "200",
        "--backend",
        "cpu",
        "--quiet",
        "--overlay",
        overlay.to_str().unwrap(),
    ]));
    assert!(text.contains("drew the frames to"), "{text}");

    let sequence = SequenceDir::open(&data).unwrap();
    let camera = sequence.camera.expect("body synth writes camera.json");
    let skeleton = sequence
        .skeleton()
        .unwrap()
        .expect("body synth writes skeleton.json");
    let truth = sequence.ground_truth(&skeleton).unwrap().unwrap();
    for (frame, true_pose) in truth.iter().enumerate() {
        let path = overlay.join(format!("overlay_{frame:05}.png"));
        let image = image::open(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let image = image.to_rgb8();
        assert_eq!(image.dimensions(), (320, 240));
        // The middle of every true capsule's axis is covered by the estimate.
        let capsules = skeleton.capsules(true_pose).unwrap();
        let covered = capsules
            .iter()
            .filter(|c| {
                let (u, v) = camera.project(&((c.a + c.b) / 2.0)).unwrap();
                estimate_colour(image.get_pixel(u.round() as u32, v.round() as u32).0)
            })
            .count();
        assert!(
            covered * 10 >= capsules.len() * 9,
            "frame {frame}: {covered} of {} true capsules under the estimate",
            capsules.len()
        );
        // Away from the body the picture is the depth view: no estimate colour in the corners.
        for (x, y) in [(0, 0), (319, 0), (0, 239), (319, 239)] {
            assert!(
                !estimate_colour(image.get_pixel(x, y).0),
                "frame {frame} ({x},{y})"
            );
        }
        // The truth's outline is drawn.
        let green = body_tracker::overlay::TRUTH_EDGE;
        assert!(
            image.pixels().any(|p| p.0 == green),
            "frame {frame}: no truth outline"
        );
    }
    // A resumed run cannot continue a video, and a bad overlay path is refused before any work.
    let err = failure(&streampf(&[
        "body",
        "track",
        d,
        "--out",
        o,
        "--backend",
        "cpu",
        "--quiet",
        "--resume",
        "--overlay",
        out.join("o.mp4").to_str().unwrap(),
    ]));
    assert!(
        err.contains("--resume cannot continue an overlay video"),
        "{err}"
    );
    let err = failure(&streampf(&[
        "body",
        "track",
        d,
        "--out",
        o,
        "--backend",
        "cpu",
        "--quiet",
        "--overlay",
        out.join("o.txt").to_str().unwrap(),
    ]));
    assert!(err.contains("give a directory for PNG frames"), "{err}");
}
