//! The trackers' own kernels (the face weighing, the capsule likelihood, the skeleton's
//! kinematics, the engine's stages) are built without wgpu's runtime checks; with
//! `STREAMPF_CHECK_KERNELS=1` every kernel keeps them. The checks only change indices that were
//! out of range, so `face track` and `body track` on the GPU must write the same files, byte for
//! byte, either way, and the checked run must say that it checks.

mod common;

use common::{ok, scratch, skipped_for_no_gpu};
use std::process::{Command, Output};

/// `streampf args`, with every kernel checked or not.
fn streampf_checking(args: &[&str], check: bool) -> Output {
    let mut command = Command::new(env!("CARGO_BIN_EXE_streampf"));
    command.args(args).env("NODEVICE_SELECT", "1");
    match check {
        true => command.env(pf_gpu::CHECK_KERNELS_VAR, "1"),
        false => command.env_remove(pf_gpu::CHECK_KERNELS_VAR),
    };
    command.output().expect("the streampf binary runs")
}

/// Runs `args` (writing to `--out DIR`) trusted, then checked; `None` when skipped for want of
/// an adapter. Returns `file`'s bytes from each run.
fn both_ways(name: &str, args: &[&str], file: &str) -> Option<(Vec<u8>, Vec<u8>)> {
    let mut files = Vec::new();
    for check in [false, true] {
        let out = scratch(&format!("{name}-{check}"));
        let mut all = args.to_vec();
        all.extend(["--out", out.to_str().unwrap()]);
        let run = streampf_checking(&all, check);
        if skipped_for_no_gpu(&String::from_utf8_lossy(&run.stderr)) {
            return None;
        }
        ok(&run);
        let stderr = String::from_utf8_lossy(&run.stderr);
        let says = stderr.contains("every GPU kernel keeps wgpu's index and loop checks");
        assert_eq!(says, check, "{stderr}");
        files.push(std::fs::read(out.join(file)).unwrap());
        std::fs::remove_dir_all(&out).unwrap();
    }
    let checked = files.pop().unwrap();
    Some((files.pop().unwrap(), checked))
}

#[test]
fn face_tracks_are_the_same_with_every_kernel_checked() {
    let args = [
        "face",
        "track",
        "--synthetic",
        "--frames",
        "6",
        "--faces",
        "2",
        "--width",
        "320",
        "--height",
        "240",
        "--backend",
        "gpu",
        "--allow-software",
    ];
    if let Some((trusted, checked)) = both_ways("trusted-face", &args, "states.csv") {
        assert!(trusted.len() > 100, "an empty states.csv");
        assert!(trusted == checked, "states.csv differs trusted and checked");
    }
}

#[test]
fn body_tracks_are_the_same_with_every_kernel_checked() {
    let args = [
        "body",
        "track",
        "--synthetic",
        "--frames",
        "4",
        "--capsules",
        "19",
        "--width",
        "96",
        "--height",
        "72",
        "--particles",
        "200",
        "--backend",
        "gpu",
        "--allow-software",
    ];
    if let Some((trusted, checked)) = both_ways("trusted-body", &args, "poses.csv") {
        assert!(trusted.len() > 100, "an empty poses.csv");
        assert!(trusted == checked, "poses.csv differs trusted and checked");
    }
}
