//! `VideoWriter`: RGB frames piped to ffmpeg's encoder for the file's container.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};

use super::{drain_messages, spawn};
use anyhow::{Context, bail};

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
