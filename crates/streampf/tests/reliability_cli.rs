//! Nothing lost or clobbered, and every bad input a one-line error: the cases of
//! docs/RELIABILITY.md, each as a user meets it (a closed or full stdout, two runs into one
//! `--out`, refused resumes, an early SIGTERM, a video whose container miscounts its frames,
//! out-of-range options, odd frames in a directory, the messages themselves).

mod common;

use std::path::Path;
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use common::{failure, ok, scratch, streampf};

const INTERRUPTED_EXIT: i32 = 130;

/// A small face run on the CPU: one synthetic face in 160×120 frames.
fn small_face_run(frames: &str, out: &Path) -> Vec<String> {
    [
        "face",
        "track",
        "--synthetic",
        "--faces",
        "1",
        "--width",
        "160",
        "--height",
        "120",
        "--backend",
        "cpu",
        "--frames",
        frames,
        "--out",
        out.to_str().unwrap(),
    ]
    .map(String::from)
    .to_vec()
}

fn strs(v: &[String]) -> Vec<&str> {
    v.iter().map(String::as_str).collect()
}

fn command(args: &[&str]) -> Command {
    let mut command = Command::new(env!("CARGO_BIN_EXE_streampf"));
    command.args(args).env("NODEVICE_SELECT", "1");
    command
}

/// The frame numbers of a CSV's rows (its first column), each row checked whole.
fn frames_in(path: &Path) -> Vec<usize> {
    let text = std::fs::read_to_string(path).unwrap();
    assert!(text.ends_with('\n'), "{} ends inside a row", path.display());
    text.lines()
        .skip(1)
        .map(|l| l.split(',').next().unwrap().parse().unwrap())
        .collect()
}

/// How many distinct frames a CSV holds.
fn distinct_frames(path: &Path) -> usize {
    let mut frames = frames_in(path);
    frames.dedup();
    frames.len()
}

/// Waits until `file` holds more than `rows` lines while `child` runs.
fn wait_for_rows(child: &mut Child, file: &Path, rows: usize) {
    let started = Instant::now();
    while std::fs::read_to_string(file).map_or(0, |t| t.lines().count()) <= rows {
        if let Ok(Some(status)) = child.try_wait() {
            panic!("the run ended ({status}) before it had {rows} rows");
        }
        assert!(started.elapsed() < Duration::from_secs(120), "no rows");
        std::thread::sleep(Duration::from_millis(10));
    }
}

fn stderr_of(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// An error is one line (`Error: ...`), with no Rust debug output, cause chain or backtrace.
fn assert_one_line_error(err: &str) {
    let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "not one line: {err}");
    assert!(lines[0].starts_with("Error: "), "{err}");
    for noise in [
        "Caused by",
        "Error: error:",
        "stack backtrace",
        "panicked",
        " { ",
    ] {
        assert!(!err.contains(noise), "{noise:?} in {err}");
    }
}

// 1. A closed or full stdout.

#[test]
fn a_closed_stdout_ends_quietly_and_every_result_is_written() {
    let dir = scratch("closed-stdout");
    let out = dir.join("out");
    // `streampf face track ... | true`: the reading end is closed before the run prints.
    let mut child = command(&strs(&small_face_run("12", &out)))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let run = child.wait_with_output().unwrap();
    let err = stderr_of(&run);
    assert!(run.status.success(), "{err}");
    assert!(
        !err.contains("panicked") && !err.contains("Broken pipe"),
        "{err}"
    );
    assert_eq!(distinct_frames(&out.join("states.csv")), 12);
    // `streampf config --print-default | head -c 10`.
    let mut child = command(&["config", "--print-default"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let run = child.wait_with_output().unwrap();
    assert!(run.status.success(), "{}", stderr_of(&run));
    assert_eq!(stderr_of(&run), "");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_full_stdout_is_a_one_line_error_after_every_result_is_written() {
    let full = Path::new("/dev/full");
    assert!(full.exists(), "the test needs Linux's /dev/full");
    let dir = scratch("full-stdout");
    let out = dir.join("out");
    let run = command(&strs(&small_face_run("12", &out)))
        .stdout(std::fs::File::create(full).unwrap())
        .output()
        .unwrap();
    let err = failure(&run);
    let last = err.lines().last().unwrap_or_default();
    assert!(
        last.starts_with("Error: writing to standard output:") && last.contains("space"),
        "{err}"
    );
    assert_eq!(distinct_frames(&out.join("states.csv")), 12);
    let run = command(&["config", "--print-default"])
        .stdout(std::fs::File::create(full).unwrap())
        .output()
        .unwrap();
    assert_one_line_error(&failure(&run));
    std::fs::remove_dir_all(&dir).unwrap();
}

// 2 and 3a. Two runs into one --out.

#[test]
fn a_second_run_into_a_busy_out_is_refused_and_the_first_keeps_every_row() {
    let dir = scratch("busy-out");
    let out = dir.join("out");
    let mut first = command(&strs(&small_face_run("150", &out)))
        .arg("--quiet")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    wait_for_rows(&mut first, &out.join("states.csv"), 3);
    // Another run, and a resume with other settings, while the first writes.
    let second = streampf(&strs(&small_face_run("5", &out)));
    let mut resume = small_face_run("150", &out);
    resume.extend(["--resume", "--seed", "2"].map(String::from));
    let resumed = streampf(&strs(&resume));
    for refused in [second, resumed] {
        let err = failure(&refused);
        assert_one_line_error(&err);
        assert!(
            err.contains(out.to_str().unwrap()) && err.contains(&format!("pid {}", first.id())),
            "{err}"
        );
    }
    let run = first.wait_with_output().unwrap();
    assert!(run.status.success(), "{}", stderr_of(&run));
    assert_eq!(
        frames_in(&out.join("states.csv")),
        (0..150).collect::<Vec<_>>()
    );
    // A lock left by a run that died (the file, no lock held) is taken over.
    std::fs::write(out.join(".streampf.lock"), "4194303\n").unwrap();
    ok(&streampf(&strs(&small_face_run("3", &out))));
    assert_eq!(distinct_frames(&out.join("states.csv")), 3);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn two_body_runs_into_one_out_are_not_mixed() {
    let dir = scratch("busy-body-out");
    let out = dir.join("out");
    let args = |frames: &'static str| {
        let mut a: Vec<&str> = vec!["body", "track", "--synthetic", "--backend", "cpu"];
        a.extend(["--particles", "100", "--width", "160", "--height", "120"]);
        a.extend([
            "--quiet",
            "--frames",
            frames,
            "--out",
            out.to_str().unwrap(),
        ]);
        a
    };
    let mut first = command(&args("60"))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    wait_for_rows(&mut first, &out.join("poses.csv"), 2);
    let err = failure(&streampf(&args("5")));
    assert!(err.contains(&format!("pid {}", first.id())), "{err}");
    assert!(first.wait().unwrap().success());
    assert_eq!(
        frames_in(&out.join("poses.csv")),
        (0..60).collect::<Vec<_>>()
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

// 3b and 4. A refused resume changes nothing.

#[test]
fn a_refused_resume_leaves_every_byte_as_it_was() {
    let dir = scratch("refused-resume");
    let done = dir.join("done");
    ok(&streampf(&strs(&small_face_run("30", &done))));
    // The first 12 frames of a finished run (one face: a row a frame), as an interrupted run
    // leaves them.
    let part = dir.join("part");
    std::fs::create_dir_all(&part).unwrap();
    let files = ["states.csv", "errors.csv"];
    let finished: Vec<String> = files
        .iter()
        .map(|f| std::fs::read_to_string(done.join(f)).unwrap())
        .collect();
    let head: Vec<String> = finished
        .iter()
        .map(|text| text.lines().take(13).map(|l| format!("{l}\n")).collect())
        .collect();
    for (f, text) in files.iter().zip(&head) {
        std::fs::write(part.join(f), text).unwrap();
    }
    let now = || -> Vec<String> {
        files
            .iter()
            .map(|f| std::fs::read_to_string(part.join(f)).unwrap())
            .collect()
    };
    for other in [
        &["--seed", "2"][..],
        &["--particles", "500"],
        &["--video-seed", "12"],
    ] {
        let mut args = small_face_run("30", &part);
        args.push("--resume".into());
        args.extend(other.iter().map(|s| s.to_string()));
        for _ in 0..2 {
            let err = failure(&streampf(&strs(&args)));
            assert!(err.contains("--resume refused"), "{err}");
            assert!(err.contains("nothing was changed"), "{err}");
            assert!(!err.contains("frames before it were written"), "{err}");
            assert_eq!(now(), head, "{other:?}");
        }
    }
    // The same settings resume it to the finished run's rows.
    let mut args = small_face_run("30", &part);
    args.push("--resume".into());
    ok(&streampf(&strs(&args)));
    assert_eq!(now(), finished);
    // 4: a --max-frames that ends before the resume point is refused, the file untouched.
    let mut args = small_face_run("30", &part);
    args.extend(["--resume", "--max-frames", "10"].map(String::from));
    let err = failure(&streampf(&strs(&args)));
    assert!(err.contains("--max-frames 10"), "{err}");
    assert_one_line_error(&err);
    assert_eq!(now(), finished);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_refused_body_resume_leaves_every_byte_as_it_was() {
    let dir = scratch("refused-body-resume");
    let out = dir.join("out");
    let args = |particles: &str, extra: &[&str]| {
        let mut a: Vec<String> = ["body", "track", "--synthetic", "--backend", "cpu"]
            .map(String::from)
            .to_vec();
        a.extend(
            [
                "--particles",
                particles,
                "--width",
                "160",
                "--height",
                "120",
                "--quiet",
            ]
            .map(String::from),
        );
        a.extend(["--frames", "12", "--out", out.to_str().unwrap()].map(String::from));
        a.extend(extra.iter().map(|s| s.to_string()));
        a
    };
    ok(&streampf(&strs(&args("100", &[]))));
    let before: Vec<String> = ["poses.csv", "joints.csv", "errors.csv"]
        .iter()
        .map(|f| std::fs::read_to_string(out.join(f)).unwrap())
        .collect();
    for _ in 0..2 {
        let err = failure(&streampf(&strs(&args("300", &["--resume"]))));
        assert!(err.contains("--resume refused"), "{err}");
    }
    let after: Vec<String> = ["poses.csv", "joints.csv", "errors.csv"]
        .iter()
        .map(|f| std::fs::read_to_string(out.join(f)).unwrap())
        .collect();
    assert_eq!(before, after);
    std::fs::remove_dir_all(&dir).unwrap();
}

// 5. An early SIGTERM.

#[test]
fn a_sigterm_while_the_run_starts_is_an_interrupt_that_keeps_its_files() {
    let dir = scratch("early-sigterm");
    let out = dir.join("out");
    // The paper-sized synthetic video: seconds of set-up (rendering, templates) before frame 0.
    let mut child = command(&[
        "face",
        "track",
        "--synthetic",
        "--frames",
        "50",
        "--backend",
        "cpu",
        "--out",
        out.to_str().unwrap(),
    ])
    .stdout(Stdio::piped())
    .stderr(Stdio::piped())
    .spawn()
    .unwrap();
    // Long enough for the process to start and parse its command line, far less than its set-up.
    std::thread::sleep(Duration::from_millis(150));
    assert!(child.try_wait().unwrap().is_none(), "the run ended early");
    let sent = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(sent.success());
    let run = child.wait_with_output().unwrap();
    let err = stderr_of(&run);
    assert_eq!(run.status.code(), Some(INTERRUPTED_EXIT), "{err}");
    let written = distinct_frames(&out.join("states.csv"));
    assert!(
        err.contains(&format!("interrupted after {written} frames")),
        "{written} frames in the file: {err}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

// 7 and 9. Options out of range, and settings of the wrong type.

#[test]
fn out_of_range_options_are_refused_before_the_run() {
    let dir = scratch("ranges");
    let out = dir.join("out");
    for bad in ["nan", "-1", "0", "inf", "1e30"] {
        let mut args = small_face_run("3", &out);
        args.push(format!("--failure-error={bad}"));
        let err = failure(&streampf(&strs(&args)));
        assert!(err.contains("--failure-error"), "{bad}: {err}");
    }
    assert!(!out.join("states.csv").exists());
    for bad in ["1e19", "0", "-0.1", "nan"] {
        let tau = format!("--tau={bad}");
        let err = failure(&streampf(&[
            "body",
            "track",
            "--synthetic",
            &tau,
            "--out",
            out.to_str().unwrap(),
        ]));
        assert!(
            err.contains("--tau") && err.contains("metres"),
            "{bad}: {err}"
        );
    }
    // Settings of the wrong TOML type.
    for (setting, says) in [
        ("out = 5", "`out` takes text in quotes, not 5"),
        ("particles = \"200\"", "`particles` takes a whole number"),
        ("tau = \"0.1\"", "`tau` takes a number"),
    ] {
        let file = dir.join("settings.toml");
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(&file, format!("[body]\n{setting}\n")).unwrap();
        let err = failure(&streampf(&[
            "body",
            "track",
            "--synthetic",
            "--config",
            file.to_str().unwrap(),
        ]));
        assert!(err.contains(says), "{setting}: {err}");
        assert_one_line_error(&err);
    }
    assert!(!Path::new("5").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

// 8, 10 and 11. Directories of frames.

fn synth(dir: &Path, frames: &str, extra: &[&str]) -> Output {
    let mut args = vec!["face", "synth", "--out", dir.to_str().unwrap()];
    args.extend(["--faces", "1", "--width", "160", "--height", "120"]);
    args.extend(["--frames", frames]);
    args.extend(extra);
    streampf(&args)
}

#[test]
fn a_header_less_faces_csv_is_read_as_rectangles() {
    let dir = scratch("faces-csv");
    let frames = dir.join("frames");
    ok(&synth(&frames, "3", &[]));
    let out = dir.join("out");
    let track = || {
        failure(&streampf(&[
            "face",
            "track",
            frames.to_str().unwrap(),
            "--backend",
            "cpu",
            "--out",
            out.to_str().unwrap(),
        ]))
    };
    // A fifth value on the rectangle's line: the same error with or without a header.
    std::fs::write(frames.join("faces.csv"), "61.25,96.5625,37.5,46.875,0.9\n").unwrap();
    let without = track();
    std::fs::write(
        frames.join("faces.csv"),
        "x,y,width,height\n61.25,96.5625,37.5,46.875,0.9\n",
    )
    .unwrap();
    let with = track();
    for err in [&without, &with] {
        assert!(err.contains("has 5 values, not x,y,width,height"), "{err}");
        assert_one_line_error(err);
    }
    // A NaN says NaN.
    std::fs::write(frames.join("faces.csv"), "nan,20,40,40\n").unwrap();
    let err = track();
    assert!(err.contains("x NaN") && !err.contains("8x8"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn overlays_and_synthetic_videos_never_land_among_a_users_frames() {
    let dir = scratch("overlay-input");
    let frames = dir.join("frames");
    ok(&synth(&frames, "3", &[]));
    let before = std::fs::read_dir(&frames).unwrap().count();
    let err = failure(&streampf(&[
        "face",
        "track",
        frames.to_str().unwrap(),
        "--backend",
        "cpu",
        "--overlay",
        frames.to_str().unwrap(),
        "--out",
        dir.join("out").to_str().unwrap(),
    ]));
    assert!(err.contains("input directory"), "{err}");
    assert_eq!(std::fs::read_dir(&frames).unwrap().count(), before);
    // A synthetic video into a directory of the user's own frames is refused unless --force.
    let mine = dir.join("mine");
    std::fs::create_dir_all(&mine).unwrap();
    std::fs::write(mine.join("frame_00000.png"), b"the user's own").unwrap();
    std::fs::write(mine.join("holiday.png"), b"another").unwrap();
    let err = failure(&synth(&mine, "2", &[]));
    assert!(err.contains("--force"), "{err}");
    assert_one_line_error(&err);
    assert_eq!(
        std::fs::read(mine.join("frame_00000.png")).unwrap(),
        b"the user's own"
    );
    ok(&synth(&mine, "2", &["--force"]));
    // A directory an earlier synth wrote is its to rewrite.
    ok(&synth(&frames, "2", &[]));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_frame_of_another_size_is_skipped_unless_strict() {
    let dir = scratch("odd-size");
    let frames = dir.join("frames");
    ok(&synth(&frames, "5", &[]));
    // Frame 2 replaced by a frame of twice the size.
    let larger = dir.join("larger");
    let mut args = vec!["face", "synth", "--out", larger.to_str().unwrap()];
    args.extend([
        "--faces", "1", "--width", "320", "--height", "240", "--frames", "1",
    ]);
    ok(&streampf(&args));
    std::fs::copy(
        larger.join("frame_00000.png"),
        frames.join("frame_00002.png"),
    )
    .unwrap();
    let out = dir.join("out");
    let track = |extra: &[&str]| {
        let mut args = vec![
            "face",
            "track",
            frames.to_str().unwrap(),
            "--backend",
            "cpu",
        ];
        args.extend(["--out", out.to_str().unwrap()]);
        args.extend(extra);
        streampf(&args)
    };
    let run = track(&[]);
    let text = ok(&run);
    assert!(
        stderr_of(&run).contains("320x240, not the first frame's 160x120"),
        "{}",
        stderr_of(&run)
    );
    assert!(text.contains("1 unreadable frame skipped (2;"), "{text}");
    assert_eq!(distinct_frames(&out.join("states.csv")), 5);
    let err = failure(&track(&["--strict"]));
    assert!(
        err.contains("frame_00002.png") && err.contains("--strict"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

// 12 and 13. Messages.

#[test]
fn user_errors_are_one_line_even_with_backtraces_asked_for() {
    let dir = scratch("messages");
    let out = dir.join("out");
    let run = |args: &[&str]| command(args).env("RUST_BACKTRACE", "1").output().unwrap();
    let err = failure(&run(&[
        "face",
        "track",
        "/dev/null",
        "--out",
        out.to_str().unwrap(),
    ]));
    assert!(err.contains("/dev/null: not a video file"), "{err}");
    assert_one_line_error(&err);
    // --out on an existing file.
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("a-file");
    std::fs::write(&file, "mine").unwrap();
    let mut args = small_face_run("2", &file);
    args.push("--quiet".into());
    let err = failure(&run(&strs(&args)));
    assert!(
        err.contains(&format!("--out {}: a file is there", file.display())),
        "{err}"
    );
    assert_one_line_error(&err);
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "mine");
    // A NaN --face.
    let mut args = small_face_run("2", &out);
    args.extend(["--face", "nan,10,40,40"].map(String::from));
    let err = failure(&run(&strs(&args)));
    assert!(err.contains("x NaN"), "{err}");
    assert_one_line_error(&err);
    // A bad value in a settings file: clap's message once, no "Error: error:".
    let settings = dir.join("bad.toml");
    std::fs::write(&settings, "[face]\nparticles = 0\n").unwrap();
    let err = failure(&run(&[
        "face",
        "track",
        "--synthetic",
        "--config",
        settings.to_str().unwrap(),
    ]));
    assert!(err.starts_with("Error: invalid value"), "{err}");
    assert!(
        !err.contains("Error: error:") && !err.contains("stack backtrace"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_run_stopped_by_a_bad_frame_says_what_it_wrote_and_no_more() {
    let dir = scratch("stopped-counts");
    let frames = dir.join("frames");
    ok(&synth(&frames, "6", &[]));
    std::fs::write(frames.join("frame_00004.png"), b"not a png").unwrap();
    let out = dir.join("out");
    let run = streampf(&[
        "face",
        "track",
        frames.to_str().unwrap(),
        "--backend",
        "cpu",
        "--strict",
        "--out",
        out.to_str().unwrap(),
    ]);
    let err = failure(&run);
    let text = String::from_utf8_lossy(&run.stdout);
    assert!(!text.contains("wrote states.csv"), "{text}");
    let written = distinct_frames(&out.join("states.csv"));
    assert_eq!(written, 4);
    assert!(
        err.contains(&format!("the {written} frames before it were written")),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// docs/RELIABILITY.md's table names the test that keeps each row true: each must exist.
#[test]
fn every_test_the_reliability_table_names_exists() {
    let crate_dir = Path::new(env!("CARGO_MANIFEST_DIR"));
    let doc = std::fs::read_to_string(crate_dir.join("../../docs/RELIABILITY.md")).unwrap();
    let source = |file: &str| {
        let path = match file {
            "video" => crate_dir.join("src/video/mod.rs"),
            "run_output" => crate_dir.join("src/run_output.rs"),
            test => crate_dir.join(format!("tests/{test}.rs")),
        };
        std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
    };
    let mut named = 0;
    for row in doc
        .lines()
        .filter(|l| l.starts_with("| ") && !l.starts_with("| class"))
    {
        let last = row
            .trim_end_matches('|')
            .rsplit('|')
            .next()
            .unwrap_or_default();
        let mut file = String::new();
        for token in last.split('`').skip(1).step_by(2) {
            if token.contains('/') || token.contains('.') {
                continue; // a path (the Python tests), not a Rust test
            }
            let name = match token.split_once("::") {
                Some((f, rest)) => {
                    file = f.to_string();
                    rest.rsplit("::").next().unwrap_or(rest)
                }
                None => token,
            };
            assert!(!file.is_empty(), "{row}: {token} names no file");
            assert!(
                source(&file).contains(&format!("fn {name}(")),
                "docs/RELIABILITY.md names {file}::{name}, which does not exist"
            );
            named += 1;
        }
    }
    assert!(
        named >= 15,
        "only {named} tests named: is the table still read right?"
    );
}
