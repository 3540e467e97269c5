//! Helpers of the command-line tests: run the binary, check its outcome, scratch directories.

#![allow(dead_code)]

use std::path::PathBuf;
use std::process::{Command, Output};

/// Runs `streampf` with `args` (Mesa's device-select layer quiet on headless machines).
pub fn streampf(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_streampf"))
        .args(args)
        .env("NODEVICE_SELECT", "1")
        .output()
        .expect("the streampf binary runs")
}

pub fn ok(out: &Output) -> String {
    assert!(
        out.status.success(),
        "{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

pub fn failure(out: &Output) -> String {
    assert!(
        !out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stdout)
    );
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(!err.contains("panicked"), "{err}");
    err
}

pub fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!(
        "streampf-{}-{name}-{}",
        env!("CARGO_CRATE_NAME"),
        std::process::id()
    ));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// Whether the tests on real media are skipped by request (STREAMPF_NO_MEDIA=1), said on stderr
/// for `test`.
pub fn opted_out(test: &str) -> bool {
    let out = std::env::var_os("STREAMPF_NO_MEDIA").is_some_and(|v| v == "1");
    if out {
        eprintln!("{test}: skipped by request (STREAMPF_NO_MEDIA=1)");
    }
    out
}

/// Runs FFmpeg with `args` (quiet, overwriting); fails the test with its message, or with
/// `help` (how to install it) when it cannot run.
pub fn ffmpeg(args: &[&str], help: &str) {
    let out = Command::new("ffmpeg")
        .args(["-nostdin", "-v", "error", "-y"])
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("ffmpeg: {e}; {help}"));
    assert!(
        out.status.success(),
        "ffmpeg {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Whether a run's error `stderr` says it found no GPU adapter: allowed (said on stderr) only
/// when the run opted out with STREAMPF_ALLOW_NO_GPU=1; without it the test fails, saying how to
/// get one. A GPU test never passes silently for lack of an adapter.
pub fn skipped_for_no_gpu(stderr: &str) -> bool {
    if !stderr.contains("no GPU adapter was found") {
        return false;
    }
    assert!(
        std::env::var("STREAMPF_ALLOW_NO_GPU").is_ok_and(|v| v == "1"),
        "this test needs a GPU adapter (or Mesa's lavapipe: apt-get install mesa-vulkan-drivers); \
         set STREAMPF_ALLOW_NO_GPU=1 to skip it explicitly.\n{stderr}"
    );
    eprintln!("SKIPPED: no GPU adapter and STREAMPF_ALLOW_NO_GPU=1");
    true
}

/// The number after `label` in `text`.
pub fn number_after(text: &str, label: &str) -> f64 {
    let start = text
        .find(label)
        .unwrap_or_else(|| panic!("{label:?} not in {text}"))
        + label.len();
    text[start..]
        .split_whitespace()
        .next()
        .and_then(|w| w.parse().ok())
        .unwrap_or_else(|| panic!("no number after {label:?} in {text}"))
}
