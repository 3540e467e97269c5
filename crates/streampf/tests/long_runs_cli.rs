//! Long runs lose nothing: a face run and a body run interrupted part-way (SIGINT from the test)
//! keep whole rows of every finished frame and a finalised overlay video; a video cut short says
//! so with a non-zero exit (or a warning with --allow-short). Needs FFmpeg (`cargo xtask
//! fetch-media` installs it) unless STREAMPF_NO_MEDIA=1 opts out of the video checks.

mod common;

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use common::{failure, ok, scratch, streampf};

const INTERRUPTED_EXIT: i32 = 130;

fn spawn(args: &[&str]) -> Child {
    Command::new(env!("CARGO_BIN_EXE_streampf"))
        .args(args)
        .env("NODEVICE_SELECT", "1")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("the streampf binary runs")
}

/// Waits until `file` has more than `rows` lines, then sends SIGINT; returns the run's output.
fn interrupt_after_rows(mut child: Child, file: &Path, rows: usize) -> std::process::Output {
    let started = Instant::now();
    loop {
        let lines = std::fs::read_to_string(file).map_or(0, |t| t.lines().count());
        if lines > rows {
            break;
        }
        if let Ok(Some(status)) = child.try_wait() {
            panic!("the run ended ({status}) before it was interrupted");
        }
        assert!(
            started.elapsed() < Duration::from_secs(120),
            "no rows after 120 s"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    let sent = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(sent.success());
    child.wait_with_output().unwrap()
}

/// The columns of the face's states.csv: frame, timestamp, track, success, status, the 7-D state,
/// ε, its 7 spreads, the ESS, the log evidence, the confidence, pitch/yaw/roll, the
/// quaternion's 4 and the identity.
const STATES_COLUMNS: usize = 5 + 7 + 1 + 7 + 3 + 3 + 4 + 1;

/// The frame column of a CSV's rows, checking that every row is whole (`columns` fields, each a
/// number or a status word) and that the file ends with a newline.
fn frames_of(path: &Path, columns: usize) -> Vec<usize> {
    let text = std::fs::read_to_string(path).unwrap();
    assert!(text.ends_with('\n'), "{} ends inside a row", path.display());
    text.lines()
        .skip(1)
        .map(|line| {
            let fields: Vec<&str> = line.split(',').collect();
            assert_eq!(fields.len(), columns, "{}: {line}", path.display());
            // Every value a number but the face rows' track (empty when no face), status and,
            // with no face, the estimate's columns.
            let status = ["tracking", "skipped", "none"];
            let no_face = fields.get(4) == Some(&"none");
            for f in &fields[1..] {
                let word = status.contains(f) || f.starts_with("lost@");
                assert!(
                    f.parse::<f64>().is_ok() || word || (no_face && f.is_empty()),
                    "{}: {line}",
                    path.display()
                );
            }
            fields[0].parse().unwrap()
        })
        .collect()
}

fn media_opted_out() -> bool {
    std::env::var_os("STREAMPF_NO_MEDIA").is_some_and(|v| v == "1")
}

#[test]
fn an_interrupted_face_run_keeps_every_finished_frame_and_a_finalised_video() {
    let dir = scratch("face-interrupt");
    let out = dir.join("out");
    let video = dir.join("overlay.mp4");
    let with_video = !media_opted_out();
    let mut args = vec![
        "face",
        "track",
        "--synthetic",
        "--frames",
        "100000",
        "--faces",
        "1",
        "--width",
        "320",
        "--height",
        "240",
        "--backend",
        "cpu",
        "--quiet",
        "--out",
        out.to_str().unwrap(),
    ];
    if with_video {
        args.extend(["--overlay", video.to_str().unwrap()]);
    }
    let run = interrupt_after_rows(spawn(&args), &out.join("states.csv"), 20);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(INTERRUPTED_EXIT), "{stderr}");
    assert!(stderr.contains("interrupted after"), "{stderr}");
    let said: usize = stderr
        .split("interrupted after ")
        .nth(1)
        .and_then(|t| t.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("{stderr}"));
    // One face: one row a frame, frames 0.. in order, as many as the run said it wrote.
    let frames = frames_of(&out.join("states.csv"), STATES_COLUMNS);
    assert_eq!(frames, (0..said).collect::<Vec<_>>());
    assert_eq!(frames_of(&out.join("errors.csv"), 4).len(), said);
    if with_video {
        let probe = Command::new("ffprobe")
            .args(["-v", "error", "-count_frames", "-select_streams", "v:0"])
            .args(["-show_entries", "stream=nb_read_frames", "-of", "csv=p=0"])
            .arg(&video)
            .output()
            .expect("ffprobe runs (cargo xtask fetch-media installs FFmpeg)");
        let decoded = String::from_utf8_lossy(&probe.stdout);
        assert_eq!(
            decoded.trim().parse::<usize>().ok(),
            Some(said),
            "{decoded}"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn an_interrupted_body_run_keeps_every_finished_frame() {
    let dir = scratch("body-interrupt");
    let out = dir.join("out");
    let args = [
        "body",
        "track",
        "--synthetic",
        "--frames",
        "100000",
        "--particles",
        "100",
        "--width",
        "160",
        "--height",
        "120",
        "--backend",
        "cpu",
        "--quiet",
        "--out",
        out.to_str().unwrap(),
    ];
    let run = interrupt_after_rows(spawn(&args), &out.join("poses.csv"), 5);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(INTERRUPTED_EXIT), "{stderr}");
    let poses = std::fs::read_to_string(out.join("poses.csv")).unwrap();
    let columns = poses.lines().next().unwrap().split(',').count();
    let frames = frames_of(&out.join("poses.csv"), columns);
    assert!(frames.len() >= 5 && frames.len() < 100000);
    assert_eq!(frames, (0..frames.len()).collect::<Vec<_>>());
    let joints = std::fs::read_to_string(out.join("joints.csv")).unwrap();
    let joint_columns = joints.lines().next().unwrap().split(',').count();
    assert_eq!(frames_of(&out.join("joints.csv"), joint_columns), frames);
    assert!(
        stderr.contains(&format!("interrupted after {} frames", frames.len())),
        "{stderr}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A one-face synthetic video of `frames` frames at 320×240, encoded by FFmpeg with `codec`
/// (output options) into `dir/name`.
fn encoded_synthetic_video(
    dir: &Path,
    frames: &str,
    name: &str,
    codec: &[&str],
) -> std::path::PathBuf {
    let pngs = dir.join("frames");
    ok(&streampf(&[
        "face",
        "synth",
        "--out",
        pngs.to_str().unwrap(),
        "--frames",
        frames,
        "--faces",
        "1",
        "--width",
        "320",
        "--height",
        "240",
    ]));
    let video = dir.join(name);
    let encoded = Command::new("ffmpeg")
        .args(["-nostdin", "-v", "error", "-y", "-framerate", "25", "-i"])
        .arg(pngs.join("frame_%05d.png"))
        .args(codec)
        .arg(&video)
        .status()
        .expect("ffmpeg runs (cargo xtask fetch-media installs FFmpeg)");
    assert!(encoded.success());
    video
}

#[test]
fn a_video_cut_short_is_a_warning_and_a_non_zero_exit() {
    if media_opted_out() {
        eprintln!("skipped by request (STREAMPF_NO_MEDIA=1)");
        return;
    }
    let dir = scratch("short-video");
    // An mp4 with its index first (as streaming sites serve them), then only its first half.
    let full = encoded_synthetic_video(
        &dir,
        "60",
        "full.mp4",
        &[
            "-c:v",
            "libx264",
            "-pix_fmt",
            "yuv420p",
            "-movflags",
            "+faststart",
        ],
    );
    let bytes = std::fs::read(&full).unwrap();
    let half = dir.join("half.mp4");
    std::fs::write(&half, &bytes[..bytes.len() / 2]).unwrap();
    let out = dir.join("out");
    let args = [
        "face",
        "track",
        half.to_str().unwrap(),
        "--face",
        "100,60,120,120",
        "--backend",
        "cpu",
        "--quiet",
        "--out",
        out.to_str().unwrap(),
    ];
    let err = failure(&streampf(&args));
    assert!(
        err.contains("of the 60 frames its container announces"),
        "{err}"
    );
    assert!(err.contains("--allow-short"), "{err}");
    let decoded: usize = err
        .split("ended after ")
        .nth(1)
        .and_then(|t| t.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("{err}"));
    assert!((1..60).contains(&decoded), "{err}");
    assert_eq!(
        frames_of(&out.join("states.csv"), STATES_COLUMNS).len(),
        decoded
    );
    let run = streampf(&[&args[..], &["--allow-short"]].concat());
    ok(&run);
    let warning = String::from_utf8_lossy(&run.stderr);
    assert!(
        warning.contains("warning: the video ended after"),
        "{warning}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A healthy video whose container announces one frame more than it shows: an mp4 remuxed to
/// start a frame late keeps every sample in its count (an edit list hides the first), as phone
/// and webcam clips often do. A note, not a failed run.
#[test]
fn a_container_that_miscounts_a_healthy_video_is_a_note() {
    if media_opted_out() {
        eprintln!("skipped by request (STREAMPF_NO_MEDIA=1)");
        return;
    }
    let dir = scratch("miscounted-video");
    let full = encoded_synthetic_video(
        &dir,
        "20",
        "full.mp4",
        &["-c:v", "libx264", "-pix_fmt", "yuv420p"],
    );
    let remuxed = dir.join("remuxed.mp4");
    let copied = Command::new("ffmpeg")
        .args(["-nostdin", "-v", "error", "-y", "-ss", "0.04", "-i"])
        .arg(&full)
        .args(["-c", "copy"])
        .arg(&remuxed)
        .status()
        .unwrap();
    assert!(copied.success());
    let out = dir.join("out");
    let run = streampf(&[
        "face",
        "track",
        remuxed.to_str().unwrap(),
        "--face",
        "100,60,120,120",
        "--backend",
        "cpu",
        "--quiet",
        "--out",
        out.to_str().unwrap(),
    ]);
    ok(&run);
    let note = String::from_utf8_lossy(&run.stderr);
    assert!(
        note.contains("note: the video held 19 frames where its container announces 20"),
        "{note}"
    );
    assert_eq!(
        frames_of(&out.join("states.csv"), STATES_COLUMNS),
        (0..19).collect::<Vec<_>>()
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_headless_run_prints_no_mesa_noise() {
    // As a user runs it: no NODEVICE_SELECT, no XDG_RUNTIME_DIR; the GPU path opens Mesa's
    // Vulkan driver (lavapipe here), whose device-selection layer would complain.
    let dir = scratch("quiet-mesa");
    let run = Command::new(env!("CARGO_BIN_EXE_streampf"))
        .args([
            "face",
            "track",
            "--synthetic",
            "--frames",
            "3",
            "--faces",
            "1",
            "--width",
            "320",
        ])
        .args([
            "--height",
            "240",
            "--backend",
            "gpu",
            "--allow-software",
            "--quiet",
            "--out",
        ])
        .arg(dir.join("out"))
        .env_remove("NODEVICE_SELECT")
        .env_remove("XDG_RUNTIME_DIR")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{stderr}");
    assert!(!stderr.contains("XDG_RUNTIME_DIR"), "{stderr}");
    assert!(stderr.trim().is_empty(), "nothing on stderr: {stderr}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_gpu_fault_mid_run_is_a_clear_error_after_every_earlier_frame_is_written() {
    let dir = scratch("gpu-fault");
    let face_out = dir.join("face");
    let body_out = dir.join("body");
    let runs = [
        (
            vec![
                "face",
                "track",
                "--synthetic",
                "--frames",
                "20",
                "--faces",
                "1",
                "--width",
                "320",
                "--height",
                "240",
                "--out",
                face_out.to_str().unwrap(),
            ],
            face_out.join("states.csv"),
            STATES_COLUMNS,
        ),
        (
            vec![
                "body",
                "track",
                "--synthetic",
                "--frames",
                "10",
                "--particles",
                "100",
                "--out",
                body_out.to_str().unwrap(),
            ],
            body_out.join("poses.csv"),
            0,
        ),
    ];
    for (mut args, rows, columns) in runs {
        args.extend(["--backend", "gpu", "--allow-software", "--quiet"]);
        let run = Command::new(env!("CARGO_BIN_EXE_streampf"))
            .args(&args)
            .env("NODEVICE_SELECT", "1")
            .env("STREAMPF_SIMULATE_GPU_FAULT_AT", "4")
            .output()
            .unwrap();
        let err = failure(&run);
        if common::skipped_for_no_gpu(&err) {
            return;
        }
        assert!(
            err.contains("device was lost") && err.contains("frame 4"),
            "{err}"
        );
        assert!(err.contains("the 4 frames before it were written"), "{err}");
        let header = std::fs::read_to_string(&rows).unwrap();
        let columns = if columns == 0 {
            header.lines().next().unwrap().split(',').count()
        } else {
            columns
        };
        assert_eq!(frames_of(&rows, columns), [0, 1, 2, 3], "{args:?}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Runs `args` to the end into `full`, and interrupted then resumed into `part`; the files must
/// be the same. Then a resume with another seed is refused, and one with nothing to resume.
fn as_strs(v: &[String]) -> Vec<&str> {
    v.iter().map(String::as_str).collect()
}

fn resume_matches_an_uninterrupted_run(args: &[&str], files: &[&str], dir: &Path) {
    let (full, part) = (dir.join("full"), dir.join("part"));
    let with_out = |out: &Path, extra: &[&str]| -> Vec<String> {
        let mut a: Vec<String> = args.iter().map(|s| s.to_string()).collect();
        a.extend(["--out".to_string(), out.display().to_string()]);
        a.extend(extra.iter().map(|s| s.to_string()));
        a
    };
    ok(&streampf(&as_strs(&with_out(&full, &[]))));
    let run = interrupt_after_rows(
        spawn(&as_strs(&with_out(&part, &[]))),
        &part.join(files[0]),
        8,
    );
    assert_eq!(run.status.code(), Some(INTERRUPTED_EXIT));
    let text = ok(&streampf(&as_strs(&with_out(&part, &["--resume"]))));
    assert!(!text.is_empty());
    for f in files {
        let (a, b) = (full.join(f), part.join(f));
        assert_eq!(
            std::fs::read_to_string(&a).unwrap(),
            std::fs::read_to_string(&b).unwrap(),
            "{f}: a resumed run's rows must be an uninterrupted run's"
        );
    }
    let err = failure(&streampf(&as_strs(&with_out(
        &part,
        &["--resume", "--seed", "99"],
    ))));
    assert!(err.contains("differs from the interrupted run's"), "{err}");
    let err = failure(&streampf(&as_strs(&with_out(
        &dir.join("empty"),
        &["--resume"],
    ))));
    assert!(err.contains("nothing to resume"), "{err}");
}

#[test]
fn a_resumed_face_run_writes_what_an_uninterrupted_one_writes() {
    let dir = scratch("face-resume");
    resume_matches_an_uninterrupted_run(
        &[
            "face",
            "track",
            "--synthetic",
            "--frames",
            "400",
            "--faces",
            "2",
            "--width",
            "320",
            "--height",
            "240",
            "--backend",
            "cpu",
            "--quiet",
        ],
        &["states.csv", "errors.csv"],
        &dir,
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_resumed_body_run_writes_what_an_uninterrupted_one_writes() {
    let dir = scratch("body-resume");
    resume_matches_an_uninterrupted_run(
        &[
            "body",
            "track",
            "--synthetic",
            "--frames",
            "80",
            "--particles",
            "100",
            "--width",
            "160",
            "--height",
            "120",
            "--backend",
            "cpu",
            "--quiet",
        ],
        &["poses.csv", "joints.csv", "errors.csv"],
        &dir,
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_corrupt_frame_in_the_middle_of_a_video_is_skipped_and_named() {
    if media_opted_out() {
        eprintln!("skipped by request (STREAMPF_NO_MEDIA=1)");
        return;
    }
    let dir = scratch("corrupt-video");
    // Motion JPEG: every frame its own JPEG, so that damage stays in frame 10.
    let video = encoded_synthetic_video(&dir, "30", "mjpeg.avi", &["-c:v", "mjpeg", "-q:v", "3"]);
    let mut bytes = std::fs::read(&video).unwrap();
    let starts: Vec<usize> = (0..bytes.len() - 2)
        .filter(|&i| bytes[i..i + 3] == [0xff, 0xd8, 0xff])
        .collect();
    assert_eq!(starts.len(), 30, "one JPEG a frame");
    // Frame 10's tables (right after its start marker) and its scan: with the scan alone
    // damaged FFmpeg's decoder may still put out a frame, and the content decides (the test
    // broke when the synthetic renderer changed).
    for k in (starts[10] + 20..starts[10] + 400)
        .chain(starts[10] + 700..starts[11] - 100)
        .step_by(5)
    {
        bytes[k] = 0xff;
    }
    std::fs::write(&video, &bytes).unwrap();
    let out = dir.join("out");
    let run = streampf(&[
        "face",
        "track",
        video.to_str().unwrap(),
        "--face",
        "100,60,120,120",
        "--backend",
        "cpu",
        "--quiet",
        "--out",
        out.to_str().unwrap(),
    ]);
    let text = ok(&run);
    assert!(
        text.contains("through 30 frames") && text.contains("skipped (10;"),
        "{text}"
    );
    let warning = String::from_utf8_lossy(&run.stderr);
    assert!(warning.contains("skipping frame 10"), "{warning}");
    let states = std::fs::read_to_string(out.join("states.csv")).unwrap();
    let statuses: Vec<&str> = states
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(4).unwrap())
        .collect();
    assert_eq!(statuses.len(), 30);
    assert_eq!(statuses[10], "skipped");
    assert!(
        statuses
            .iter()
            .enumerate()
            .all(|(f, s)| f == 10 || *s == "tracking"),
        "{statuses:?}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
