//! Where `streampf face track` gets its frames (a video file, a directory of images, a generated
//! video, a webcam) and where it draws its results (PNG frames or a video).

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use face_tracker::GrayImage;
use face_tracker::synth::FaceVideoRenderer;
use rayon::prelude::*;

use crate::video::{VideoRead, VideoReader, is_video_path};

/// Image files read from a directory of frames.
pub const IMAGE_EXTENSIONS: [&str; 7] = ["png", "jpg", "jpeg", "bmp", "pgm", "ppm", "pnm"];

/// Frames, one after another.
pub enum Source {
    Images {
        files: Vec<PathBuf>,
        next: usize,
        /// The first frame's size: a later image of another size is unreadable as a frame.
        size: Option<(u32, u32)>,
    },
    Synthetic {
        renderer: Box<FaceVideoRenderer>,
        next: usize,
    },
    Video(Box<VideoReader>),
}

impl Source {
    /// The most frames [`Source::read_batch`] reads at once.
    pub const BATCH: usize = 16;

    /// A video file or a directory of image files (name order).
    pub fn open(path: &Path) -> anyhow::Result<Self> {
        if path.is_dir() {
            let mut files: Vec<PathBuf> = std::fs::read_dir(path)
                .with_context(|| format!("reading {}", path.display()))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| {
                    p.extension()
                        .and_then(|e| e.to_str())
                        .is_some_and(|e| IMAGE_EXTENSIONS.iter().any(|x| x.eq_ignore_ascii_case(e)))
                })
                .collect();
            files.sort();
            if files.is_empty() {
                bail!(
                    "{}: no image frames ({}) in the directory",
                    path.display(),
                    IMAGE_EXTENSIONS.join(", ")
                );
            }
            return Ok(Source::Images {
                files,
                next: 0,
                size: None,
            });
        }
        if !path.exists() {
            bail!("{}: no such file or directory", path.display());
        }
        if !path.is_file() {
            bail!(
                "{}: not a video file (a device, a pipe or a directory)",
                path.display()
            );
        }
        if !is_video_path(path) {
            // FFmpeg reads more than the usual extensions; let it try and say what is wrong.
            errln!(
                "note: {} has no usual video extension; trying FFmpeg on it",
                path.display()
            );
        }
        Ok(Source::Video(Box::new(VideoReader::open(path)?)))
    }

    /// Frames in the source, when known in advance.
    pub fn len(&self) -> Option<usize> {
        match self {
            Source::Images { files, .. } => Some(files.len()),
            Source::Synthetic { renderer, .. } => Some(renderer.config().frames),
            Source::Video(reader) => reader.info.frames,
        }
    }

    /// Frames per second for an annotated video (the source's, else 25).
    pub fn fps(&self) -> f64 {
        match self {
            Source::Video(reader) => reader.info.fps.unwrap_or(25.0),
            _ => 25.0,
        }
    }

    /// The next frame, `None` after the last; an image file that cannot be read is an error.
    pub fn next_frame(&mut self) -> anyhow::Result<Option<GrayImage>> {
        match self.read_next()? {
            FrameRead::Frame(image) => Ok(Some(image)),
            FrameRead::Unreadable(e) => Err(e),
            FrameRead::End => Ok(None),
        }
    }

    /// The next frame, telling a frame that cannot be read (an image file that is truncated or
    /// not an image: the run may skip it) from a source that cannot go on (an error).
    pub fn read_next(&mut self) -> anyhow::Result<FrameRead> {
        match self {
            Source::Images { files, next, size } => {
                let Some(path) = files.get(*next) else {
                    return Ok(FrameRead::End);
                };
                *next += 1;
                Ok(FrameRead::load(path).of_size(size, path))
            }
            Source::Synthetic { renderer, next } => {
                if *next >= renderer.config().frames {
                    return Ok(FrameRead::End);
                }
                *next += 1;
                Ok(FrameRead::Frame(renderer.render(*next - 1)?))
            }
            Source::Video(reader) => Ok(match reader.read()? {
                VideoRead::Frame(image) => FrameRead::Frame(image),
                VideoRead::Undecodable(index) => FrameRead::Unreadable(anyhow::anyhow!(
                    "frame {index} of the video could not be decoded (FFmpeg dropped it; its messages come at the end)"
                )),
                VideoRead::End => FrameRead::End,
            }),
        }
    }

    /// The next reads, at most `max` (at least one), in order: a directory's images are decoded
    /// and a synthetic video's frames rendered a frame per core at once (up to
    /// [`Source::BATCH`]; the frames are independent of each other; a synthetic video's first
    /// frame comes alone); a video file (FFmpeg decodes on its own threads) and a camera give
    /// one frame.
    pub fn read_batch(&mut self, max: usize) -> Vec<anyhow::Result<FrameRead>> {
        let count = max.clamp(1, rayon::current_num_threads().clamp(1, Self::BATCH));
        match self {
            Source::Images { files, next, size } => {
                let end = (*next + count).min(files.len());
                if *next >= end {
                    return vec![Ok(FrameRead::End)];
                }
                let loaded: Vec<FrameRead> = files[*next..end]
                    .par_iter()
                    .map(|p| FrameRead::load(p))
                    .collect();
                let reads = loaded
                    .into_iter()
                    .zip(&files[*next..end])
                    .map(|(read, path)| Ok(read.of_size(size, path)))
                    .collect();
                *next = end;
                reads
            }
            Source::Synthetic { renderer, next } => {
                let end = (*next + count).min(renderer.config().frames);
                if *next >= end {
                    return vec![Ok(FrameRead::End)];
                }
                if *next == 0 {
                    // The first frame alone, banded over all cores: the tracker starts at once
                    // instead of waiting for a whole batch.
                    *next = 1;
                    return vec![renderer.render(0).map(FrameRead::Frame).map_err(Into::into)];
                }
                let reads = renderer
                    .render_frames(*next..end)
                    .into_iter()
                    .map(|frame| Ok(FrameRead::Frame(frame?)))
                    .collect();
                *next = end;
                reads
            }
            _ => vec![self.read_next()],
        }
    }

    /// After the last frame: the decoder's error messages (empty when none, or not a video).
    pub fn decoder_messages(&self) -> &str {
        match self {
            Source::Video(reader) => reader.messages(),
            _ => "",
        }
    }

    /// After the last frame: how a video fell short of the length its container announced.
    pub fn short_end(&self) -> Option<&crate::video::ShortEnd> {
        match self {
            Source::Video(reader) => reader.short_end(),
            _ => None,
        }
    }
}

/// One read of a [`Source`].
pub enum FrameRead {
    Frame(GrayImage),
    /// This frame cannot be read; the next may be.
    Unreadable(anyhow::Error),
    End,
}

impl FrameRead {
    /// An image file: a frame, or unreadable (truncated, not an image).
    fn load(path: &Path) -> Self {
        match GrayImage::load(path) {
            Ok(image) => FrameRead::Frame(image),
            Err(e) => FrameRead::Unreadable(e.into()),
        }
    }

    /// An image of a size other than the first frame's is unreadable as a frame (skipped with a
    /// warning, or an error with --strict) instead of stopping the run; the first frame read
    /// sets `size`.
    fn of_size(self, size: &mut Option<(u32, u32)>, path: &Path) -> Self {
        let FrameRead::Frame(image) = self else {
            return self;
        };
        let (width, height) = *size.get_or_insert((image.width, image.height));
        if (image.width, image.height) == (width, height) {
            return FrameRead::Frame(image);
        }
        FrameRead::Unreadable(anyhow::anyhow!(
            "{}: {}x{}, not the first frame's {width}x{height}",
            path.display(),
            image.width,
            image.height
        ))
    }
}

/// Frames in flight on the reading side: a thread owns the source and decodes up to
/// [`ReadAhead::FRAMES`] frames ahead of the tracker (a synthetic video: a batch of a frame per
/// core, see [`Source::read_batch`]), so that reading frame t+1 overlaps tracking frame t. The
/// frames come in order and are the ones the source gives, so the results are those of reading
/// one frame at a time.
pub struct ReadAhead {
    frames: std::sync::mpsc::Receiver<anyhow::Result<FrameRead>>,
    /// Frames the reader has handed over so far (read by the tests, which watch it get ahead).
    #[cfg_attr(not(test), allow(dead_code))]
    handed_over: std::sync::Arc<std::sync::atomic::AtomicUsize>,
    reader: Option<std::thread::JoinHandle<Source>>,
    /// The source, once its thread has ended.
    source: Option<Source>,
}

impl ReadAhead {
    /// Frames decoded ahead of the tracker: room for a whole batch and then some, so that the
    /// reader hands a batch over at once and goes on to the next while the tracker works
    /// through it (with room for two frames, it waited on the tracker for all but the last two
    /// frames of each batch, and reading and tracking took turns).
    pub const FRAMES: usize = Source::BATCH + 2;

    /// Starts reading at most `limit` more frames of `source` on a thread of its own.
    pub fn start(mut source: Source, limit: usize) -> anyhow::Result<Self> {
        let (send, frames) = std::sync::mpsc::sync_channel(Self::FRAMES);
        // The batches decode (or render) on threads of their own: in the shared pool they would
        // queue behind the detector's work and hold up the tracker.
        let decoders = rayon::ThreadPoolBuilder::new()
            .num_threads(rayon::current_num_threads().clamp(1, Source::BATCH))
            .thread_name(|k| format!("frame-decoder-{k}"))
            .build()
            .context("starting the frame decoder threads")?;
        let handed_over = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(0));
        let count = handed_over.clone();
        let reader = std::thread::Builder::new()
            .name("frame-reader".into())
            .spawn(move || {
                let mut left = limit;
                'reading: while left > 0 {
                    for read in decoders.install(|| source.read_batch(left)) {
                        left -= 1;
                        let last = matches!(read, Ok(FrameRead::End) | Err(_));
                        // A closed channel: the tracker stopped (limit, interrupt, failure).
                        if send.send(read).is_err() || last {
                            break 'reading;
                        }
                        count.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    }
                }
                source
            })
            .context("starting the frame reader thread")?;
        Ok(Self {
            frames,
            handed_over,
            reader: Some(reader),
            source: None,
        })
    }

    /// Frames the reader has handed over so far (taken or waiting).
    #[cfg(test)]
    fn handed_over(&self) -> usize {
        self.handed_over.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// The next frame, in order; `End` after the limit.
    pub fn read_next(&mut self) -> anyhow::Result<FrameRead> {
        match self.frames.recv() {
            Ok(read) => read,
            // The reader has ended: at the limit (or after an error already returned), unless it
            // panicked, which must not pass for the end of the video.
            Err(_) => {
                self.join()?;
                Ok(FrameRead::End)
            }
        }
    }

    fn join(&mut self) -> anyhow::Result<()> {
        if let Some(reader) = self.reader.take() {
            let source = reader
                .join()
                .map_err(|_| anyhow::anyhow!("the frame reader thread panicked"))?;
            self.source = Some(source);
        }
        Ok(())
    }

    /// Stops reading (a frame being decoded is finished first) and gives the source back, for
    /// its decoder messages and its short-end check.
    pub fn finish(mut self) -> anyhow::Result<Source> {
        // Dropping the receiver makes the reader's next send fail, which ends its loop.
        let (unused_send, unused_frames) = std::sync::mpsc::sync_channel(0);
        drop(unused_send);
        drop(std::mem::replace(&mut self.frames, unused_frames));
        self.join()?;
        self.source
            .take()
            .context("the frame reader gave no source back")
    }
}

#[cfg(test)]
mod read_ahead_tests {
    use super::*;
    use face_tracker::model::FaceModel;
    use face_tracker::synth::FaceSynthConfig;

    fn synthetic(frames: usize) -> (Source, FaceVideoRenderer) {
        let config = FaceSynthConfig {
            width: 160,
            height: 120,
            faces: 1,
            half_width: 12.0,
            ..FaceSynthConfig::paper(frames)
        };
        let model = FaceModel::generic(33).unwrap();
        let renderer = FaceVideoRenderer::new(&config, &model).unwrap();
        let source = Source::Synthetic {
            renderer: Box::new(renderer.clone()),
            next: 0,
        };
        (source, renderer)
    }

    fn frame(read: FrameRead) -> Option<GrayImage> {
        match read {
            FrameRead::Frame(image) => Some(image),
            FrameRead::End => None,
            FrameRead::Unreadable(e) => panic!("unreadable: {e}"),
        }
    }

    #[test]
    fn frames_come_in_order_up_to_the_end_or_the_limit() {
        let (source, renderer) = synthetic(6);
        let mut ahead = ReadAhead::start(source, usize::MAX).unwrap();
        for k in 0..6 {
            let image = frame(ahead.read_next().unwrap()).expect("a frame");
            assert_eq!(image, renderer.render(k).unwrap(), "frame {k}");
        }
        assert!(frame(ahead.read_next().unwrap()).is_none());
        assert!(frame(ahead.read_next().unwrap()).is_none());
        let source = ahead.finish().unwrap();
        assert_eq!(source.len(), Some(6));

        // A limit of 3: three frames, then the end; the source has read exactly those.
        let (source, _) = synthetic(6);
        let mut ahead = ReadAhead::start(source, 3).unwrap();
        for _ in 0..3 {
            assert!(frame(ahead.read_next().unwrap()).is_some());
        }
        assert!(frame(ahead.read_next().unwrap()).is_none());
        match ahead.finish().unwrap() {
            Source::Synthetic { next, .. } => assert_eq!(next, 3),
            _ => unreachable!(),
        }
    }

    #[test]
    fn stopping_early_gives_the_source_back() {
        let (source, _) = synthetic(50);
        let mut ahead = ReadAhead::start(source, usize::MAX).unwrap();
        assert!(frame(ahead.read_next().unwrap()).is_some());
        // The reader is at most FRAMES (+ the one being handed over) ahead, then stops; a
        // synthetic source renders a batch of a frame per core at once.
        let most = ReadAhead::FRAMES + 2 + Source::BATCH;
        match ahead.finish().unwrap() {
            Source::Synthetic { next, .. } => {
                assert!((1..=most).contains(&next), "read {next}")
            }
            _ => unreachable!(),
        }
    }

    /// While the tracker works on a frame, the reader goes on: with the tracker holding still
    /// after the first frame, the reader fills the hand-over with a whole batch and renders the
    /// next (with room for two frames it stopped inside the first batch, and reading and
    /// tracking took turns).
    #[test]
    fn the_reader_gets_a_whole_batch_ahead_of_a_busy_tracker() {
        let (source, _) = synthetic(100);
        let mut ahead = ReadAhead::start(source, usize::MAX).unwrap();
        assert!(frame(ahead.read_next().unwrap()).is_some());
        // The one frame taken and a full hand-over: the reader got there without the tracker.
        // (Tiny frames take milliseconds; the deadline is for a machine busy with other work.)
        let full = 1 + ReadAhead::FRAMES;
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(60);
        while ahead.handed_over() < full && std::time::Instant::now() < deadline {
            std::thread::sleep(std::time::Duration::from_millis(10));
        }
        assert_eq!(
            ahead.handed_over(),
            full,
            "the reader did not fill the hand-over"
        );
        let batch = rayon::current_num_threads().clamp(1, Source::BATCH);
        match ahead.finish().unwrap() {
            Source::Synthetic { next, .. } => assert!(
                next > Source::BATCH + batch,
                "the reader stopped at frame {next} (batches of {batch})"
            ),
            _ => unreachable!(),
        }
    }
}
