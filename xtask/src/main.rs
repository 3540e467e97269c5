//! Project automation: `cargo xtask <command>`.
//!
//! - `test`: makes sure the GPU tests have an adapter (installs Mesa's software Vulkan driver,
//!   lavapipe, through apt-get when running as root on Debian/Ubuntu; otherwise prints the exact
//!   command and stops), then runs every test of the workspace.

use std::path::Path;
use std::process::{Command, ExitCode};

use anyhow::{Context, bail};

const USAGE: &str = "usage: cargo xtask <command>

commands:
  test [--no-gpu] [-- <cargo test args>]
      install what the tests need (Mesa's lavapipe Vulkan driver) when it is missing, then run
      every test of the workspace. --no-gpu skips the install and lets the GPU tests skip
      explicitly (STREAMPF_ALLOW_NO_GPU=1) on a machine with no adapter.";

/// The Debian packages that give wgpu a software Vulkan adapter.
const GPU_PACKAGES: [&str; 2] = ["mesa-vulkan-drivers", "libvulkan1"];

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let result = match args.first().map(String::as_str) {
        Some("test") => test(&args[1..]),
        Some("-h" | "--help" | "help") => {
            println!("{USAGE}");
            Ok(())
        }
        Some(other) => Err(anyhow::anyhow!("unknown command {other:?}\n\n{USAGE}")),
        None => Err(anyhow::anyhow!("no command given\n\n{USAGE}")),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("xtask: {err:#}");
            ExitCode::FAILURE
        }
    }
}

fn test(args: &[String]) -> anyhow::Result<()> {
    let (ours, passthrough) = match args.iter().position(|a| a == "--") {
        Some(i) => (&args[..i], &args[i + 1..]),
        None => (args, &[][..]),
    };
    let mut no_gpu = false;
    for a in ours {
        match a.as_str() {
            "--no-gpu" => no_gpu = true,
            other => bail!("unknown option {other:?} for `test`\n\n{USAGE}"),
        }
    }
    if !no_gpu {
        ensure_software_vulkan()?;
    }
    let mut cargo = Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()));
    cargo
        .current_dir(workspace_root())
        .args(["test", "--workspace", "--all-targets"])
        .args(passthrough);
    if no_gpu {
        cargo.env("STREAMPF_ALLOW_NO_GPU", "1");
    }
    // Mesa's device-select Vulkan layer looks for a Wayland display and prints an error on
    // headless machines; the tests need no display, so switch the layer off.
    cargo.env("NODEVICE_SELECT", "1");
    run(&mut cargo, "cargo test")?;
    // Doc tests are not part of --all-targets.
    let mut doc = Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()));
    doc.current_dir(workspace_root())
        .args(["test", "--workspace", "--doc"]);
    run(&mut doc, "cargo test --doc")
}

fn workspace_root() -> &'static Path {
    // xtask/ sits at the root of the workspace.
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .unwrap_or(Path::new("."))
}

fn run(cmd: &mut Command, what: &str) -> anyhow::Result<()> {
    let status = cmd.status().with_context(|| format!("starting {what}"))?;
    if !status.success() {
        bail!("{what} failed ({status})");
    }
    Ok(())
}

/// Installs lavapipe when this is a Debian-like system that lacks it. Elsewhere (a machine with a
/// real GPU driver, another distribution) it leaves the system alone: the GPU tests themselves
/// fail with instructions if no adapter turns up.
fn ensure_software_vulkan() -> anyhow::Result<()> {
    if !is_debian_like() {
        eprintln!(
            "xtask: not a Debian/Ubuntu system; make sure a Vulkan driver is installed (Mesa's lavapipe works)"
        );
        return Ok(());
    }
    let missing: Vec<&str> = GPU_PACKAGES
        .into_iter()
        .filter(|p| !package_installed(p))
        .collect();
    if missing.is_empty() {
        return Ok(());
    }
    let install = format!(
        "apt-get install -y --no-install-recommends {}",
        missing.join(" ")
    );
    if !is_root() {
        bail!(
            "the GPU tests need {} (Mesa's software Vulkan driver). Install it with:\n\n    sudo apt-get update && sudo {install}\n\nthen run `cargo xtask test` again (or `cargo xtask test --no-gpu` to skip the GPU tests explicitly)",
            missing.join(" ")
        );
    }
    eprintln!("xtask: installing {}", missing.join(" "));
    run(Command::new("apt-get").arg("update"), "apt-get update")?;
    run(
        Command::new("apt-get")
            .args(["install", "-y", "--no-install-recommends"])
            .args(&missing)
            .env("DEBIAN_FRONTEND", "noninteractive"),
        "apt-get install",
    )
}

fn is_debian_like() -> bool {
    Path::new("/etc/debian_version").exists() && which("dpkg-query") && which("apt-get")
}

fn which(program: &str) -> bool {
    std::env::var_os("PATH")
        .is_some_and(|path| std::env::split_paths(&path).any(|dir| dir.join(program).is_file()))
}

fn package_installed(package: &str) -> bool {
    Command::new("dpkg-query")
        .args(["-W", "-f=${Status}", package])
        .output()
        .is_ok_and(|o| {
            o.status.success()
                && String::from_utf8_lossy(&o.stdout).contains("install ok installed")
        })
}

fn is_root() -> bool {
    Command::new("id")
        .arg("-u")
        .output()
        .is_ok_and(|o| String::from_utf8_lossy(&o.stdout).trim() == "0")
}
