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
mod probe;
mod reader;
mod writer;

pub use reader::{ShortEnd, VideoRead, VideoReader};
pub use writer::VideoWriter;
pub(crate) use writer::encoder_args;

use std::io::Read;
use std::path::Path;
use std::process::{Child, Command};

use anyhow::Context;

const INSTALL: &str = "install FFmpeg (Debian/Ubuntu: apt-get install ffmpeg)";

/// File extensions read as video (anything else in a directory is not).
pub const VIDEO_EXTENSIONS: [&str; 8] = ["mp4", "avi", "webm", "mkv", "mov", "m4v", "mpg", "ogv"];

pub fn is_video_path(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| VIDEO_EXTENSIONS.iter().any(|v| v.eq_ignore_ascii_case(e)))
}

pub(super) fn spawn(command: &mut Command, what: &str) -> anyhow::Result<Child> {
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
pub(super) fn drain_messages(child: &mut Child) -> anyhow::Result<std::thread::JoinHandle<String>> {
    let mut err = child.stderr.take().context("ffmpeg's error pipe")?;
    Ok(std::thread::spawn(move || {
        let mut text = String::new();
        let _ = err.read_to_string(&mut text);
        text
    }))
}

#[cfg(test)]
mod tests {
    use super::probe::parse_probe;
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
