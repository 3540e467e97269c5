//! Video in and out through FFmpeg's command-line tools (Debian's `ffmpeg` package), as
//! subprocess pipes of raw frames.
//!
//! Why pipes rather than linking libav* (the ffmpeg-next crate): nothing to build against (no
//! FFmpeg headers, no bindgen), any FFmpeg version on the PATH works, and a decoder that crashes
//! on a bad file takes down its own process, not the tracker, which reports ffmpeg's message.
//!
//! Frames come out as FFmpeg's `gray`: the decoder's luma plane (BT.601 weights for the usual SD
//! and webcam material), which is what a Viola–Jones detector and the tracker want; no colour
//! conversion happens on our side.

use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};

use anyhow::{Context, bail};
use face_tracker::GrayImage;

const INSTALL: &str = "install FFmpeg (Debian/Ubuntu: apt-get install ffmpeg)";

/// File extensions read as video (anything else in a directory is not).
pub const VIDEO_EXTENSIONS: [&str; 8] = ["mp4", "avi", "webm", "mkv", "mov", "m4v", "mpg", "ogv"];

pub fn is_video_path(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| VIDEO_EXTENSIONS.iter().any(|v| v.eq_ignore_ascii_case(e)))
}

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

fn spawn(command: &mut Command, what: &str) -> anyhow::Result<Child> {
    // Its own process group: a terminal's Ctrl-C reaches only us, and we finish the frame and
    // close the encoder properly instead of finding FFmpeg already killed.
    #[cfg(unix)]
    std::os::unix::process::CommandExt::process_group(command, 0);
    command.spawn().map_err(|e| {
        if e.kind() == std::io::ErrorKind::NotFound {
            anyhow::anyhow!("{what}: FFmpeg is not installed ({e}); {INSTALL}")
        } else {
            anyhow::anyhow!("{what}: cannot start FFmpeg: {e}")
        }
    })
}

/// Reads an FFmpeg process's messages in a thread beside the frames (a full pipe would stall
/// it); the thread returns them when the process ends.
fn drain_messages(child: &mut Child) -> anyhow::Result<std::thread::JoinHandle<String>> {
    let mut err = child.stderr.take().context("ffmpeg's error pipe")?;
    Ok(std::thread::spawn(move || {
        let mut text = String::new();
        let _ = err.read_to_string(&mut text);
        text
    }))
}

/// Reads a decoder's level-tagged messages in a thread: `showinfo`'s frame times go to the
/// returned channel as they come, error lines are kept (untagged) and returned at the end.
fn frame_times_and_errors(
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

/// Gray frames from an FFmpeg decoder process.
///
/// A file is decoded with FFmpeg's `showinfo` filter and `-fps_mode passthrough`: a frame FFmpeg
/// cannot decode leaves a gap in the decoded frames' times, which tells which frame it was
/// ([`VideoRead::Undecodable`]) instead of a silently repeated neighbour.
pub struct VideoReader {
    name: String,
    pub info: VideoInfo,
    child: Child,
    stdout: ChildStdout,
    stderr: Option<std::thread::JoinHandle<String>>,
    /// Each decoded frame's time (s), from `showinfo`, when the reader asked for them.
    frame_times: Option<std::sync::mpsc::Receiver<f64>>,
    /// Frames read from FFmpeg.
    decoded: usize,
    /// The index the next frame should have.
    next_index: usize,
    /// The first decoded frame's time (s): frame indices count from it.
    first_time: Option<f64>,
    /// Frames found missing before `held`, reported one at a time.
    missing: std::collections::VecDeque<usize>,
    /// A frame read ahead while its missing predecessors are reported.
    held: Option<GrayImage>,
    short: Option<ShortEnd>,
    /// FFmpeg's error messages, after the end.
    messages: String,
}

/// One read of a [`VideoReader`].
pub enum VideoRead {
    Frame(GrayImage),
    /// Frame `index` could not be decoded (FFmpeg dropped it).
    Undecodable(usize),
    End,
}

/// A video that ended before the length its container announced.
#[derive(Debug, Clone)]
pub struct ShortEnd {
    pub decoded: usize,
    /// The container's frame count.
    pub expected: usize,
    /// The frames the stream's duration holds at its frame rate, when both are known.
    pub by_duration: Option<usize>,
    /// What FFmpeg said (may be empty).
    pub message: String,
}

impl ShortEnd {
    /// Whether the evidence says the file is damaged: FFmpeg reported an error, or more frames
    /// are missing than a container's count is off by for a healthy file (more than 2 frames
    /// and more than 1 %). A container's count is an estimate (edit lists, B-frame delay, a
    /// duration × rate rounded), so an ordinary clip may announce a frame or two more than it
    /// holds.
    pub fn is_damage(&self) -> bool {
        let missing = self.expected.saturating_sub(self.decoded);
        let many_missing = missing > 2 && missing * 100 > self.expected;
        // An edit list that starts the video late keeps the count of every sample but shortens
        // the duration: a stream as long as its duration says is whole.
        let as_long_as_its_duration = self
            .by_duration
            .is_some_and(|frames| self.decoded + 1 >= frames);
        !self.message.trim().is_empty() || (many_missing && !as_long_as_its_duration)
    }

    /// The note for a shortfall that is not damage.
    pub fn as_estimate(&self) -> String {
        format!(
            "the video held {} frames where its container announces {} (a container's count is an estimate; FFmpeg reported no error)",
            self.decoded, self.expected
        )
    }
}

impl std::fmt::Display for ShortEnd {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "the video ended after {} of the {} frames its container announces",
            self.decoded, self.expected
        )?;
        // FFmpeg repeats itself on a damaged file: its last lines say enough.
        let lines: Vec<&str> = self.message.trim().lines().collect();
        match lines.len() {
            0 => write!(f, " (FFmpeg reported no error: is the file truncated?)"),
            n => write!(
                f,
                "; FFmpeg said{}: {}",
                if n > 4 {
                    format!(" ({} lines, the last 4)", n)
                } else {
                    String::new()
                },
                lines[n.saturating_sub(4)..].join("\n")
            ),
        }
    }
}

impl VideoReader {
    /// Opens a video file.
    pub fn open(path: &Path) -> anyhow::Result<Self> {
        let info = probe(path)?;
        let mut command = Command::new("ffmpeg");
        // Messages tagged by level (errors are kept, showinfo's lines give each frame's time).
        command
            .args([
                "-nostdin",
                "-hide_banner",
                "-nostats",
                "-v",
                "level+info",
                "-i",
            ])
            .arg(path)
            .args(["-map", "0:v:0", "-fps_mode", "passthrough"])
            .args(["-vf", "showinfo=checksum=0"])
            .args(["-f", "rawvideo", "-pix_fmt", "gray", "-"]);
        Self::start(path.display().to_string(), info, command, true)
    }

    /// Opens a V4L2 camera (Linux) at the given size.
    #[cfg(feature = "webcam")]
    pub fn webcam(device: &Path, width: u32, height: u32) -> anyhow::Result<Self> {
        let info = VideoInfo {
            width,
            height,
            fps: None,
            frames: None,
            duration: None,
        };
        Self::start(
            device.display().to_string(),
            info,
            webcam_command(device, width, height),
            false,
        )
    }

    /// Starts the decoder; `frame_times`: its messages carry showinfo's frame times.
    fn start(
        name: String,
        info: VideoInfo,
        mut command: Command,
        frame_times: bool,
    ) -> anyhow::Result<Self> {
        let mut child = spawn(
            command
                .stdin(Stdio::null())
                .stdout(Stdio::piped())
                .stderr(Stdio::piped()),
            &format!("decoding {name}"),
        )?;
        let stdout = child.stdout.take().context("ffmpeg's output pipe")?;
        let (stderr, frame_times) = if frame_times {
            let (stderr, times) = frame_times_and_errors(&mut child)?;
            (stderr, Some(times))
        } else {
            (drain_messages(&mut child)?, None)
        };
        Ok(Self {
            name,
            info,
            child,
            stdout,
            stderr: Some(stderr),
            frame_times,
            decoded: 0,
            next_index: 0,
            first_time: None,
            missing: Default::default(),
            held: None,
            short: None,
            messages: String::new(),
        })
    }

    /// The next frame, a frame FFmpeg could not decode, or the end (see [`VideoReader`]).
    pub fn read(&mut self) -> anyhow::Result<VideoRead> {
        if let Some(index) = self.missing.pop_front() {
            return Ok(VideoRead::Undecodable(index));
        }
        if let Some(frame) = self.held.take() {
            return Ok(VideoRead::Frame(frame));
        }
        let Some(frame) = self.next_frame()? else {
            return Ok(VideoRead::End);
        };
        let index = self.index_of_decoded_frame();
        self.missing.extend(self.next_index..index);
        self.next_index = index.max(self.next_index) + 1;
        match self.missing.pop_front() {
            Some(first) => {
                self.held = Some(frame);
                Ok(VideoRead::Undecodable(first))
            }
            None => Ok(VideoRead::Frame(frame)),
        }
    }

    /// The index of the frame just read: its time since the first frame × the frame rate, when
    /// both are known, else the next in order. A jump of more than two seconds is taken for a
    /// break in the timestamps, not for lost frames: the count goes on from there.
    fn index_of_decoded_frame(&mut self) -> usize {
        let (Some(times), Some(fps)) = (&self.frame_times, self.info.fps) else {
            return self.next_index;
        };
        // showinfo logs a frame before FFmpeg writes it, so its line is there or nearly.
        let Ok(time) = times.recv_timeout(std::time::Duration::from_secs(5)) else {
            return self.next_index;
        };
        let origin = *self.first_time.get_or_insert(time);
        let index = ((time - origin) * fps).round();
        if !index.is_finite()
            || index < self.next_index as f64
            || index > (self.next_index as f64 + 2.0 * fps)
        {
            // Re-based so that this frame is the next one.
            self.first_time = Some(time - self.next_index as f64 / fps);
            return self.next_index;
        }
        index as usize
    }

    /// The next frame; `None` at the end of the stream. A stream that ends inside a frame, or an
    /// ffmpeg that exits with an error, is an error with ffmpeg's message.
    pub fn next_frame(&mut self) -> anyhow::Result<Option<GrayImage>> {
        let (w, h) = (self.info.width, self.info.height);
        let mut data = vec![0u8; w as usize * h as usize];
        let mut filled = 0;
        while filled < data.len() {
            match self.stdout.read(&mut data[filled..]) {
                Ok(0) => break,
                Ok(n) => filled += n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(e).with_context(|| format!("reading {}", self.name)),
            }
        }
        if filled == data.len() {
            self.decoded += 1;
            return Ok(Some(GrayImage::new(w, h, data)?));
        }
        let status = self.child.wait().with_context(|| self.name.clone())?;
        let message = self
            .stderr
            .take()
            .and_then(|t| t.join().ok())
            .unwrap_or_default();
        if !status.success() {
            bail!(
                "{}: FFmpeg stopped after {} frames: {}",
                self.name,
                self.decoded,
                message.trim()
            );
        }
        if filled > 0 {
            bail!(
                "{}: the stream ended inside frame {} ({filled} of {} bytes)",
                self.name,
                self.decoded,
                data.len()
            );
        }
        if self.decoded == 0 {
            bail!("{}: FFmpeg decoded no frames", self.name);
        }
        // Frames found undecodable count as read: only frames missing at the end make it short.
        let accounted = self.decoded.max(self.next_index);
        if let Some(expected) = self.info.frames.filter(|&n| accounted < n) {
            let short = ShortEnd {
                decoded: accounted,
                expected,
                by_duration: (self.info.duration.zip(self.info.fps))
                    .map(|(seconds, fps)| (seconds * fps).round() as usize),
                message: message.clone(),
            };
            if short.is_damage() {
                self.short = Some(short);
            } else {
                errln!("note: {}", short.as_estimate());
            }
        }
        self.messages = message;
        Ok(None)
    }

    /// After the end: FFmpeg's error messages (empty when it had none).
    pub fn messages(&self) -> &str {
        &self.messages
    }

    /// After the end: how the stream fell short of its announced length, if it did.
    pub fn short_end(&self) -> Option<&ShortEnd> {
        self.short.as_ref()
    }
}

impl Drop for VideoReader {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

#[cfg(feature = "webcam")]
fn webcam_command(device: &Path, width: u32, height: u32) -> Command {
    let mut command = Command::new("ffmpeg");
    command
        .args(["-nostdin", "-v", "error", "-f", "v4l2", "-video_size"])
        .arg(format!("{width}x{height}"))
        .arg("-i")
        .arg(device)
        .args(["-f", "rawvideo", "-pix_fmt", "gray", "-"]);
    command
}

/// The encoder for an output file's container.
pub(crate) fn encoder_args(path: &Path) -> anyhow::Result<&'static [&'static str]> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    Ok(match ext.as_deref() {
        Some("mp4" | "mkv" | "mov" | "m4v") => {
            &["-c:v", "libx264", "-crf", "20", "-preset", "fast"]
        }
        Some("avi") => &["-c:v", "mpeg4", "-q:v", "3"],
        Some("webm") => &["-c:v", "libvpx-vp9", "-crf", "32", "-b:v", "0"],
        _ => bail!(
            "{}: write annotated video as .mp4, .mkv, .mov, .avi or .webm, or give a directory for PNG frames",
            path.display()
        ),
    })
}

/// RGB frames into an FFmpeg encoder process.
pub struct VideoWriter {
    path: PathBuf,
    size: (u32, u32),
    child: Child,
    stdin: Option<ChildStdin>,
    stderr: Option<std::thread::JoinHandle<String>>,
}

impl VideoWriter {
    pub fn create(path: &Path, width: u32, height: u32, fps: f64) -> anyhow::Result<Self> {
        let codec = encoder_args(path)?;
        // Most encoders need even sizes for 4:2:0: the last row or column is cropped if odd.
        let (even_w, even_h) = (width & !1, height & !1);
        let mut command = Command::new("ffmpeg");
        command
            .args([
                "-nostdin", "-v", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgb24",
            ])
            .args(["-s", &format!("{width}x{height}"), "-r", &format!("{fps}")])
            .args(["-i", "-", "-vf", &format!("crop={even_w}:{even_h}:0:0")])
            .args(codec)
            .args(["-pix_fmt", "yuv420p"])
            .arg(path);
        let mut child = spawn(
            command
                .stdin(Stdio::piped())
                .stdout(Stdio::null())
                .stderr(Stdio::piped()),
            &format!("writing {}", path.display()),
        )?;
        let stdin = child.stdin.take();
        let stderr = drain_messages(&mut child)?;
        Ok(Self {
            path: path.to_path_buf(),
            size: (width, height),
            child,
            stdin,
            stderr: Some(stderr),
        })
    }

    fn failure(&mut self) -> anyhow::Error {
        self.stdin = None;
        let _ = self.child.wait();
        let message = self
            .stderr
            .take()
            .and_then(|t| t.join().ok())
            .unwrap_or_default();
        anyhow::anyhow!(
            "{}: FFmpeg could not encode the video: {}",
            self.path.display(),
            message.trim()
        )
    }

    pub fn write(&mut self, frame: &image::RgbImage) -> anyhow::Result<()> {
        if frame.dimensions() != self.size {
            bail!(
                "{}: a {}x{} frame in a {}x{} video",
                self.path.display(),
                frame.width(),
                frame.height(),
                self.size.0,
                self.size.1
            );
        }
        let written = match self.stdin.as_mut() {
            Some(stdin) => stdin.write_all(frame.as_raw()).is_ok(),
            None => false,
        };
        if written { Ok(()) } else { Err(self.failure()) }
    }

    /// Closes the stream and waits for the encoder.
    pub fn finish(mut self) -> anyhow::Result<()> {
        self.stdin = None;
        let status = self
            .child
            .wait()
            .with_context(|| self.path.display().to_string())?;
        if status.success() {
            Ok(())
        } else {
            Err(self.failure())
        }
    }
}

impl Drop for VideoWriter {
    fn drop(&mut self) {
        self.stdin = None;
        let _ = self.child.wait();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn probe_answers_parse_in_any_order() {
        let info = parse_probe(
            "nb_frames=270\nwidth=720\nr_frame_rate=2997/125\nheight=528\nduration=11.26\n",
        )
        .unwrap();
        assert_eq!(
            (info.width, info.height, info.frames, info.duration),
            (720, 528, Some(270), Some(11.26))
        );
        assert!((info.fps.unwrap() - 23.976).abs() < 1e-3);
        let webm = parse_probe("width=64\nheight=48\nr_frame_rate=0/0\nnb_frames=N/A\n").unwrap();
        assert_eq!((webm.fps, webm.frames, webm.duration), (None, None, None));
        for bad in [
            "",
            "width=0\nheight=10",
            "width=abc\nheight=10",
            "height=10",
        ] {
            assert!(parse_probe(bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn only_evidence_of_damage_makes_a_short_video_an_error() {
        let short = |decoded, expected, by_duration, message: &str| ShortEnd {
            decoded,
            expected,
            by_duration,
            message: message.into(),
        };
        // A container's count off by a frame or two, or by 1 % of a long video: an estimate.
        assert!(!short(123, 124, None, "").is_damage());
        assert!(!short(18, 20, None, "").is_damage());
        assert!(!short(990, 1000, None, "").is_damage());
        // An edit list: every sample counted, the stream as long as its duration.
        assert!(!short(90, 100, Some(90), "").is_damage());
        // More missing, or a decoder's error, is damage.
        assert!(short(17, 20, None, "").is_damage());
        assert!(short(30, 60, Some(60), "").is_damage());
        assert!(short(123, 124, None, "Invalid NAL unit size").is_damage());
    }

    #[test]
    fn output_containers_choose_an_encoder_or_say_what_works() {
        assert!(
            encoder_args(Path::new("a.mp4"))
                .unwrap()
                .contains(&"libx264")
        );
        assert!(encoder_args(Path::new("a.AVI")).unwrap().contains(&"mpeg4"));
        assert!(
            encoder_args(Path::new("a.webm"))
                .unwrap()
                .contains(&"libvpx-vp9")
        );
        let err = encoder_args(Path::new("a.gif")).unwrap_err().to_string();
        assert!(err.contains(".mp4") && err.contains("directory"), "{err}");
        assert!(is_video_path(Path::new("x/Megamind.AVI")));
        assert!(!is_video_path(Path::new("x/frame.png")));
    }
}
