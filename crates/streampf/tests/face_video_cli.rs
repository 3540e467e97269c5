//! `streampf face track VIDEO` as a user runs it: FFmpeg decodes the video, the detector finds
//! the faces, the landmark fit personalises their face models, the tracker follows them, FFmpeg
//! encodes the annotated video. Needs FFmpeg, opencv-data's cascade and libdlib-data's landmark
//! model (`cargo xtask fetch-media` installs them); without them the tests fail with
//! instructions unless STREAMPF_NO_MEDIA=1 opts out explicitly.

mod common;

use std::path::Path;
use std::process::Command;

use common::{failure, ffmpeg, number_after, ok, opted_out, scratch, streampf};

const HELP: &str = "run `cargo xtask fetch-media` (it installs FFmpeg, opencv-data, opencv-doc and libdlib-data), or set STREAMPF_NO_MEDIA=1 to skip the tests on real media explicitly";

/// Frames in a video, counted by decoding it.
fn frames_in(video: &Path) -> usize {
    let out = Command::new("ffprobe")
        .args(["-v", "error", "-count_frames", "-select_streams", "v:0"])
        .args(["-show_entries", "stream=nb_read_frames", "-of", "csv=p=0"])
        .arg(video)
        .output()
        .unwrap_or_else(|e| panic!("ffprobe: {e}; {HELP}"));
    String::from_utf8_lossy(&out.stdout).trim().parse().unwrap()
}

#[test]
fn tracks_the_faces_of_encoded_videos_and_writes_an_annotated_one() {
    if opted_out("face track on encoded videos") {
        return;
    }
    let data = scratch("video-data");
    let d = data.to_str().unwrap();
    ok(&streampf(&[
        "face",
        "synth",
        "--out",
        d,
        "--frames",
        "12",
        "--faces",
        "2",
        "--width",
        "640",
        "--height",
        "480",
        "--max-yaw",
        "20",
    ]));
    for (container, codec) in [("mp4", "libx264"), ("avi", "mpeg4"), ("webm", "libvpx-vp9")] {
        let video = data.join(format!("faces.{container}"));
        let pattern = data.join("frame_%05d.png");
        ffmpeg(
            &[
                "-framerate",
                "25",
                "-i",
                pattern.to_str().unwrap(),
                "-c:v",
                codec,
                "-pix_fmt",
                "yuv420p",
                video.to_str().unwrap(),
            ],
            HELP,
        );
        let out = data.join(format!("out-{container}"));
        let annotated = data.join(format!("annotated-{container}.mp4"));
        let text = ok(&streampf(&[
            "face",
            "track",
            video.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--overlay",
            annotated.to_str().unwrap(),
            "--particles",
            "200",
            "--detect-every",
            "2",
            "--backend",
            "cpu",
        ]));
        assert!(text.contains("of 640x480"), "{text}");
        // Both faces are found (by the detector: nothing told the tracker where they are).
        assert_eq!(number_after(&text, "tracked"), 2.0, "{container}: {text}");
        let states = std::fs::read_to_string(out.join("states.csv")).unwrap();
        let last: Vec<&str> = states.lines().filter(|l| l.starts_with("11,")).collect();
        assert_eq!(
            last.len(),
            2,
            "{container}: both faces tracked at the last frame\n{states}"
        );
        assert!(last.iter().all(|l| l.contains(",tracking,")), "{states}");
        assert_eq!(frames_in(&annotated), 12, "{container}");
    }
    std::fs::remove_dir_all(&data).unwrap();
}

#[test]
fn videos_that_cannot_be_read_are_clear_errors() {
    if opted_out("bad video files") {
        return;
    }
    let data = scratch("bad-video");
    std::fs::create_dir_all(&data).unwrap();
    let missing = data.join("missing.mp4");
    let err = failure(&streampf(&["face", "track", missing.to_str().unwrap()]));
    assert!(
        err.contains("missing.mp4") && err.contains("no such file"),
        "{err}"
    );
    let garbage = data.join("garbage.mp4");
    std::fs::write(&garbage, "this is not a video").unwrap();
    let err = failure(&streampf(&["face", "track", garbage.to_str().unwrap()]));
    assert!(
        err.contains("garbage.mp4") && err.contains("FFmpeg cannot decode"),
        "{err}"
    );
    // An annotated output FFmpeg has no encoder for.
    let err = failure(&streampf(&[
        "face",
        "track",
        "--synthetic",
        "--frames",
        "2",
        "--overlay",
        "out.gif",
    ]));
    assert!(err.contains("out.gif") && err.contains(".mp4"), "{err}");
    // No FFmpeg on the PATH: the error says how to install it.
    let out = Command::new(env!("CARGO_BIN_EXE_streampf"))
        .args(["face", "track", garbage.to_str().unwrap()])
        .env("PATH", "")
        .output()
        .unwrap();
    let err = failure(&out);
    assert!(err.contains("apt-get install ffmpeg"), "{err}");
    // A landmark model that is not one: a clear error before any tracking.
    let not_a_model = data.join("landmarks.dat");
    std::fs::write(&not_a_model, "version 1").unwrap();
    for model in [not_a_model, data.join("missing.dat")] {
        let err = failure(&streampf(&[
            "face",
            "track",
            "--synthetic",
            "--frames",
            "2",
            "--landmarks",
            model.to_str().unwrap(),
        ]));
        let name = model.file_name().unwrap().to_str().unwrap();
        assert!(
            err.contains(name) && err.contains("landmark model"),
            "{err}"
        );
    }
    std::fs::remove_dir_all(&data).unwrap();
}

/// The clip of OpenCV's samples (Debian's opencv-doc).
const MEGAMIND: &str = "/usr/share/doc/opencv-doc/examples/data/Megamind.avi";

#[test]
fn finds_and_keeps_both_faces_of_the_first_shot_of_megamind() {
    if opted_out("face track on Megamind.avi") {
        return;
    }
    assert!(
        Path::new(MEGAMIND).is_file(),
        "{MEGAMIND} is missing; {HELP}"
    );
    let landmarks = "/usr/share/dlib/shape_predictor_68_face_landmarks.dat";
    assert!(
        Path::new(landmarks).is_file(),
        "{landmarks} is missing; {HELP}"
    );
    let out = scratch("megamind");
    let text = ok(&streampf(&[
        "face",
        "track",
        MEGAMIND,
        "--landmarks",
        landmarks,
        "--max-frames",
        "60",
        "--particles",
        "300",
        "--out",
        out.to_str().unwrap(),
        "--backend",
        "cpu",
    ]));
    assert!(text.contains("of 720x528"), "{text}");
    // The faces' templates are built on models personalised to their landmarks.
    let personalised = number_after(&text, "personalised to the landmarks of");
    assert!(personalised >= 2.0, "{text}");
    // The first shot (frames 0-97) has the woman in front and a man behind her; the first frame
    // is black. Both are found within the first 20 frames and are still tracked at frame 59,
    // each by one track.
    let states = std::fs::read_to_string(out.join("states.csv")).unwrap();
    let rows: Vec<Vec<&str>> = states
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect())
        .collect();
    let first_frame = |track: &str| {
        rows.iter()
            .find(|r| r[2] == track)
            .map(|r| r[0].parse::<usize>().unwrap())
    };
    let last: Vec<&Vec<&str>> = rows.iter().filter(|r| r[0] == "59").collect();
    assert_eq!(last.len(), 2, "{states}");
    for row in &last {
        assert_eq!(row[4], "tracking", "{row:?}");
        assert!(first_frame(row[2]).unwrap() <= 20, "{row:?}");
    }
    // The woman's face is left of centre, the man's to the right of her (x ≈ 470-500).
    let mut xs: Vec<f32> = last.iter().map(|r| r[5].parse().unwrap()).collect();
    xs.sort_by(f32::total_cmp);
    assert!(
        (250.0..420.0).contains(&xs[0]) && (440.0..540.0).contains(&xs[1]),
        "{xs:?}"
    );
    std::fs::remove_dir_all(&out).unwrap();
}

/// Megamind.avi cuts from its first shot (the woman, a man behind her) to a close-up of another
/// man at frame 98. The tracks of the first shot end at the cut (the detector does not find
/// their faces again there); with `--scene-cut off` a track of the first shot goes on into the
/// second, on whatever its template fits there, until its fit fails (measured: to frame 106;
/// to the run's end at 114 before a shot's first frames went to the detector one after the
/// other): still there six frames after the cut.
#[test]
fn tracks_end_at_a_scene_cut_unless_found_again() {
    if opted_out("face track on Megamind.avi across a cut") {
        return;
    }
    assert!(
        Path::new(MEGAMIND).is_file(),
        "{MEGAMIND} is missing; {HELP}"
    );
    let run = |scene_cut: &str| {
        let out = scratch(&format!("megamind-cut-{scene_cut}"));
        let text = ok(&streampf(&[
            "face",
            "track",
            MEGAMIND,
            "--max-frames",
            "115",
            "--particles",
            "300",
            "--scene-cut",
            scene_cut,
            "--out",
            out.to_str().unwrap(),
            "--backend",
            "cpu",
        ]));
        let states = std::fs::read_to_string(out.join("states.csv")).unwrap();
        std::fs::remove_dir_all(&out).unwrap();
        let rows: Vec<(usize, String, String)> = (states.lines().skip(1))
            .map(|l| {
                let r: Vec<&str> = l.split(',').collect();
                (r[0].parse().unwrap(), r[2].to_owned(), r[4].to_owned())
            })
            .collect();
        (text, rows)
    };
    let (text, rows) = run("0.25");
    // The black first frame's fade-in may count as a cut too (no track runs there).
    let cuts = (text.lines())
        .find_map(|l| l.strip_prefix("scene cuts at frames "))
        .and_then(|l| l.split(':').next())
        .unwrap_or_else(|| panic!("no scene cuts reported: {text}"));
    assert!(cuts.split(", ").any(|f| f == "98"), "{text}");
    let before_cut: Vec<&String> = (rows.iter())
        .filter(|(frame, _, status)| *frame == 97 && status == "tracking")
        .map(|(_, track, _)| track)
        .collect();
    assert!(!before_cut.is_empty(), "{rows:?}");
    for track in &before_cut {
        let last = rows.iter().rev().find(|(_, t, _)| t == *track).unwrap();
        assert!(
            last.2.starts_with("lost@") && (98..=99).contains(&last.0),
            "track {track} ends at {last:?}"
        );
    }
    let (_, rows) = run("off");
    let carried_over = (rows.iter())
        .filter(|(frame, _, status)| *frame == 104 && status == "tracking")
        .any(|(_, track, _)| {
            rows.iter()
                .any(|(frame, t, s)| *frame == 97 && t == track && s == "tracking")
        });
    assert!(carried_over, "{rows:?}");
    let refused = failure(&streampf(&[
        "face",
        "track",
        MEGAMIND,
        "--scene-cut",
        "2.5",
    ]));
    assert!(refused.contains("below 2"), "{refused}");
}

/// A face that appears late: every frame has a row (no face yet: `success` 0, status `none`, the
/// estimate's columns empty), the timestamps follow the frame rate (25 frames/s for a directory
/// of images), and once the detector has found the face its rows are tracked with a confidence
/// in [0, 1].
#[test]
fn a_face_that_appears_late_has_a_row_for_every_frame() {
    if opted_out("a face that appears late") {
        return;
    }
    const FRAMES: usize = 30;
    const EMPTY: usize = 8;
    let data = scratch("late-face");
    let d = data.to_str().unwrap();
    let frames = FRAMES.to_string();
    ok(&streampf(&[
        "face",
        "synth",
        "--out",
        d,
        "--frames",
        &frames,
        "--faces",
        "2",
        "--width",
        "640",
        "--height",
        "480",
        "--max-yaw",
        "20",
    ]));
    // No face in the first frames; no rectangles, so the detector finds it.
    for k in 0..EMPTY {
        image::GrayImage::from_pixel(640, 480, image::Luma([128]))
            .save(data.join(format!("frame_{k:05}.png")))
            .unwrap();
    }
    std::fs::remove_file(data.join("faces.csv")).unwrap();
    std::fs::remove_file(data.join("ground_truth.csv")).unwrap();
    let out = scratch("late-face-out");
    ok(&streampf(&[
        "face",
        "track",
        d,
        "--out",
        out.to_str().unwrap(),
        "--generic-model",
        "--particles",
        "200",
        "--backend",
        "cpu",
        "--quiet",
    ]));
    let states = std::fs::read_to_string(out.join("states.csv")).unwrap();
    let header: Vec<&str> = states.lines().next().unwrap().split(',').collect();
    let column = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let (frame, timestamp, success, status, confidence) = (
        column("frame"),
        column("timestamp"),
        column("success"),
        column("status"),
        column("confidence"),
    );
    let rows: Vec<Vec<&str>> = states
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect())
        .collect();
    assert!(rows.iter().all(|r| r.len() == header.len()), "{states}");
    let mut seen = [false; FRAMES];
    let mut first_tracked = None;
    for r in &rows {
        let f: usize = r[frame].parse().unwrap();
        seen[f] = true;
        let t: f64 = r[timestamp].parse().unwrap();
        assert!((t - f as f64 / 25.0).abs() < 1e-6, "frame {f} at {t} s");
        if r[success] == "1" {
            assert_eq!(r[status], "tracking");
            let c: f64 = r[confidence].parse().unwrap();
            assert!((0.0..=1.0).contains(&c), "confidence {c}");
            first_tracked.get_or_insert(f);
        } else {
            assert_eq!(r[success], "0");
        }
        if f < EMPTY {
            assert_eq!((r[success], r[status]), ("0", "none"), "{r:?}");
            assert!(r[status + 1..].iter().all(|v| v.is_empty()), "{r:?}");
        }
    }
    assert!(seen.iter().all(|&s| s), "a frame without a row:\n{states}");
    let first = first_tracked.expect("the face was never tracked");
    assert!(
        (EMPTY..FRAMES - 5).contains(&first),
        "first tracked at {first}"
    );
}

#[test]
fn landmarks_out_writes_each_tracked_faces_68_landmarks_every_frame() {
    if opted_out("face track --landmarks-out") {
        return;
    }
    let model = "/usr/share/dlib/shape_predictor_68_face_landmarks.dat";
    assert!(Path::new(model).is_file(), "{model} is missing; {HELP}");
    let data = scratch("landmarks-data");
    let out = scratch("landmarks-out");
    let (d, o) = (data.to_str().unwrap(), out.to_str().unwrap());
    ok(&streampf(&[
        "face", "synth", "--out", d, "--frames", "3", "--faces", "2", "--width", "480", "--height",
        "360",
    ]));
    let text = ok(&streampf(&[
        "face",
        "track",
        d,
        "--landmarks",
        model,
        "--landmarks-out",
        "--particles",
        "200",
        "--backend",
        "cpu",
        "--quiet",
        "--out",
        o,
    ]));
    assert!(text.contains("landmarks.csv"), "{text}");
    let read = |name: &str| -> Vec<Vec<String>> {
        let text = std::fs::read_to_string(out.join(name)).unwrap();
        text.lines()
            .map(|l| l.split(',').map(str::to_string).collect())
            .collect()
    };
    let landmarks = read("landmarks.csv");
    let states = read("states.csv");
    assert_eq!(
        &landmarks[0][..5],
        ["frame", "timestamp", "track", "x0", "y0"]
    );
    assert_eq!(landmarks[0].last().unwrap(), "y67");
    // One row per frame and tracked face, each with 68 finite points.
    assert_eq!(landmarks.len(), 1 + 3 * 2);
    for row in &landmarks[1..] {
        assert_eq!(row.len(), 3 + 2 * 68, "{row:?}");
        let values: Vec<f32> = row[3..].iter().map(|v| v.parse().unwrap()).collect();
        assert!(values.iter().all(|v| v.is_finite()), "{row:?}");
        // The points sit on that face: centred near its estimate (tx, ty in states.csv) and
        // spread over a face's size (the heads are about 56 px wide here), not on one spot.
        let state = states[1..]
            .iter()
            .find(|s| s[0] == row[0] && s[2] == row[2])
            .expect("a states row for each landmarks row");
        let (tx, ty): (f32, f32) = (state[5].parse().unwrap(), state[6].parse().unwrap());
        let xs: Vec<f32> = values.iter().step_by(2).copied().collect();
        let ys: Vec<f32> = values.iter().skip(1).step_by(2).copied().collect();
        let mean = |v: &[f32]| v.iter().sum::<f32>() / v.len() as f32;
        assert!((mean(&xs) - tx).abs() < 20.0, "x {} vs {tx}", mean(&xs));
        assert!((mean(&ys) - ty).abs() < 25.0, "y {} vs {ty}", mean(&ys));
        let width = xs.iter().copied().fold(f32::MIN, f32::max)
            - xs.iter().copied().fold(f32::MAX, f32::min);
        assert!((25.0..120.0).contains(&width), "landmarks {width} px wide");
    }
    // OUTPUT.md documents the file.
    let doc =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/OUTPUT.md"))
            .unwrap();
    assert!(doc.contains("`landmarks.csv`") && doc.contains("`x0`, `y0` … `x67`, `y67`"));
    // Without a landmark model there is nothing to place: a clear error, nothing tracked.
    let err = failure(&streampf(&[
        "face",
        "track",
        d,
        "--generic-model",
        "--landmarks-out",
        "--backend",
        "cpu",
        "--quiet",
        "--out",
        out.join("none").to_str().unwrap(),
    ]));
    assert!(
        err.contains("--landmarks-out needs dlib's 68-landmark model"),
        "{err}"
    );
    std::fs::remove_dir_all(&data).unwrap();
}

#[test]
fn a_colour_video_is_drawn_in_colour_and_tracked_as_without_the_overlay() {
    if opted_out("the overlay of a colour video") {
        return;
    }
    let data = scratch("colour-video");
    let d = data.to_str().unwrap();
    ok(&streampf(&[
        "face", "synth", "--out", d, "--frames", "6", "--faces", "1", "--width", "320", "--height",
        "240",
    ]));
    // A blue tint: FFmpeg's gray of it is what the tracker reads, with or without the overlay.
    let video = data.join("blue.mp4");
    let pattern = data.join("frame_%05d.png");
    ffmpeg(
        &[
            "-framerate",
            "25",
            "-i",
            pattern.to_str().unwrap(),
            "-vf",
            "colorchannelmixer=rr=0.5:gg=0.7:bb=1.0",
            "-c:v",
            "libx264",
            "-pix_fmt",
            "yuv420p",
            video.to_str().unwrap(),
        ],
        HELP,
    );
    let rects = std::fs::read_to_string(data.join("faces.csv")).unwrap();
    let rect = rects.lines().nth(1).unwrap().to_string();
    let track = |out: &str, extra: &[&str]| {
        let out = data.join(out);
        let mut args = vec![
            "face",
            "track",
            video.to_str().unwrap(),
            "--face",
            &rect,
            "--generic-model",
            "--particles",
            "100",
            "--backend",
            "cpu",
            "--quiet",
            "--out",
        ];
        args.push(out.to_str().unwrap());
        args.extend_from_slice(extra);
        ok(&streampf(&args));
        std::fs::read_to_string(out.join("states.csv")).unwrap()
    };
    let drawn = data.join("drawn");
    let with = track("with", &["--overlay", drawn.to_str().unwrap()]);
    let without = track("without", &[]);
    assert_eq!(with, without, "the overlay changed the tracking");
    let frame = image::open(drawn.join("overlay_00005.png"))
        .unwrap()
        .to_rgb8();
    // The background keeps the video's blue.
    let corner = frame.get_pixel(310, 230).0;
    assert!(corner[2] > corner[0] + 15, "{corner:?}");
    std::fs::remove_dir_all(&data).unwrap();
}
