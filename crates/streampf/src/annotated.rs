//! Where annotated frames go, for both trackers' `--overlay`: PNG frames in a directory, or a
//! video file encoded by FFmpeg (by its extension).

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};

use crate::video::{VideoWriter, is_video_path};

/// Where annotated frames go: PNGs in a directory, or a video file (by its extension).
pub enum Annotated {
    Frames(PathBuf),
    Video(VideoWriter),
}

impl Annotated {
    /// Checks that `path` names something an overlay can be written as (a video container we
    /// encode, or a directory), before the run creates or writes anything.
    pub fn check_path(path: &Path) -> anyhow::Result<()> {
        if is_video_path(path) {
            crate::video::encoder_args(path)?;
        } else if path.extension().is_some() && !path.is_dir() {
            bail!(
                "{}: give a directory for PNG frames or a .mp4, .mkv, .avi or .webm file",
                path.display()
            );
        }
        Ok(())
    }

    /// Refuses an overlay directory that is the input's directory of frames: its PNGs would be
    /// written among the frames, and read as frames by the next run.
    pub fn check_not_input(path: &Path, input: Option<&Path>) -> anyhow::Result<()> {
        let same = |a: &Path, b: &Path| match (a.canonicalize(), b.canonicalize()) {
            (Ok(a), Ok(b)) => a == b,
            _ => false,
        };
        if let Some(input) = input.filter(|i| i.is_dir() && same(path, i)) {
            bail!(
                "--overlay {}: that is the input directory {}; its annotated PNGs would be read as frames by the next run: give another directory",
                path.display(),
                input.display()
            );
        }
        Ok(())
    }

    pub fn create(path: &Path, width: u32, height: u32, fps: f64) -> anyhow::Result<Self> {
        Self::check_path(path)?;
        if is_video_path(path) {
            if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
                std::fs::create_dir_all(parent)
                    .with_context(|| format!("creating {}", parent.display()))?;
            }
            return Ok(Annotated::Video(VideoWriter::create(
                path, width, height, fps,
            )?));
        }
        std::fs::create_dir_all(path).with_context(|| format!("creating {}", path.display()))?;
        Ok(Annotated::Frames(path.to_path_buf()))
    }

    pub fn write(&mut self, index: usize, frame: &image::RgbImage) -> anyhow::Result<()> {
        match self {
            Annotated::Frames(dir) => {
                let path = dir.join(format!("overlay_{index:05}.png"));
                frame
                    .save(&path)
                    .with_context(|| format!("writing {}", path.display()))
            }
            Annotated::Video(writer) => writer.write(frame),
        }
    }

    pub fn finish(self) -> anyhow::Result<()> {
        match self {
            Annotated::Frames(_) => Ok(()),
            Annotated::Video(writer) => writer.finish(),
        }
    }
}
