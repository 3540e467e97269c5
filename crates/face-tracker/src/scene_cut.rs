//! Scene cuts: where an edited video jumps from one shot to the next. A track does not survive
//! a cut on its own: its particles stay where its face was, and a template of a small or
//! low-contrast face fits the next shot's background (a wall, a dark corner) well enough never to
//! fail. [`crate::auto::AutoTracker`] therefore asks the detector to find every running track's
//! face again in the cut's first frame and ends the tracks it does not find
//! ([`crate::auto::same_face_and_size`]).
//!
//! A cut is told by the frame's gray-level histogram: the share of its pixels in each of
//! [`HISTOGRAM_BINS`] bins changes, in L1 distance (0 the same, 2 disjoint), by more than a
//! threshold from one frame to the next. Within a shot a face that talks and turns, or a camera
//! that pans, moves a histogram little: at most 0.08 from frame to frame on the three real
//! talking-head clips of the head-pose check that have no edits (carphone, franck, wolfgang),
//! where the cuts between the shots of Megamind.avi change it by 0.35–0.38 (docs/ACCURACY.md,
//! "Tracks on faces"). The jump cuts and exposure jumps of the edited clips (cap12, cap13; 0.3 to
//! 0.8) count as cuts too: the detector finds the same face again there and the track goes on,
//! its results unchanged.

use crate::extraction::FaceRect;
use crate::image::GrayImage;

/// The histogram's bins (8 gray levels each).
pub const HISTOGRAM_BINS: usize = 32;

/// The default threshold on a histogram's change that marks a cut.
pub const DEFAULT_SCENE_CUT: f32 = 0.25;

/// The histogram samples every `SAMPLE_STRIDE`-th pixel of every `SAMPLE_STRIDE`-th row: a
/// frame's distribution of levels needs no more, and the test then costs a few microseconds.
const SAMPLE_STRIDE: usize = 4;

/// The share of `frame`'s sampled pixels in each of [`HISTOGRAM_BINS`] gray-level bins (all
/// zero for an empty frame).
pub fn gray_histogram(frame: &GrayImage) -> [f32; HISTOGRAM_BINS] {
    let mut counts = [0u32; HISTOGRAM_BINS];
    let width = frame.width as usize;
    if width > 0 {
        for row in frame.data.chunks_exact(width).step_by(SAMPLE_STRIDE) {
            for &level in row.iter().step_by(SAMPLE_STRIDE) {
                counts[usize::from(level) * HISTOGRAM_BINS / 256] += 1;
            }
        }
    }
    let total = counts.iter().sum::<u32>().max(1) as f32;
    counts.map(|c| c as f32 / total)
}

/// The L1 distance between two histograms: 0 for the same shares, 2 for disjoint ones.
pub fn histogram_change(a: &[f32; HISTOGRAM_BINS], b: &[f32; HISTOGRAM_BINS]) -> f32 {
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).sum()
}

/// Tells cuts frame by frame.
#[derive(Debug, Clone)]
pub struct SceneCuts {
    threshold: f32,
    previous: Option<[f32; HISTOGRAM_BINS]>,
}

impl SceneCuts {
    /// A histogram change above `threshold` (in (0, 2)) is a cut.
    pub fn new(threshold: f32) -> Self {
        Self {
            threshold,
            previous: None,
        }
    }

    /// Whether `frame` starts a new shot: its histogram changed by more than the threshold
    /// since the frame before (the first frame is no cut).
    pub fn is_cut(&mut self, frame: &GrayImage) -> bool {
        let histogram = gray_histogram(frame);
        let cut = (self.previous.as_ref())
            .is_some_and(|previous| histogram_change(previous, &histogram) > self.threshold);
        self.previous = Some(histogram);
        cut
    }
}

/// The tracks that ran when a cut came, waiting for the detector to find their faces again.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct PendingCut {
    /// The cut's first frame: a detection of this frame or a later one decides.
    pub frame: usize,
    /// Whether a frame from the cut on was handed to the detector.
    pub sent: bool,
    /// (track, its rectangle at the cut) not yet found again.
    pub unconfirmed: Vec<(usize, FaceRect)>,
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn image(width: u32, height: u32, data: Vec<u8>) -> GrayImage {
        GrayImage {
            width,
            height,
            data,
        }
    }

    proptest! {
        /// A histogram's shares sum to one; a frame against itself changes by 0, and by at most
        /// 2 against any other; the change is symmetric.
        #[test]
        fn a_histogram_change_is_a_distance_between_shares(
            (width, height, a, b) in (1u32..40, 1u32..40).prop_flat_map(|(w, h)| {
                let n = (w * h) as usize;
                (Just(w), Just(h), proptest::collection::vec(any::<u8>(), n),
                 proptest::collection::vec(any::<u8>(), n))
            })
        ) {
            let (ha, hb) = (gray_histogram(&image(width, height, a)), gray_histogram(&image(width, height, b)));
            prop_assert!((ha.iter().sum::<f32>() - 1.0).abs() < 1e-4);
            prop_assert_eq!(histogram_change(&ha, &ha), 0.0);
            let change = histogram_change(&ha, &hb);
            prop_assert!((0.0..=2.0 + 1e-4).contains(&change));
            prop_assert_eq!(change, histogram_change(&hb, &ha));
        }

        /// Frames of one scene under small changes (noise of a few levels on every pixel, the
        /// picture shifted by a few pixels) are no cut; a frame of other levels is, and only at
        /// the frame where it starts.
        #[test]
        fn a_shot_changing_little_is_no_cut_and_a_new_shot_is(
            seed in any::<u64>(), shift in 0usize..6, noise in 0u8..4,
        ) {
            let (width, height) = (160u32, 120u32);
            let mut state = seed | 1;
            let mut next = move || { state ^= state << 13; state ^= state >> 7; state ^= state << 17; state };
            // A scene: a smooth gradient with a bright disc (a face) in the middle.
            let scene = |dx: usize| -> Vec<u8> {
                (0..height as usize).flat_map(|y| (0..width as usize).map(move |x| {
                    let (fx, fy) = (x as f32 - 80.0 - dx as f32, y as f32 - 60.0);
                    if fx * fx + fy * fy < 900.0 { 200 } else { (x / 2 + y / 4) as u8 }
                })).collect()
            };
            let mut cuts = SceneCuts::new(DEFAULT_SCENE_CUT);
            prop_assert!(!cuts.is_cut(&image(width, height, scene(0))));
            let moved: Vec<u8> = scene(shift).iter()
                .map(|&v| v.saturating_add((next() % (u64::from(noise) + 1)) as u8))
                .collect();
            prop_assert!(!cuts.is_cut(&image(width, height, moved)));
            // Another shot: darker, its own gradient.
            let other: Vec<u8> = (0..width * height).map(|i| (i % 37) as u8).collect();
            prop_assert!(cuts.is_cut(&image(width, height, other.clone())));
            prop_assert!(!cuts.is_cut(&image(width, height, other)));
        }
    }

    #[test]
    fn an_empty_frame_has_an_empty_histogram() {
        assert_eq!(
            gray_histogram(&image(0, 0, Vec::new())),
            [0.0; HISTOGRAM_BINS]
        );
    }
}
