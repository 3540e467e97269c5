//! What keeps a long run's results: CSV files written row by row and flushed every frame (a run
//! stopped at any point leaves whole rows up to its last finished frame), the Ctrl-C / SIGTERM
//! handler that lets the current frame finish, and the error that says a run was interrupted.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::Context;

/// The exit status of a run stopped by Ctrl-C or SIGTERM (128 + SIGINT, as shells report it).
pub const INTERRUPTED_EXIT: i32 = 130;

static STOP_REQUESTED: AtomicBool = AtomicBool::new(false);

/// Installs the handler: the first Ctrl-C or SIGTERM asks the run to stop after the current frame
/// (it then closes its files and says how many frames it wrote); a second stops at once.
pub fn install_interrupt_handler() -> anyhow::Result<()> {
    ctrlc::set_handler(|| {
        if STOP_REQUESTED.swap(true, Ordering::SeqCst) {
            eprintln!("\nstopped at once (second interrupt)");
            std::process::exit(INTERRUPTED_EXIT);
        }
        eprintln!("\ninterrupted: finishing the current frame and closing the files (interrupt again to stop at once)");
    })
    .context("installing the Ctrl-C handler")
}

/// Whether an interrupt asked the run to stop.
pub fn stop_requested() -> bool {
    STOP_REQUESTED.load(Ordering::SeqCst)
}

/// The environment variable that loses the GPU on purpose before frame N of a `face track` or
/// `body track` run (`STREAMPF_SIMULATE_GPU_FAULT_AT=N`), through wgpu's device-lost path: the
/// tests' way to check that a GPU fault ends a run with a clear error and every earlier frame
/// written.
pub const SIMULATE_GPU_FAULT_ENV: &str = "STREAMPF_SIMULATE_GPU_FAULT_AT";

/// Loses `ctx`'s device when `frame` is the one [`SIMULATE_GPU_FAULT_ENV`] names.
pub fn maybe_simulate_gpu_fault(frame: usize, ctx: Option<&pf_gpu::GpuContext>) {
    let at = std::env::var(SIMULATE_GPU_FAULT_ENV).ok();
    if let (Some(ctx), Some(at)) = (ctx, at.and_then(|v| v.parse::<usize>().ok()))
        && at == frame
    {
        ctx.simulate_device_loss();
    }
}

/// The error of a run that stopped on an interrupt after writing `frames` frames; `main` turns it
/// into [`INTERRUPTED_EXIT`].
#[derive(Debug, thiserror::Error)]
#[error("interrupted after {frames} frames; every finished frame was written to {}", out.display())]
pub struct Interrupted {
    pub frames: usize,
    pub out: PathBuf,
}

/// A CSV file written a row at a time; [`CsvStream::end_frame`] flushes it, so that the file
/// holds whole rows of every finished frame whatever stops the run.
pub struct CsvStream {
    path: PathBuf,
    out: BufWriter<File>,
}

impl CsvStream {
    /// Creates (or truncates) `path` and writes the header line.
    pub fn create(path: &Path, header: &str) -> anyhow::Result<Self> {
        let file = File::create(path).with_context(|| format!("creating {}", path.display()))?;
        let mut stream = Self {
            path: path.to_path_buf(),
            out: BufWriter::new(file),
        };
        stream.row(header)?;
        stream.end_frame()?;
        Ok(stream)
    }

    /// Appends one line (without its newline).
    pub fn row(&mut self, line: &str) -> anyhow::Result<()> {
        writeln!(self.out, "{line}").with_context(|| format!("writing {}", self.path.display()))
    }

    /// Flushes the rows written so far to the file.
    pub fn end_frame(&mut self) -> anyhow::Result<()> {
        self.out
            .flush()
            .with_context(|| format!("writing {}", self.path.display()))
    }
}

/// Removes the result files a previous run may have left in `dir` (`names`), so that a reused
/// output directory never mixes an old file with new ones.
pub fn clear_old_results(dir: &Path, names: &[&str]) -> anyhow::Result<()> {
    for name in names {
        let path = dir.join(name);
        match std::fs::remove_file(&path) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => {
                return Err(e).with_context(|| format!("removing the old {}", path.display()));
            }
        }
    }
    Ok(())
}

/// The file that lists the frames a run skipped, and why.
pub const SKIPPED_FILE: &str = "skipped.csv";

/// The frames a run skipped: each warned about on stderr and listed in skipped.csv (created at
/// the first one, so that a run that skipped nothing leaves no such file).
pub struct SkipLog {
    path: PathBuf,
    file: Option<CsvStream>,
    /// The frames skipped, in order.
    pub frames: Vec<usize>,
}

impl SkipLog {
    /// A log for the output directory `out`; an old skipped.csv there is removed.
    pub fn new(out: &Path) -> anyhow::Result<Self> {
        clear_old_results(out, &[SKIPPED_FILE])?;
        Ok(Self {
            path: out.join(SKIPPED_FILE),
            file: None,
            frames: Vec::new(),
        })
    }

    /// Warns about `frame` and writes its row.
    pub fn record(&mut self, frame: usize, error: &anyhow::Error) -> anyhow::Result<()> {
        let reason = format!("{error:#}");
        eprintln!("warning: skipping frame {frame}: {reason}");
        if self.file.is_none() {
            self.file = Some(CsvStream::create(&self.path, "frame,reason")?);
        }
        if let Some(file) = self.file.as_mut() {
            file.row(&format!("{frame},\"{}\"", reason.replace('"', "\"\"")))?;
            file.end_frame()?;
        }
        self.frames.push(frame);
        Ok(())
    }

    /// The summary line's note of skipped frames ("" when none).
    pub fn note(&self) -> String {
        match self.frames.as_slice() {
            [] => String::new(),
            [one] => format!(", 1 unreadable frame skipped ({}; see {SKIPPED_FILE})", one),
            many => {
                let listed: Vec<String> = many.iter().take(10).map(|f| f.to_string()).collect();
                let more = if many.len() > 10 { ", …" } else { "" };
                format!(
                    ", {} unreadable frames skipped ({}{more}; see {SKIPPED_FILE})",
                    many.len(),
                    listed.join(", ")
                )
            }
        }
    }
}
