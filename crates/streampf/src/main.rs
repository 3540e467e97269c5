//! `streampf`: GPU particle filtering for visual tracking, from the command line.

fn main() -> std::process::ExitCode {
    streampf::cli_main()
}
