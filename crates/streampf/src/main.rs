//! `streampf`: GPU particle filtering for visual tracking, from the command line.

/// mimalloc keeps the pages of the large buffers that threads make and drop every frame (see
/// Cargo.toml).
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn main() -> std::process::ExitCode {
    streampf::cli_main()
}
