//! `streampf`: GPU particle filtering for visual tracking, from the command line. The binary
//! (`main.rs`) calls [`cli_main`]; [`run_embedded`] runs the same commands inside another
//! program (the Python package's `track_video`), without touching its signal handlers.

#[macro_use]
mod console;
mod annotated;
mod body;
mod demo;
mod devices;
mod face;
mod face_io;
mod face_overlay;
mod filter_args;
mod gpu;
mod recording;
mod run_output;
mod settings;
pub mod smoothing;
mod video;

use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};

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
    /// Settings files (`face track --config FILE`, `body track --config FILE`).
    Config(ConfigArgs),
}

#[derive(Debug, clap::Args)]
struct ConfigArgs {
    /// Print a settings file with every setting of `face track` and `body track` at its
    /// default.
    #[arg(long, required = true)]
    print_default: bool,
}

/// The `streampf` binary: parses the process's command line, runs the command, and turns the
/// result into the exit status (130 for an interrupted run).
///
/// An error is one line on stderr (`Error: what: why`), never a stack trace: errors that reach
/// here are the user's input or the machine's state, and a bug panics instead.
pub fn cli_main() -> std::process::ExitCode {
    quiet_mesa_device_selection();
    let cli = match parse_command_line() {
        Ok(cli) => cli,
        Err(e) => {
            report_error(&e);
            return std::process::ExitCode::FAILURE;
        }
    };
    // A track run keeps what it wrote when stopped: the handler goes in before the models load
    // and the video opens (seconds on a cold start), so that an early SIGTERM is a stop too.
    if cli.command.writes_results()
        && let Err(e) = run_output::install_interrupt_handler()
    {
        report_error(&e);
        return std::process::ExitCode::FAILURE;
    }
    let status = match run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            if let Some(interrupted) = e.downcast_ref::<run_output::Interrupted>() {
                errln!("{interrupted}");
                return std::process::ExitCode::from(run_output::INTERRUPTED_EXIT as u8);
            }
            report_error(&e);
            std::process::ExitCode::FAILURE
        }
    };
    // A closed stdout ends quietly; a failing one (a full disk) is an error of its own, reported
    // after the run has closed its files.
    match console::stdout_failure() {
        Some(e) => {
            errln!("Error: writing to standard output: {e}");
            std::process::ExitCode::FAILURE
        }
        None => status,
    }
}

/// Prints `e` and its causes on one line.
fn report_error(e: &anyhow::Error) {
    errln!("Error: {}", one_line_message(e));
}

/// `e` and its causes joined by ": " (anyhow's `{:#}`, which never prints a backtrace), without
/// clap's own "error: " prefix where a clap message is inside.
fn one_line_message(e: &anyhow::Error) -> String {
    let text = format!("{e:#}");
    text.strip_prefix("error: ").unwrap_or(&text).to_string()
}

impl Command {
    /// Whether the command writes result files that an interrupt must not lose.
    fn writes_results(&self) -> bool {
        match self {
            Command::Face { command } => matches!(command, face::FaceCommand::Track(_)),
            Command::Body { command } => matches!(command, body::BodyCommand::Track(_)),
            Command::Devices | Command::Demo(_) | Command::Config(_) => false,
        }
    }
}

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Config(_) => {
            out!("{}", settings::default_settings(&Cli::command()));
            Ok(())
        }
        Command::Devices => devices::run(),
        Command::Demo(args) => demo::run(&args),
        Command::Body { command } => body::run(&command),
        Command::Face { command } => face::run(&command),
    }
}

pub use run_output::Interrupted;

/// A command line that [`run_embedded`] refused (clap's message, with usage).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct UsageError(pub String);

/// Runs `streampf ARGS…` in this process (`args` without the program's name), for a program that
/// embeds streampf: a bad command line is an error (clap's message) instead of an exit, and no
/// Ctrl-C handler is installed — the embedding program calls [`request_stop`] instead, and the
/// run then ends after its current frame with an [`Interrupted`] error, every finished frame
/// written. Progress and summaries go to stderr and stdout as the binary's do.
pub fn run_embedded<I, S>(args: I) -> anyhow::Result<()>
where
    I: IntoIterator<Item = S>,
    S: Into<std::ffi::OsString>,
{
    run_output::start_embedded_run();
    let argv: Vec<std::ffi::OsString> = std::iter::once("streampf".into())
        .chain(args.into_iter().map(Into::into))
        .collect();
    let command = Cli::command();
    let settings::WithSettings { argv, file } = settings::with_config_file(&command, argv)?;
    let matches = command.try_get_matches_from(argv).map_err(|e| {
        let message = clap_message(&e);
        UsageError(match file {
            Some(file) => format!(
                "{}\n(the options above include the settings of {})",
                message,
                file.display()
            ),
            None => message,
        })
    })?;
    run(Cli::from_arg_matches(&matches)?)
}

/// Parses `streampf ARGS…` (`args` without the program's name) as the binary would, without
/// running anything: clap's message for a bad command line. Asking for help or the version
/// parses. The commands the documentation shows are checked with it (`tests/doc_commands.rs`).
pub fn check_command_line<I, S>(args: I) -> Result<(), UsageError>
where
    I: IntoIterator<Item = S>,
    S: Into<std::ffi::OsString>,
{
    let argv = std::iter::once("streampf".into()).chain(args.into_iter().map(Into::into));
    match Cli::command().try_get_matches_from(argv.collect::<Vec<std::ffi::OsString>>()) {
        Ok(_) => Ok(()),
        Err(e)
            if matches!(
                e.kind(),
                clap::error::ErrorKind::DisplayHelp | clap::error::ErrorKind::DisplayVersion
            ) =>
        {
            Ok(())
        }
        Err(e) => Err(UsageError(clap_message(&e))),
    }
}

/// Asks a run started by [`run_embedded`] to stop after its current frame.
pub fn request_stop() {
    run_output::request_stop();
}

/// The command line, with the settings of a `--config FILE` added where the command line does
/// not give them. A mistake on the command line itself exits as clap does (usage, code 2).
fn parse_command_line() -> anyhow::Result<Cli> {
    let argv: Vec<std::ffi::OsString> = std::env::args_os().collect();
    let command = Cli::command();
    let settings::WithSettings { argv, file } = settings::with_config_file(&command, argv)?;
    let matches = match (command.try_get_matches_from(argv), file) {
        (Ok(matches), _) => matches,
        // A bad value in the file: clap's message names the option, this names the file.
        (Err(e), Some(file)) if e.use_stderr() => anyhow::bail!(
            "{}\n(the options above include the settings of {})",
            clap_message(&e),
            file.display()
        ),
        (Err(e), _) => e.exit(),
    };
    Ok(Cli::from_arg_matches(&matches).unwrap_or_else(|e| e.exit()))
}

/// clap's message for `e` without its "error: " prefix (the caller's report adds "Error: ").
fn clap_message(e: &clap::Error) -> String {
    let text = e.render().to_string();
    let text = text.trim_end();
    text.strip_prefix("error: ").unwrap_or(text).to_string()
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
