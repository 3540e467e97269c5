//! `face track --overlay`: every frame drawn with what the tracker knows.
//!
//! - the frame in colour when the input is colour (image files re-read in colour; a video decoded
//!   a second time by FFmpeg as RGB — the tracker keeps FFmpeg's own gray, so its results do not
//!   depend on the overlay), else in gray;
//! - each running track: its visible template points posed by the estimate, the head's axes
//!   (x red, y green, z blue towards the camera) and a label `#TRACK CONFIDENCE` in the track's
//!   colour (a palette with no pure red, green or blue, so that tracks are not mistaken for axes);
//! - a fresh detection that started or restarted a track: a white rectangle labelled `new #N`
//!   or `re #N`;
//! - a track lost in the last [`LOST_SHOWN`] frames: a dashed rectangle where it was last seen,
//!   labelled `lost #N`;
//! - the frame number in the top left corner.

use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdout, Command, Stdio};

use anyhow::Context;
use face_tracker::extraction::FaceRect;
use face_tracker::likelihood::Lens;
use face_tracker::{FaceEstimate, GrayImage, Pose, Template, TrackStatus};
use image::{Rgb, RgbImage};
use nalgebra::Vector3;

use crate::annotated::Annotated;

/// Colours of the tracks (by track number): none is an axis's pure red, green or blue.
pub const TRACK_COLOURS: [[u8; 3]; 6] = [
    [255, 200, 0],
    [0, 220, 220],
    [230, 80, 230],
    [255, 140, 60],
    [160, 255, 120],
    [150, 150, 255],
];
/// Fresh detections.
pub const DETECTION: [u8; 3] = [255, 255, 255];
/// Tracks just lost.
pub const LOST: [u8; 3] = [255, 60, 60];
/// How many frames a lost track stays marked.
pub const LOST_SHOWN: usize = 15;
/// Pixels per font pixel of the labels (font8x8's 8×8 glyphs).
const TEXT_SCALE: u32 = 2;

/// What a frame's drawing needs besides the picture and the estimates.
#[derive(Debug, Default, Clone)]
pub struct Marks {
    /// Tracks that a detection started (`false`) or restarted (`true`) before this frame.
    pub detections: Vec<(usize, FaceRect, bool)>,
    /// Tracks lost recently: (track, where it was last seen, the frame it was lost at).
    pub lost: Vec<(usize, FaceRect, usize)>,
}

/// `picture` (the frame, in colour or gray) with the frame number, the tracks, the fresh
/// detections and the recently lost tracks drawn on it; the tracks' points seen through `lens`.
pub fn draw_faces(
    mut picture: RgbImage,
    frame: usize,
    templates: &[(usize, &Template)],
    estimates: &[FaceEstimate],
    marks: &Marks,
    lens: &Lens,
) -> RgbImage {
    for e in estimates
        .iter()
        .filter(|e| e.status == TrackStatus::Tracking)
    {
        let Some((_, template)) = templates.iter().find(|(id, _)| *id == e.track) else {
            continue;
        };
        draw_track(&mut picture, e, template, lens);
    }
    for (track, rect, restarted) in &marks.detections {
        rectangle(&mut picture, rect, DETECTION, false);
        let label = format!("{} #{track}", if *restarted { "re" } else { "new" });
        text(
            &mut picture,
            rect.x,
            rect.y + rect.height + 2.0,
            &label,
            DETECTION,
        );
    }
    for (track, rect, lost_at) in &marks.lost {
        if frame < lost_at + LOST_SHOWN {
            rectangle(&mut picture, rect, LOST, true);
            text(
                &mut picture,
                rect.x,
                rect.y + rect.height + 2.0,
                &format!("lost #{track}"),
                LOST,
            );
        }
    }
    text(
        &mut picture,
        4.0,
        4.0,
        &format!("frame {frame}"),
        [255, 255, 255],
    );
    picture
}

/// One track: its visible template points posed by the estimate, the head's axes, its label.
fn draw_track(picture: &mut RgbImage, e: &FaceEstimate, template: &Template, lens: &Lens) {
    let colour = TRACK_COLOURS[e.track % TRACK_COLOURS.len()];
    for (x, y) in posed_points(e, template, lens) {
        for (dx, dy) in [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0)] {
            put(picture, x + dx, y + dy, colour);
        }
    }
    let (origin, ends) = head_axes(e, lens);
    for (end, c) in ends.into_iter().zip(AXIS_COLOURS) {
        for offset in [-0.5f32, 0.0, 0.5] {
            line(
                picture,
                (origin.0 + offset, origin.1 + offset),
                (end.0 + offset, end.1 + offset),
                c,
            );
        }
    }
    let label = face_label(e);
    let above = e.rect.y - (8 * TEXT_SCALE) as f32 - 4.0;
    text(picture, e.rect.x, above.max(0.0), &label, colour);
}

/// A track's label on the overlay and in the recording: `#TRACK CONFIDENCE`, with the person
/// (`id IDENTITY`) when the track took an earlier track's identity.
pub fn face_label(e: &FaceEstimate) -> String {
    if e.identity == e.track {
        format!("#{} {:.2}", e.track, e.confidence)
    } else {
        format!("#{} id {} {:.2}", e.track, e.identity, e.confidence)
    }
}

/// The head's axes' colours: x red, y green, z blue.
pub const AXIS_COLOURS: [[u8; 3]; 3] = [[255, 0, 0], [0, 255, 0], [0, 0, 255]];

/// A track's template points that face the camera, posed by its estimate and seen through
/// `lens`, in pixels.
pub fn posed_points(e: &FaceEstimate, template: &Template, lens: &Lens) -> Vec<(f32, f32)> {
    let pose = Pose::new(&e.state);
    (template.points.iter())
        .filter(|q| pose.faces_camera(&Vector3::from(q.normal)))
        .filter_map(|q| pose.project_through(&Vector3::from(q.position), lens))
        .map(|p| (p.x, p.y))
        .collect()
}

/// The head's origin and the ends of its x, y and z axes in pixels, each axis half the face's
/// width long (at S = 1), seen through `lens` (an end at or behind the camera is drawn where
/// weak perspective puts it).
pub fn head_axes(e: &FaceEstimate, lens: &Lens) -> ((f32, f32), [(f32, f32); 3]) {
    let pose = Pose::new(&e.state);
    let length = 0.5 * e.rect.width / e.state[face_tracker::projection::SCALE].max(1e-3);
    let seen = |p: Vector3<f32>| {
        let at = (pose.project_through(&p, lens)).unwrap_or_else(|| pose.project(&p));
        (at.x, at.y)
    };
    let ends = [Vector3::x(), Vector3::y(), Vector3::z()].map(|axis| seen(axis * length));
    (seen(Vector3::zeros()), ends)
}

fn put(picture: &mut RgbImage, x: f32, y: f32, colour: [u8; 3]) {
    if x >= 0.0 && y >= 0.0 && (x as u32) < picture.width() && (y as u32) < picture.height() {
        picture.put_pixel(x as u32, y as u32, Rgb(colour));
    }
}

fn line(picture: &mut RgbImage, a: (f32, f32), b: (f32, f32), colour: [u8; 3]) {
    let steps = ((b.0 - a.0).abs().max((b.1 - a.1).abs()).ceil() as usize).max(1);
    for i in 0..=steps {
        let t = i as f32 / steps as f32;
        put(
            picture,
            a.0 + (b.0 - a.0) * t,
            a.1 + (b.1 - a.1) * t,
            colour,
        );
    }
}

/// A rectangle two pixels thick; `dashed`: 6 pixels on, 4 off. Only the part inside the picture
/// is walked, so a rectangle of a diverged estimate costs no more than one that fits.
fn rectangle(picture: &mut RgbImage, rect: &FaceRect, colour: [u8; 3], dashed: bool) {
    let (x0, y0) = (rect.x, rect.y);
    let (x1, y1) = (rect.x + rect.width, rect.y + rect.height);
    if !(x0.is_finite() && y0.is_finite() && x1.is_finite() && y1.is_finite()) {
        return;
    }
    let on = |k: f32| !dashed || (k as u32 % 10) < 6;
    let (width, height) = (picture.width() as f32, picture.height() as f32);
    for inset in [0.0, 1.0] {
        // Whole steps past the left edge, so that the dashes keep their phase.
        let mut x = x0 + (-x0).max(0.0).floor();
        while x <= x1.min(width) {
            if on(x - x0) {
                put(picture, x, y0 + inset, colour);
                put(picture, x, y1 - inset, colour);
            }
            x += 1.0;
        }
        let mut y = y0 + (-y0).max(0.0).floor();
        while y <= y1.min(height) {
            if on(y - y0) {
                put(picture, x0 + inset, y, colour);
                put(picture, x1 - inset, y, colour);
            }
            y += 1.0;
        }
    }
}

/// `label` in font8x8's glyphs at (x, y) (its top left), on a black box so that it reads on
/// any picture. Characters the font lacks are drawn as `?`.
pub fn text(picture: &mut RgbImage, x: f32, y: f32, label: &str, colour: [u8; 3]) {
    use font8x8::UnicodeFonts;
    let (x, y) = (x.max(0.0) as u32, y.max(0.0) as u32);
    let advance = 8 * TEXT_SCALE;
    for (k, c) in label.chars().enumerate() {
        let glyph = font8x8::BASIC_FONTS
            .get(c)
            .or_else(|| font8x8::BASIC_FONTS.get('?'))
            .unwrap_or([0; 8]);
        let left = x.saturating_add((k as u32).saturating_mul(advance));
        for (row, bits) in glyph.iter().enumerate() {
            for column in 0..8u32 {
                let ink = bits >> column & 1 == 1;
                for dy in 0..TEXT_SCALE {
                    for dx in 0..TEXT_SCALE {
                        let (px, py) = (
                            left.saturating_add(column * TEXT_SCALE + dx),
                            y.saturating_add(row as u32 * TEXT_SCALE + dy),
                        );
                        if px < picture.width() && py < picture.height() {
                            let shade = if ink { colour } else { [0, 0, 0] };
                            picture.put_pixel(px, py, Rgb(shade));
                        }
                    }
                }
            }
        }
    }
}

/// The frames in colour, for the overlay, in the order the tracker reads them.
pub enum ColourFrames {
    /// Image files, re-read in colour by index.
    Images(Vec<PathBuf>),
    /// A second FFmpeg decoder of the video, as RGB: its k-th frame is the k-th frame the
    /// tracker's gray decoder gave (both drop the same undecodable frames).
    Video {
        child: Child,
        stdout: ChildStdout,
        size: (u32, u32),
    },
}

impl ColourFrames {
    /// Colour frames of a directory's images (the files the tracker reads, in its order) or of
    /// a video file.
    pub fn images(files: Vec<PathBuf>) -> Self {
        ColourFrames::Images(files)
    }

    pub fn video(path: &Path, size: (u32, u32)) -> anyhow::Result<Self> {
        let mut child = Command::new("ffmpeg")
            .args(["-nostdin", "-hide_banner", "-nostats", "-v", "error", "-i"])
            .arg(path)
            .args(["-map", "0:v:0", "-fps_mode", "passthrough"])
            .args(["-f", "rawvideo", "-pix_fmt", "rgb24", "-"])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .context("starting FFmpeg to decode the overlay's colour frames")?;
        let stdout = child.stdout.take().context("FFmpeg's output")?;
        Ok(ColourFrames::Video {
            child,
            stdout,
            size,
        })
    }

    /// The colour of frame `index`, which the tracker read as `gray`; `None` when there is
    /// none (the frame is then drawn in gray).
    fn frame(&mut self, index: usize, gray: &GrayImage) -> Option<RgbImage> {
        let picture = match self {
            ColourFrames::Images(files) => image::open(files.get(index)?).ok()?.to_rgb8(),
            ColourFrames::Video { stdout, size, .. } => {
                use std::io::Read;
                let mut bytes = vec![0u8; 3 * size.0 as usize * size.1 as usize];
                stdout.read_exact(&mut bytes).ok()?;
                RgbImage::from_raw(size.0, size.1, bytes)?
            }
        };
        (picture.dimensions() == (gray.width, gray.height)).then_some(picture)
    }
}

impl Drop for ColourFrames {
    fn drop(&mut self) {
        if let ColourFrames::Video { child, .. } = self {
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

fn gray_picture(frame: &GrayImage) -> RgbImage {
    RgbImage::from_fn(frame.width, frame.height, |x, y| {
        let v = frame.data[(y * frame.width + x) as usize];
        Rgb([v, v, v])
    })
}

/// The overlay of a run: where it goes, the colour frames, the marks that last several frames.
pub struct FaceOverlay {
    out: Annotated,
    colour: Option<ColourFrames>,
    lost: Vec<(usize, FaceRect, usize)>,
    /// The last frame drawn, repeated for a frame that could not be read.
    last: Option<RgbImage>,
    /// The camera the tracker sees the faces through: the points are drawn where it sees them.
    lens: Lens,
}

impl FaceOverlay {
    pub fn new(out: Annotated, colour: Option<ColourFrames>, lens: Lens) -> Self {
        Self {
            out,
            colour,
            lost: Vec::new(),
            last: None,
            lens,
        }
    }

    /// Draws and writes frame `index`. `write`: false for a frame a resumed run only replays
    /// (its colour frame is still consumed, to stay in step).
    pub fn draw(
        &mut self,
        index: usize,
        gray: &GrayImage,
        templates: &[(usize, &Template)],
        estimates: &[FaceEstimate],
        detections: Vec<(usize, FaceRect, bool)>,
        write: bool,
    ) -> anyhow::Result<()> {
        for e in estimates {
            if let TrackStatus::Lost { frame } = e.status {
                self.lost.push((e.track, e.rect, frame));
            }
        }
        self.lost.retain(|(_, _, at)| index < at + LOST_SHOWN);
        let colour = self.colour.as_mut().and_then(|c| c.frame(index, gray));
        if !write {
            return Ok(());
        }
        let picture = colour.unwrap_or_else(|| gray_picture(gray));
        let marks = Marks {
            detections,
            lost: self.lost.clone(),
        };
        let drawn = draw_faces(picture, index, templates, estimates, &marks, &self.lens);
        self.out.write(index, &drawn)?;
        self.last = Some(drawn);
        Ok(())
    }

    /// A frame that could not be read: the last picture again, keeping a video's timing.
    pub fn repeat_last(&mut self, index: usize) -> anyhow::Result<()> {
        match &self.last {
            Some(last) => self.out.write(index, last),
            None => Ok(()),
        }
    }

    /// Closes the output (a video is finalised).
    pub fn finish(self) -> anyhow::Result<()> {
        let FaceOverlay { out, colour, .. } = self;
        drop(colour);
        out.finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rect(x: f32, y: f32) -> FaceRect {
        FaceRect {
            x,
            y,
            width: 40.0,
            height: 40.0,
        }
    }

    fn count(picture: &RgbImage, colour: [u8; 3]) -> usize {
        picture.pixels().filter(|p| p.0 == colour).count()
    }

    #[test]
    fn detections_and_recently_lost_tracks_are_marked() {
        let blank = RgbImage::from_pixel(200, 160, Rgb([90, 90, 90]));
        let marks = Marks {
            detections: vec![(3, rect(20.0, 20.0), false)],
            lost: vec![(1, rect(120.0, 60.0), 5)],
        };
        let drawn = draw_faces(blank.clone(), 10, &[], &[], &marks, &Lens::WEAK);
        // The detection's rectangle (its corner) and its label below it.
        assert_eq!(drawn.get_pixel(20, 20).0, DETECTION);
        assert!((62..78).any(|y| (20..60).any(|x| drawn.get_pixel(x, y).0 == DETECTION)));
        // The lost track's dashed rectangle: on at its corner, off 7 pixels along.
        assert_eq!(drawn.get_pixel(120, 60).0, LOST);
        assert_ne!(drawn.get_pixel(127, 60).0, LOST);
        // LOST_SHOWN frames after it was lost the mark is gone; the detection stays (it is
        // only passed for the frame it happened).
        let later = draw_faces(blank.clone(), 5 + LOST_SHOWN, &[], &[], &marks, &Lens::WEAK);
        assert_eq!(count(&later, LOST), 0);
        // Away from every mark the picture is untouched.
        assert_eq!(drawn.get_pixel(100, 150).0, [90, 90, 90]);
    }

    #[test]
    fn a_label_names_the_person_when_a_track_took_an_earlier_identity() {
        let mut e = FaceEstimate {
            track: 5,
            identity: 5,
            slot: 0,
            state: [100.0, 80.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            error: 0.01,
            spread: [0.0; 7],
            ess: 10.0,
            log_evidence: 0.0,
            confidence: 0.5234,
            status: TrackStatus::Tracking,
            rect: rect(80.0, 60.0),
        };
        assert_eq!(face_label(&e), "#5 0.52");
        e.identity = 2;
        assert_eq!(face_label(&e), "#5 id 2 0.52");
    }

    #[test]
    fn text_draws_ink_on_a_black_box_and_clips_at_the_border() {
        let mut picture = RgbImage::from_pixel(40, 20, Rgb([90, 90, 90]));
        text(&mut picture, 30.0, 10.0, "#7 ü", [0, 255, 255]);
        assert!(count(&picture, [0, 255, 255]) > 0);
        assert!(count(&picture, [0, 0, 0]) > 0);
        // Left of the label nothing changed.
        assert!((0..30).all(|x| picture.get_pixel(x, 15).0 == [90, 90, 90]));
    }
}

#[cfg(test)]
mod far_off_marks {
    use super::*;

    #[test]
    fn marks_far_outside_the_picture_are_clipped_not_walked() {
        let blank = RgbImage::from_pixel(64, 48, Rgb([90, 90, 90]));
        let far = FaceRect {
            x: -1.0e9,
            y: 3.0e9,
            width: 4.0e9,
            height: 4.0e9,
        };
        let marks = Marks {
            detections: vec![(usize::MAX, far, false)],
            lost: vec![(1, far, 0)],
        };
        // Returns (quickly) with the out-of-picture marks drawn nowhere.
        let drawn = draw_faces(blank, 1, &[], &[], &marks, &Lens::WEAK);
        assert_eq!(drawn.get_pixel(40, 30).0, [90, 90, 90]);
        assert!(!drawn.pixels().any(|p| p.0 == LOST));
    }
}
