//! Settings files: `streampf config --print-default` round-trips (a run with the printed file
//! is the run without it), a file's settings apply, the command line wins over them, and a bad
//! file is refused with its key named.

mod common;

use common::{failure, ok, scratch, streampf};
use std::path::Path;

/// A small synthetic face run on the CPU, with `extra` options; returns states.csv.
fn face_run(out: &Path, extra: &[&str]) -> String {
    let o = out.to_str().unwrap();
    let mut args = vec![
        "face",
        "track",
        "--synthetic",
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
        o,
    ];
    args.extend_from_slice(extra);
    ok(&streampf(&args));
    std::fs::read_to_string(out.join("states.csv")).expect("states.csv written")
}

fn frames_in(states: &str) -> usize {
    states.lines().count() - 1
}

fn write(path: &Path, text: &str) -> String {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    std::fs::write(path, text).unwrap();
    path.to_str().unwrap().to_string()
}

#[test]
fn the_printed_defaults_read_back_as_the_defaults() {
    let dir = scratch("settings-defaults");
    let printed = ok(&streampf(&["config", "--print-default"]));
    assert!(
        printed.contains("[face]") && printed.contains("[body]"),
        "{printed}"
    );
    assert!(printed.contains("\nparticles = 1000\n") && printed.contains("\nparticles = 1500\n"));
    let file = write(&dir.join("defaults.toml"), &printed);

    let plain = face_run(&dir.join("plain"), &["--frames", "3", "--seed", "4"]);
    let with_file = face_run(
        &dir.join("with-file"),
        &["--frames", "3", "--seed", "4", "--config", &file],
    );
    assert_eq!(frames_in(&plain), 3);
    assert_eq!(
        plain, with_file,
        "a run with the default settings file differs"
    );

    // The body's table is read as well: a run with it is the run without it.
    let body = |out: &Path, extra: &[&str]| {
        let o = out.to_str().unwrap();
        let mut args = vec![
            "body",
            "track",
            "--synthetic",
            "--frames",
            "2",
            "--capsules",
            "19",
            "--width",
            "96",
            "--height",
            "72",
            "--particles",
            "40",
            "--layers",
            "1",
            "--backend",
            "cpu",
            "--quiet",
            "--out",
            o,
        ];
        args.extend_from_slice(extra);
        ok(&streampf(&args));
        std::fs::read_to_string(out.join("poses.csv")).unwrap()
    };
    assert_eq!(
        body(&dir.join("body-plain"), &[]),
        body(&dir.join("body-file"), &["--config", &file])
    );
}

#[test]
fn a_file_sets_what_the_command_line_does_not() {
    let dir = scratch("settings-apply");
    let file = write(
        &dir.join("s.toml"),
        "[face]\nframes = 4\nparticles = 64\nseed = 9\nmax-yaw = 30.0\n\n[body]\nparticles = 10\n",
    );
    let from_file = face_run(&dir.join("a"), &["--config", &file]);
    assert_eq!(frames_in(&from_file), 4);
    // The same settings as flags give the same rows.
    let as_flags = face_run(
        &dir.join("b"),
        &[
            "--frames",
            "4",
            "--particles",
            "64",
            "--seed",
            "9",
            "--max-yaw",
            "30",
        ],
    );
    assert_eq!(from_file, as_flags);
    // The command line wins.
    let overridden = face_run(&dir.join("c"), &["--config", &file, "--frames", "2"]);
    assert_eq!(frames_in(&overridden), 2);
    assert_eq!(
        overridden,
        from_file
            .lines()
            .take(3)
            .map(|l| format!("{l}\n"))
            .collect::<String>()
    );
}

#[test]
fn a_switch_in_the_file_turns_on_and_an_input_on_the_command_line_drops_synthetic() {
    let dir = scratch("settings-switch");
    // `synthetic = true` stands in for --synthetic.
    let file = write(
        &dir.join("s.toml"),
        "[face]\nsynthetic = true\nframes = 2\nfaces = 1\n",
    );
    let o = dir.join("out");
    ok(&streampf(&[
        "face",
        "track",
        "--config",
        &file,
        "--width",
        "320",
        "--height",
        "240",
        "--backend",
        "cpu",
        "--quiet",
        "--out",
        o.to_str().unwrap(),
    ]));
    assert_eq!(
        frames_in(&std::fs::read_to_string(o.join("states.csv")).unwrap()),
        2
    );
    // A directory named on the command line conflicts with the file's synthetic: the command
    // line wins, and the error is about the directory, not the conflict.
    let missing = dir.join("no-such-frames");
    let err = failure(&streampf(&[
        "face",
        "track",
        missing.to_str().unwrap(),
        "--config",
        &file,
        "--backend",
        "cpu",
        "--quiet",
        "--out",
        o.to_str().unwrap(),
    ]));
    assert!(err.contains("no-such-frames"), "{err}");
    assert!(!err.contains("cannot be used with"), "{err}");
}

#[test]
fn bad_files_are_refused_with_the_key_named_and_nothing_written() {
    let dir = scratch("settings-bad");
    let out = dir.join("out");
    let o = out.to_str().unwrap();
    let run = |file: &str| {
        failure(&streampf(&[
            "face",
            "track",
            "--synthetic",
            "--config",
            file,
            "--backend",
            "cpu",
            "--quiet",
            "--out",
            o,
        ]))
    };
    let err = run(&write(&dir.join("typo.toml"), "[face]\nparticls = 100\n"));
    assert!(err.contains("unknown setting `particls`"), "{err}");
    // A typo in the other tracker's table is reported too.
    let err = run(&write(
        &dir.join("body-typo.toml"),
        "[face]\n[body]\nsamples = 3\n",
    ));
    assert!(err.contains("`samples`") && err.contains("[body]"), "{err}");
    let err = run(&write(&dir.join("table.toml"), "[fase]\nparticles = 100\n"));
    assert!(err.contains("unknown table [fase]"), "{err}");
    let err = run(&write(
        &dir.join("value.toml"),
        "[face]\nparticles = \"many\"\n",
    ));
    // A string where the option takes a number: the file's type mistake, named.
    assert!(
        err.contains("`particles` takes a whole number, not \"many\""),
        "{err}"
    );
    let err = run(&write(&dir.join("range.toml"), "[face]\nparticles = 0\n"));
    assert!(err.contains("--particles"), "{err}");
    // `scene-cut` takes a number or `off`; not a switch's value, nor a number out of range.
    let err = run(&write(&dir.join("cut.toml"), "[face]\nscene-cut = true\n"));
    assert!(
        err.contains("`scene-cut` takes a number or text in quotes"),
        "{err}"
    );
    let err = run(&write(
        &dir.join("cut-range.toml"),
        "[face]\nscene-cut = 3.5\n",
    ));
    assert!(err.contains("below 2"), "{err}");
    let err = run(&write(&dir.join("switch.toml"), "[face]\ndetect = 1\n"));
    assert!(err.contains("`detect` is a switch"), "{err}");
    let err = run(&write(&dir.join("syntax.toml"), "[face\nparticles = 100\n"));
    assert!(err.contains("not valid TOML"), "{err}");
    let err = run(&write(
        &dir.join("no-face.toml"),
        "[body]\nparticles = 100\n",
    ));
    assert!(err.contains("no [face] table"), "{err}");
    let err = run(dir.join("absent.toml").to_str().unwrap());
    assert!(err.contains("cannot read the settings file"), "{err}");
    assert!(!out.exists(), "a refused run wrote {}", out.display());
}
