//! `VideoReader`: a video file or a webcam decoded by ffmpeg into gray frames, with what an
//! early end or a damaged stream means.

use std::io::Read;
use std::path::Path;
use std::process::{Child, ChildStdout, Command, Stdio};

use super::probe::{VideoInfo, frame_times_and_errors, probe};
use super::{drain_messages, spawn};
use anyhow::{Context, bail};
use face_tracker::GrayImage;

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
