//! The `streampf` binary as a user runs it.

mod common;

use std::process::Command;

use common::{number_after, streampf};

#[test]
fn demo_tracks_better_than_the_raw_observations() {
    let out = streampf(&["demo", "--steps", "150", "--particles", "800", "--quiet"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    let filtered = number_after(&text, "mean translation error");
    let raw = number_after(&text, "raw observations were off by");
    assert!(
        filtered < 0.8 * raw,
        "filter {filtered} px vs raw {raw} px\n{text}"
    );
}

#[test]
fn demo_prints_one_line_per_step_and_is_reproducible() {
    let args = [
        "demo",
        "--steps",
        "12",
        "--particles",
        "300",
        "--resampler",
        "rejection",
        "--ess-threshold",
        "0.5",
    ];
    let a = streampf(&args);
    assert!(a.status.success(), "{}", String::from_utf8_lossy(&a.stderr));
    let text = String::from_utf8_lossy(&a.stdout);
    // A step line is six columns whose first is the step number.
    let step_lines = text
        .lines()
        .filter(|l| {
            let cols: Vec<_> = l.split_whitespace().collect();
            cols.len() == 6 && cols[0].parse::<u32>().is_ok()
        })
        .count();
    assert_eq!(step_lines, 12, "{text}");
    // Everything but the timing line is a function of the seed.
    let strip = |o: &std::process::Output| {
        String::from_utf8_lossy(&o.stdout)
            .lines()
            .filter(|l| !l.contains("ms per step"))
            .collect::<Vec<_>>()
            .join("\n")
    };
    assert_eq!(strip(&a), strip(&streampf(&args)));
}

#[test]
fn bad_arguments_are_clear_errors() {
    for (args, expect) in [
        (vec!["demo", "--resampler", "bogus"], "unknown resampler"),
        (vec!["demo", "--particles", "0"], "--particles"),
        (vec!["demo", "--steps", "-3"], "'-3'"),
        (
            vec!["demo", "--ess-threshold", "1.5"],
            "--ess-threshold must be a fraction",
        ),
        (vec!["frobnicate"], "unrecognized subcommand"),
    ] {
        let out = streampf(&args);
        assert!(!out.status.success(), "{args:?} succeeded");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(expect), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{args:?}: {err}");
    }
}

#[test]
fn help_and_version_work() {
    let help = streampf(&["--help"]);
    assert!(help.status.success());
    let text = String::from_utf8_lossy(&help.stdout);
    assert!(text.contains("devices") && text.contains("demo"), "{text}");
    let version = streampf(&["--version"]);
    assert!(String::from_utf8_lossy(&version.stdout).contains(env!("CARGO_PKG_VERSION")));
}

#[test]
fn devices_with_an_unmatched_name_says_what_to_install() {
    let out = Command::new(env!("CARGO_BIN_EXE_streampf"))
        .arg("devices")
        .env("WGPU_ADAPTER_NAME", "no-such-adapter-anywhere")
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("mesa-vulkan-drivers") && err.contains("no-such-adapter-anywhere"),
        "{err}"
    );
}

/// Runs `args`, or returns `None` when there is no adapter and the run opted out of GPU tests
/// (`STREAMPF_ALLOW_NO_GPU=1`); without the opt-out a missing adapter fails the test.
fn streampf_gpu(args: &[&str]) -> Option<std::process::Output> {
    let out = streampf(args);
    let err = String::from_utf8_lossy(&out.stderr);
    if !out.status.success() && common::skipped_for_no_gpu(&err) {
        return None;
    }
    Some(out)
}

#[test]
fn demo_on_the_gpu_tracks_several_targets_as_well_as_the_cpu() {
    let common = [
        "demo",
        "--steps",
        "60",
        "--particles",
        "500",
        "--targets",
        "4",
        "--quiet",
    ];
    let Some(gpu) = streampf_gpu(&[&common[..], &["--gpu", "--allow-software"]].concat()) else {
        return;
    };
    assert!(
        gpu.status.success(),
        "{}",
        String::from_utf8_lossy(&gpu.stderr)
    );
    let gpu_text = String::from_utf8_lossy(&gpu.stdout);
    assert!(gpu_text.contains("on GPU:"), "{gpu_text}");
    assert!(gpu_text.contains("of it the GPU step"), "{gpu_text}");
    let cpu = streampf(&common);
    let cpu_text = String::from_utf8_lossy(&cpu.stdout);
    let (g, c) = (
        number_after(&gpu_text, "mean translation error"),
        number_after(&cpu_text, "mean translation error"),
    );
    let raw = number_after(&gpu_text, "raw observations were off by");
    assert!(g < 0.8 * raw, "GPU {g} px vs raw {raw} px\n{gpu_text}");
    // Two Monte Carlo runs of the same filter: within 30 % of each other.
    assert!((g - c).abs() <= 0.3 * c, "GPU {g} px vs CPU {c} px");
}

#[test]
fn gpu_demo_refuses_what_the_gpu_cannot_do() {
    let out = streampf(&[
        "demo",
        "--gpu",
        "--allow-software",
        "--resampler",
        "rejection",
    ]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("--resampler")
            && err.contains(
                "the GPU resamples with systematic, stratified, metropolis, not rejection"
            ),
        "{err}"
    );
    let out = streampf(&["demo", "--allow-software"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--gpu"));
}
