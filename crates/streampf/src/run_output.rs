//! What keeps a long run's results: CSV files written row by row and flushed every frame (a run
//! stopped at any point leaves whole rows up to its last finished frame), the Ctrl-C / SIGTERM
//! handler that lets the current frame finish, and the error that says a run was interrupted.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{Context, bail};

/// The exit status of a run stopped by Ctrl-C or SIGTERM (128 + SIGINT, as shells report it).
pub const INTERRUPTED_EXIT: i32 = 130;

static STOP_REQUESTED: AtomicBool = AtomicBool::new(false);
/// Set once a run is started by an embedding program (`crate::run_embedded`).
static EMBEDDED: AtomicBool = AtomicBool::new(false);

/// Marks the process as an embedding program's and clears an earlier run's stop request.
pub fn start_embedded_run() {
    EMBEDDED.store(true, Ordering::SeqCst);
    STOP_REQUESTED.store(false, Ordering::SeqCst);
}

/// Asks the run to stop after its current frame, as a first Ctrl-C does.
pub fn request_stop() {
    STOP_REQUESTED.store(true, Ordering::SeqCst);
}

/// Installs the handler: the first Ctrl-C or SIGTERM asks the run to stop after the current frame
/// (it then closes its files and says how many frames it wrote); a second stops at once.
/// Inside an embedding program ([`start_embedded_run`]) it installs nothing: that program keeps
/// its own signal handling and calls [`request_stop`].
pub fn install_interrupt_handler() -> anyhow::Result<()> {
    if EMBEDDED.load(Ordering::SeqCst) {
        return Ok(());
    }
    ctrlc::set_handler(|| {
        if STOP_REQUESTED.swap(true, Ordering::SeqCst) {
            errln!("\nstopped at once (second interrupt)");
            std::process::exit(INTERRUPTED_EXIT);
        }
        errln!("\ninterrupted: finishing the current frame and closing the files (interrupt again to stop at once)");
    })
    .context("installing the Ctrl-C handler")
}

/// Whether an interrupt asked the run to stop.
pub fn stop_requested() -> bool {
    STOP_REQUESTED.load(Ordering::SeqCst)
}

/// The environment variable that loses the GPU on purpose before frame N of a `face track` or
/// `body track` run is stepped (`STREAMPF_SIMULATE_GPU_FAULT_AT=N`; with frames in flight,
/// before frame N is read back), through wgpu's device-lost path: the tests' way to check that
/// a GPU fault ends a run with a clear error and every earlier frame written.
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
///
/// A resumed run ([`CsvStream::resume`]) first re-makes the rows the file already holds: each is
/// checked against the file instead of written, so that a run whose inputs or settings differ
/// from the interrupted one's is refused ([`ResumeRefused`]) at the first row that differs. The
/// file is not touched until every kept row has been made again: a refused resume leaves every
/// byte as it was.
pub struct CsvStream {
    path: PathBuf,
    /// None while a resumed run replays the file's rows.
    out: Option<BufWriter<File>>,
    /// Rows already in the file that the resumed run must make again, in order.
    expected: std::collections::VecDeque<String>,
    /// A resumed file's header and kept rows: written over the file (dropping the rows of the
    /// frame the resumed run starts at, which may have been cut) before its first new row.
    rewrite: Option<String>,
    /// The file's length at the last finished frame.
    committed: u64,
    /// Bytes of rows written since then (buffered, or partly on disk).
    pending: u64,
}

/// A frame that was not finished (its rows failed to write: a full disk) leaves nothing: its rows
/// are dropped and the file cut back to the last finished frame, so that the file never ends in
/// half a row.
impl Drop for CsvStream {
    fn drop(&mut self) {
        if self.pending == 0 {
            return;
        }
        if let Some(out) = self.out.take() {
            let (file, _unwritten) = out.into_parts();
            let _ = file.set_len(self.committed);
        }
    }
}

/// A `--resume` refused because the resumed run made a row that differs from the file's: the
/// inputs or settings differ. Nothing was written.
#[derive(Debug, Clone, thiserror::Error)]
#[error(
    "--resume refused: this run's row differs from the interrupted run's in {} (frame {frame}): the inputs or settings differ; give the same ones, or start over without --resume (nothing was changed)\n  before: {before}\n  now:    {now}",
    path.display()
)]
pub struct ResumeRefused {
    pub path: PathBuf,
    pub frame: String,
    pub before: String,
    pub now: String,
}

/// The error of a run that stopped on `e` after writing `frames` frames to `out`; a refused
/// resume as it is (it wrote nothing, and says so).
pub fn stopped(e: anyhow::Error, frames: usize, out: &Path) -> anyhow::Error {
    if let Some(refused) = e.downcast_ref::<ResumeRefused>() {
        return anyhow::Error::new(refused.clone());
    }
    e.context(format!(
        "stopped; the {frames} frames before it were written to {}",
        out.display()
    ))
}

/// Where an interrupted run's files let a resumed one continue.
pub struct ResumePoint {
    /// The first frame to write again: the last frame in the file (which may have been cut
    /// mid-frame), 0 when it holds no rows.
    pub frame: usize,
}

impl ResumePoint {
    /// The resume point of `path` (a CSV whose rows start with the frame number); an error when
    /// the file is missing or is not this kind of file.
    pub fn of(path: &Path, header: &str) -> anyhow::Result<Self> {
        let text = std::fs::read_to_string(path).with_context(|| {
            format!(
                "--resume: nothing to resume at {} (no earlier run there)",
                path.display()
            )
        })?;
        if text.lines().next() != Some(header) {
            bail!(
                "--resume: {} was not written by this command (its header differs)",
                path.display()
            );
        }
        let frame = text
            .lines()
            .skip(1)
            .filter_map(|l| l.split(',').next()?.parse::<usize>().ok())
            .max()
            .unwrap_or(0);
        Ok(Self { frame })
    }

    /// Refuses a resume that would end before it wrote anything: a `limit` (--max-frames) at or
    /// below the resume point would only re-check frames the file already holds.
    pub fn check_limit(&self, limit: Option<u64>, path: &Path) -> anyhow::Result<()> {
        match limit {
            Some(limit) if limit as usize <= self.frame => bail!(
                "--resume: {} already holds frames 0 to {}; --max-frames {limit} would end before the first frame to write (give a larger --max-frames, or none, to continue the run)",
                path.display(),
                self.frame
            ),
            _ => Ok(()),
        }
    }
}

impl CsvStream {
    /// Creates (or truncates) `path` and writes the header line.
    pub fn create(path: &Path, header: &str) -> anyhow::Result<Self> {
        let file = File::create(path).with_context(|| format!("creating {}", path.display()))?;
        let mut stream = Self {
            path: path.to_path_buf(),
            out: Some(BufWriter::new(file)),
            expected: Default::default(),
            rewrite: None,
            committed: 0,
            pending: 0,
        };
        stream.row(header)?;
        stream.end_frame()?;
        Ok(stream)
    }

    /// Reopens an interrupted run's `path` at `from`: its rows of earlier frames are kept (and
    /// will be checked as the resumed run makes them again), later ones are dropped when the
    /// first new row is written. Reads the file and changes nothing.
    pub fn resume(path: &Path, header: &str, from: &ResumePoint) -> anyhow::Result<Self> {
        Self::resume_numbered_from(path, header, from, 0)
    }

    /// [`Self::resume`] for a file whose frames are numbered from `first` (OpenFace's from 1).
    pub fn resume_numbered_from(
        path: &Path,
        header: &str,
        from: &ResumePoint,
        first: usize,
    ) -> anyhow::Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("--resume: reading {}", path.display()))?;
        if text.lines().next() != Some(header) {
            bail!("--resume: {} has another header", path.display());
        }
        let kept: Vec<String> = text
            .lines()
            .skip(1)
            .take_while(|l| {
                l.split(',')
                    .next()
                    .and_then(|f| f.trim().parse::<usize>().ok())
                    .is_some_and(|f| f < from.frame + first)
            })
            .map(str::to_string)
            .collect();
        let mut body = format!("{header}\n");
        kept.iter().for_each(|l| {
            body.push_str(l);
            body.push('\n');
        });
        Ok(Self {
            path: path.to_path_buf(),
            out: None,
            expected: kept.into(),
            rewrite: Some(body),
            committed: 0,
            pending: 0,
        })
    }

    /// Appends one line (without its newline); while resuming, checks it against the file.
    pub fn row(&mut self, line: &str) -> anyhow::Result<()> {
        if let Some(kept) = self.expected.pop_front() {
            if kept != line {
                return Err(ResumeRefused {
                    path: self.path.clone(),
                    frame: line.split(',').next().unwrap_or_default().to_string(),
                    before: kept,
                    now: line.to_string(),
                }
                .into());
            }
            return Ok(());
        }
        self.pending += line.len() as u64 + 1;
        let out = self.writer()?;
        writeln!(out, "{line}").with_context(|| format!("writing {}", self.path.display()))
    }

    /// The file to append to; a resumed file is first cut back to its kept rows.
    fn writer(&mut self) -> anyhow::Result<&mut BufWriter<File>> {
        if self.out.is_none() {
            let body = self.rewrite.take().unwrap_or_default();
            self.committed = body.len() as u64;
            // Rewritten whole and renamed over the old file: a stop here leaves one or the other.
            let staged = self.path.with_extension("csv.resume");
            std::fs::write(&staged, body)
                .with_context(|| format!("writing {}", staged.display()))?;
            std::fs::rename(&staged, &self.path)
                .with_context(|| format!("replacing {}", self.path.display()))?;
            let file = std::fs::OpenOptions::new()
                .append(true)
                .open(&self.path)
                .with_context(|| format!("opening {}", self.path.display()))?;
            self.out = Some(BufWriter::new(file));
        }
        self.out
            .as_mut()
            .with_context(|| format!("writing {}", self.path.display()))
    }

    /// Flushes the rows written so far to the file: the frame is finished.
    pub fn end_frame(&mut self) -> anyhow::Result<()> {
        self.flush()?;
        self.committed += std::mem::take(&mut self.pending);
        Ok(())
    }

    /// Ends a frame in several files at once (a frame's states and errors, poses and joints):
    /// the frame counts as written only when every file took it; otherwise each is cut back to
    /// the frame before, so that the files always hold the same frames.
    pub fn end_frame_in_all(files: &mut [&mut CsvStream]) -> anyhow::Result<()> {
        if let Err(e) = files.iter_mut().try_for_each(|f| f.flush()) {
            files.iter_mut().for_each(|f| f.drop_unfinished_frame());
            return Err(e);
        }
        for f in files.iter_mut() {
            f.committed += std::mem::take(&mut f.pending);
        }
        Ok(())
    }

    fn flush(&mut self) -> anyhow::Result<()> {
        match self.out.as_mut() {
            Some(out) => out
                .flush()
                .with_context(|| format!("writing {}", self.path.display())),
            None => Ok(()),
        }
    }

    /// Drops the rows written since the last finished frame, from the buffer and the file.
    fn drop_unfinished_frame(&mut self) {
        if self.pending == 0 {
            return;
        }
        self.pending = 0;
        if let Some(out) = self.out.take() {
            let (file, _unwritten) = out.into_parts();
            let _ = file.set_len(self.committed);
            // Appending goes on at the new end (the file was opened to append, or is reopened).
            self.out = std::fs::OpenOptions::new()
                .append(true)
                .open(&self.path)
                .ok()
                .map(BufWriter::new);
        }
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

/// The lock file a run holds in its output directory (see [`OutputLock`]).
pub const LOCK_FILE: &str = ".streampf.lock";

/// An advisory lock on a run's output directory, held until the run ends: a second run into the
/// same `--out` (or a `--resume` of a run still going) is refused instead of mixing or cutting
/// the first run's files. The lock is the operating system's (`flock`), so a run that died
/// leaves no lock behind, only the file, which the next run takes over. The file holds the
/// holder's pid, for the refusal's message; it is never removed (removing it would let two runs
/// lock two different files of that name).
pub struct OutputLock {
    _file: File,
}

impl OutputLock {
    /// Creates `dir` if needed and locks it; an error naming the directory and the holder's pid
    /// when another run holds it.
    pub fn acquire(dir: &Path) -> anyhow::Result<Self> {
        use std::io::{Read, Seek};
        std::fs::create_dir_all(dir).with_context(|| match dir.is_file() {
            true => format!("--out {}: a file is there, not a directory", dir.display()),
            false => format!("creating the output directory {}", dir.display()),
        })?;
        let path = dir.join(LOCK_FILE);
        let mut file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .with_context(|| format!("opening the lock file {}", path.display()))?;
        match file.try_lock() {
            Ok(()) => {}
            Err(std::fs::TryLockError::WouldBlock) => {
                let mut holder = String::new();
                let _ = file.read_to_string(&mut holder);
                let holder = match holder.trim() {
                    "" => "another streampf run".to_string(),
                    pid => format!("another streampf run (pid {pid})"),
                };
                bail!(
                    "{}: {holder} is writing its results there; wait for it to end or give another --out",
                    dir.display()
                );
            }
            Err(std::fs::TryLockError::Error(e)) => {
                return Err(e).with_context(|| format!("locking {}", path.display()));
            }
        }
        file.set_len(0)
            .and_then(|()| file.rewind())
            .and_then(|()| writeln!(file, "{}", std::process::id()))
            .with_context(|| format!("writing the lock file {}", path.display()))?;
        Ok(Self { _file: file })
    }
}

/// The marker file of a directory that `face synth` or `body synth` wrote.
pub const SYNTHETIC_MARKER: &str = ".streampf-synthetic";

/// Makes `dir` ready for a synthetic video: a new or empty directory, or one an earlier
/// `synth` wrote (it holds [`SYNTHETIC_MARKER`]), whose old frames the new video replaces. A
/// directory holding anything else is the user's (their own `frame_*.png`, other images that a
/// later run would read as frames) and is refused unless `force`.
pub fn claim_synthetic_dir(dir: &Path, force: bool) -> anyhow::Result<()> {
    if dir.is_file() {
        bail!("--out {}: a file is there, not a directory", dir.display());
    }
    if dir.is_dir() && !dir.join(SYNTHETIC_MARKER).exists() && !force {
        let mut entries =
            std::fs::read_dir(dir).with_context(|| format!("reading {}", dir.display()))?;
        if let Some(entry) = entries.next() {
            let name = entry
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .unwrap_or_default();
            bail!(
                "--out {}: the directory holds files that streampf did not write (such as {name}); give a new or empty directory, or --force to write the video among them",
                dir.display()
            );
        }
    }
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    std::fs::write(dir.join(SYNTHETIC_MARKER), "written by streampf synth\n")
        .with_context(|| format!("writing {}", dir.join(SYNTHETIC_MARKER).display()))
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
        errln!("warning: skipping frame {frame}: {reason}");
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

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("streampf-run-output-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir.join(name)
    }

    /// A stream whose file is /dev/full: every flush fails, as on a full disk.
    fn full_disk() -> CsvStream {
        let file = std::fs::OpenOptions::new()
            .write(true)
            .open("/dev/full")
            .expect("the test needs Linux's /dev/full");
        CsvStream {
            path: PathBuf::from("/dev/full"),
            out: Some(BufWriter::new(file)),
            expected: Default::default(),
            rewrite: None,
            committed: 0,
            pending: 0,
        }
    }

    #[test]
    fn an_unfinished_frame_never_stays_in_the_file() {
        let path = scratch("unfinished.csv");
        let mut stream = CsvStream::create(&path, "frame,value").unwrap();
        stream.row("0,1.5").unwrap();
        stream.end_frame().unwrap();
        stream.row("1,2.5").unwrap();
        stream.row("1,3.5").unwrap();
        drop(stream);
        assert_eq!(
            std::fs::read_to_string(&path).unwrap(),
            "frame,value\n0,1.5\n"
        );
        std::fs::remove_file(&path).unwrap();
    }

    #[test]
    fn a_frame_one_file_cannot_take_is_dropped_from_every_file() {
        let path = scratch("together.csv");
        let mut states = CsvStream::create(&path, "frame,value").unwrap();
        states.row("0,1.5").unwrap();
        states.end_frame().unwrap();
        let mut errors = full_disk();
        states.row("1,2.5").unwrap();
        errors.row("1,0.25").unwrap();
        let failed = CsvStream::end_frame_in_all(&mut [&mut states, &mut errors]);
        assert!(failed.is_err());
        assert_eq!(
            std::fs::read_to_string(&path).unwrap(),
            "frame,value\n0,1.5\n"
        );
        // The stream goes on from the frame before: the next frame is appended after it.
        states.row("1,9.5").unwrap();
        states.end_frame().unwrap();
        drop(states);
        assert_eq!(
            std::fs::read_to_string(&path).unwrap(),
            "frame,value\n0,1.5\n1,9.5\n"
        );
        std::fs::remove_file(&path).unwrap();
    }
}
