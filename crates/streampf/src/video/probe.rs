//! What ffprobe says of a video: its size, frames, rate and duration, and each frame's time.

use std::path::Path;
use std::process::{Child, Command, Stdio};

use super::spawn;
use anyhow::{Context, bail};

/// What ffprobe says of a video's first video stream.
#[derive(Debug, Clone, PartialEq)]
pub struct VideoInfo {
    pub width: u32,
    pub height: u32,
    /// Frames per second (None when the container does not say).
    pub fps: Option<f64>,
    /// Frames in the stream, when the container says.
    pub frames: Option<usize>,
    /// The stream's duration in seconds, when the container says.
    pub duration: Option<f64>,
}

/// Parses ffprobe's `key=value` lines (`-of default=noprint_wrappers=1`).
pub fn parse_probe(text: &str) -> anyhow::Result<VideoInfo> {
    let value = |key: &str| {
        text.lines()
            .find_map(|l| l.trim().strip_prefix(key)?.strip_prefix('='))
            .map(str::trim)
    };
    let size = |key: &str| -> anyhow::Result<u32> {
        value(key)
            .and_then(|v| v.parse::<u32>().ok())
            .filter(|&v| v > 0)
            .with_context(|| format!("no {key} in ffprobe's answer {text:?}"))
    };
    let fps = value("r_frame_rate").and_then(|v| {
        let (n, d) = v.split_once('/').unwrap_or((v, "1"));
        let (n, d) = (n.parse::<f64>().ok()?, d.parse::<f64>().ok()?);
        (n > 0.0 && d > 0.0).then(|| n / d)
    });
    let frames = value("nb_frames")
        .and_then(|v| v.parse::<usize>().ok())
        .filter(|&n| n > 0);
    let duration = value("duration")
        .and_then(|v| v.parse::<f64>().ok())
        .filter(|d| d.is_finite() && *d > 0.0);
    Ok(VideoInfo {
        width: size("width")?,
        height: size("height")?,
        fps,
        frames,
        duration,
    })
}

/// Reads a decoder's level-tagged messages in a thread: `showinfo`'s frame times go to the
/// returned channel as they come, error lines are kept (untagged) and returned at the end.
pub(super) fn frame_times_and_errors(
    child: &mut Child,
) -> anyhow::Result<(
    std::thread::JoinHandle<String>,
    std::sync::mpsc::Receiver<f64>,
)> {
    use std::io::BufRead;
    let err = child.stderr.take().context("ffmpeg's error pipe")?;
    let (sender, receiver) = std::sync::mpsc::channel();
    let thread = std::thread::spawn(move || {
        let mut kept = String::new();
        for line in std::io::BufReader::new(err).lines().map_while(Result::ok) {
            if let Some(time) = line
                .split_once("pts_time:")
                .filter(|_| line.contains("Parsed_showinfo"))
                .and_then(|(_, rest)| rest.split_whitespace().next()?.parse::<f64>().ok())
            {
                let _ = sender.send(time);
            } else if let Some(tag) = ["[error] ", "[fatal] "]
                .into_iter()
                .find(|tag| line.contains(tag))
            {
                kept.push_str(&line.replacen(tag, "", 1));
                kept.push('\n');
            }
        }
        kept
    });
    Ok((thread, receiver))
}

/// Asks ffprobe for the size, rate and length of `path`'s first video stream.
pub fn probe(path: &Path) -> anyhow::Result<VideoInfo> {
    if !path.exists() {
        bail!("{}: no such video file", path.display());
    }
    if !path.is_file() {
        bail!(
            "{}: not a video file (a device, a pipe or a directory)",
            path.display()
        );
    }
    let what = format!("reading {}", path.display());
    let output = spawn(
        Command::new("ffprobe")
            .args(["-v", "error", "-select_streams", "v:0", "-show_entries"])
            .arg("stream=width,height,r_frame_rate,nb_frames,duration")
            .args(["-of", "default=noprint_wrappers=1"])
            .arg(path)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped()),
        &what,
    )?
    .wait_with_output()
    .with_context(|| what.clone())?;
    let stderr = String::from_utf8_lossy(&output.stderr);
    if !output.status.success() {
        bail!(
            "{}: FFmpeg cannot decode this file: {}",
            path.display(),
            stderr.trim()
        );
    }
    let stdout = String::from_utf8_lossy(&output.stdout);
    if stdout.trim().is_empty() {
        bail!("{}: the file has no video stream", path.display());
    }
    parse_probe(&stdout).with_context(|| format!("{}: not a video FFmpeg can read", path.display()))
}
