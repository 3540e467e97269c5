//! The command line's commands run in this process (`streampf.track_video` builds a `face
//! track` command line): on a thread of its own, while this thread keeps Python's signals, so
//! that Ctrl-C stops the run after its current frame with every finished frame written.

use std::time::Duration;

use pyo3::exceptions::PyKeyboardInterrupt;
use pyo3::prelude::*;

use crate::errors::{runtime_error, value_error};

/// Runs `streampf ARGS…`; a bad command line is a ValueError, a failed run a RuntimeError and
/// an interrupted one KeyboardInterrupt (after the run has closed its files).
#[pyfunction]
pub fn run_command(py: Python<'_>, args: Vec<String>) -> PyResult<()> {
    let run = std::thread::Builder::new()
        .name("streampf run".into())
        .spawn(move || streampf::run_embedded(args))
        .map_err(|e| runtime_error(format!("starting the run's thread: {e}")))?;
    while !run.is_finished() {
        py.detach(|| std::thread::sleep(Duration::from_millis(20)));
        if let Err(interrupt) = py.check_signals() {
            streampf::request_stop();
            let finished = py.detach(|| run.join());
            return match finished {
                Ok(Err(e)) if e.downcast_ref::<streampf::Interrupted>().is_some() => {
                    Err(PyKeyboardInterrupt::new_err(e.to_string()))
                }
                _ => Err(interrupt),
            };
        }
    }
    match run.join() {
        Ok(Ok(())) => Ok(()),
        Ok(Err(e)) if e.downcast_ref::<streampf::UsageError>().is_some() => {
            Err(value_error(e.to_string()))
        }
        Ok(Err(e)) => Err(runtime_error(format!("{e:#}"))),
        Err(_) => Err(runtime_error("the run panicked")),
    }
}
