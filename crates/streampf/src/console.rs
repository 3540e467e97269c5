//! What the command prints for its user: summaries on stdout (`outln!`), notes and warnings on
//! stderr (`errln!`).
//!
//! A run's results are its files, so printing never stops a run or loses a row. `println!`
//! panics when stdout is closed or full; these do not:
//! - a closed stdout (a pipe whose reader has gone: `| head`, `| true`) silences further output,
//!   as `rg` and `cat` end quietly on one, and the run goes on writing its files;
//! - any other failure (`> /dev/full`, a full disk) also silences it, and is kept:
//!   [`stdout_failure`] hands it to `cli_main`, which reports it in one line once the run has
//!   closed its files.
//!
//! A failure to write to stderr is ignored: there is nowhere left to report it.

use std::io::Write;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};

/// Set at the first failed write to stdout: nothing more is written there.
static STDOUT_SILENCED: AtomicBool = AtomicBool::new(false);
/// The first failure to write to stdout other than a closed pipe.
static STDOUT_FAILURE: Mutex<Option<std::io::Error>> = Mutex::new(None);

/// Writes to stdout and flushes (so that a full disk is seen at the line that meets it); see
/// the module doc for what a failure does.
pub fn write_stdout(text: std::fmt::Arguments) {
    if STDOUT_SILENCED.load(Ordering::SeqCst) {
        return;
    }
    let mut out = std::io::stdout().lock();
    if let Err(e) = out.write_fmt(text).and_then(|()| out.flush()) {
        STDOUT_SILENCED.store(true, Ordering::SeqCst);
        if e.kind() != std::io::ErrorKind::BrokenPipe
            && let Ok(mut failure) = STDOUT_FAILURE.lock()
        {
            failure.get_or_insert(e);
        }
    }
}

/// Writes to stderr, ignoring a failure.
pub fn write_stderr(text: std::fmt::Arguments) {
    let mut err = std::io::stderr().lock();
    let _ = err.write_fmt(text).and_then(|()| err.flush());
}

/// The first failure to write to stdout that was not a closed pipe (taken: asked once).
pub fn stdout_failure() -> Option<std::io::Error> {
    STDOUT_FAILURE.lock().ok()?.take()
}

/// The progress bar of a run of `frames` frames on stderr (hidden when `quiet`): the rate with
/// one decimal and the time left.
pub(crate) fn progress_bar(frames: usize, quiet: bool) -> indicatif::ProgressBar {
    if quiet {
        return indicatif::ProgressBar::hidden();
    }
    let bar = indicatif::ProgressBar::new(frames as u64);
    // The rate with one decimal (indicatif's own shows four) and the time left.
    if let Ok(style) = indicatif::ProgressStyle::with_template(
        "{bar:40} {pos}/{len} frames {rate} {eta} left {msg}",
    ) {
        bar.set_style(style.with_key(
            "rate",
            |state: &indicatif::ProgressState, w: &mut dyn std::fmt::Write| {
                let _ = write!(w, "{:.1} frames/s", state.per_sec());
            },
        ));
    }
    bar
}

/// `println!` that never panics (see the module doc).
macro_rules! outln {
    () => { $crate::console::write_stdout(format_args!("\n")) };
    ($($arg:tt)*) => {
        $crate::console::write_stdout(format_args!("{}\n", format_args!($($arg)*)))
    };
}

/// `print!` that never panics.
macro_rules! out {
    ($($arg:tt)*) => { $crate::console::write_stdout(format_args!($($arg)*)) };
}

/// `eprintln!` that never panics.
macro_rules! errln {
    ($($arg:tt)*) => {
        $crate::console::write_stderr(format_args!("{}\n", format_args!($($arg)*)))
    };
}
