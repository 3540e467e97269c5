//! `streampf`: GPU particle filtering for visual tracking, from the command line.

mod body;
mod demo;
mod devices;
mod face;
mod face_io;
mod filter_args;
mod gpu;
mod run_output;
mod video;

use clap::{Parser, Subcommand};

#[derive(Debug, Parser)]
#[command(
    name = "streampf",
    version,
    about = "GPU particle filtering (Condensation) for visual tracking",
    long_about = "GPU particle filtering (Condensation) for visual tracking.\n\n\
                  `streampf face track VIDEO` finds and tracks the faces in a video; `streampf face track --synthetic` tracks four synthetic faces; \
                  `streampf body track --synthetic` tracks a synthetic walking body; \
                  `streampf demo` tracks synthetic 7-D pose targets; \
                  `streampf devices` lists the GPU adapters wgpu can use."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// List the GPU adapters (name, type, backend); honours WGPU_BACKEND and WGPU_ADAPTER_NAME.
    Devices,
    /// Track a synthetic target and print the per-step error and a summary.
    Demo(demo::DemoArgs),
    /// Multi-face tracking: `face track VIDEO|DIR`, `face track --synthetic`, `face synth`.
    Face {
        #[command(subcommand)]
        command: face::FaceCommand,
    },
    /// Stereo articulated body tracking: `body track DIR`, `body track --synthetic`, `body synth`.
    Body {
        #[command(subcommand)]
        command: body::BodyCommand,
    },
}

fn main() -> std::process::ExitCode {
    quiet_mesa_device_selection();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Devices => devices::run(),
        Command::Demo(args) => demo::run(&args),
        Command::Body { command } => body::run(&command),
        Command::Face { command } => face::run(&command),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            if let Some(interrupted) = e.downcast_ref::<run_output::Interrupted>() {
                eprintln!("{interrupted}");
                return std::process::ExitCode::from(run_output::INTERRUPTED_EXIT as u8);
            }
            eprintln!("Error: {e:?}");
            std::process::ExitCode::FAILURE
        }
    }
}

/// Mesa's Vulkan device-selection layer prints "XDG_RUNTIME_DIR is invalid or not set" on a
/// headless machine before any output of ours, and selects nothing wgpu does not choose itself:
/// keep it off unless the user set it.
fn quiet_mesa_device_selection() {
    if std::env::var_os("NODEVICE_SELECT").is_none() {
        // SAFETY: the first thing main does, before any thread exists that could read the
        // environment.
        unsafe { std::env::set_var("NODEVICE_SELECT", "1") };
    }
}
