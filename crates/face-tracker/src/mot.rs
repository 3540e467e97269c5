//! Multiple-object tracking scores of a run against its ground truth, as the MOT benchmarks
//! define them and `py-motmetrics` computes them: CLEAR MOT's MOTA and identity switches
//! (Bernardin & Stiefelhagen, 2008) and the identity measures IDF1, IDP and IDR (Ristani et al.,
//! ECCV 2016 workshops).
//!
//! A true face and a track may match in a frame when the track's centre lies within the face's
//! `radius` of the face's centre. Per frame, a face keeps the track it matched last when they
//! may still match; the others are matched by the assignment of least total distance among the
//! pairs that may match (most pairs first); a face matched to another track than its last is
//! an identity switch. IDF1 matches whole trajectories once: each true identity to at most one
//! track, so that the frames they match (IDTP) are as many as they can be.
//! `crates/streampf-py/tests/test_mot.py` holds these numbers to py-motmetrics'.

use std::collections::{BTreeMap, BTreeSet, HashMap};

use pathfinding::kuhn_munkres::kuhn_munkres;
use pathfinding::matrix::Matrix;

/// A true face in a frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrueFace {
    pub identity: u64,
    pub centre: [f32; 2],
    /// How far from the centre a track may lie and still match it (pixels).
    pub radius: f32,
}

/// A track's estimate in a frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackedFace {
    pub track: u64,
    pub centre: [f32; 2],
}

/// One frame: its true faces and the tracks' estimates.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MotFrame {
    pub truth: Vec<TrueFace>,
    pub tracks: Vec<TrackedFace>,
}

/// The scores of a run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotScores {
    /// True face-frames.
    pub ground_truth: usize,
    /// Face-frames matched to a track.
    pub matches: usize,
    pub false_positives: usize,
    pub misses: usize,
    pub id_switches: usize,
    /// 1 − (misses + false positives + switches) / true face-frames (−∞ or NaN without true
    /// faces, as py-motmetrics has it).
    pub mota: f64,
    /// Face-frames matched with the identity's own track (the trajectories' assignment).
    pub idtp: usize,
    pub idf1: f64,
    pub idp: f64,
    pub idr: f64,
}

/// Whether `track` may match `face`, and at what distance.
fn distance(face: &TrueFace, track: &TrackedFace) -> Option<f64> {
    // In f64 from the start, as a scorer reading the values from a file computes it.
    let (dx, dy) = (
        f64::from(face.centre[0]) - f64::from(track.centre[0]),
        f64::from(face.centre[1]) - f64::from(track.centre[1]),
    );
    let d = (dx * dx + dy * dy).sqrt();
    (d <= f64::from(face.radius)).then_some(d)
}

/// How [`best_pairs`] ranks assignments.
#[derive(Clone, Copy, PartialEq)]
enum Rank {
    /// The most pairs, then the greatest total weight (CLEAR MOT's matching of a frame).
    MostPairs,
    /// The greatest total weight alone (IDF1's assignment of trajectories).
    Weight,
}

/// The one-to-one assignment of rows to columns ranked best by `rank` (`weight` `None`: may not
/// be paired; weights finite); returns the pairs.
fn best_pairs(
    rows: usize,
    columns: usize,
    rank: Rank,
    weight: impl Fn(usize, usize) -> Option<f64>,
) -> Vec<(usize, usize)> {
    if rows == 0 || columns == 0 {
        return Vec::new();
    }
    // Integer weights for the exact algorithm: each weight as a share of the largest, in units
    // of 2^-30 of it, so that no sum overflows; to rank by pairs first, a bonus larger than
    // every weight together on each pair.
    let n = rows.max(columns);
    let largest = (0..rows)
        .flat_map(|r| (0..columns).map(move |c| (r, c)))
        .filter_map(|(r, c)| weight(r, c))
        .fold(0.0f64, |m, w| m.max(w.abs()));
    let unit = if largest > 0.0 {
        largest / f64::from(1u32 << 30)
    } else {
        1.0
    };
    let scaled = |w: f64| (w / unit).round() as i64;
    let bonus = match rank {
        // k + 1 pairs outweigh k whatever their weights (each within ±2^30).
        Rank::MostPairs => (2 * n as i64 + 1) * (1i64 << 30) + 1,
        Rank::Weight => 0,
    };
    let mut matrix = Matrix::new(n, n, 0i64);
    for r in 0..rows {
        for c in 0..columns {
            if let Some(w) = weight(r, c) {
                matrix[(r, c)] = bonus + scaled(w);
            }
        }
    }
    let (_, assignment) = kuhn_munkres(&matrix);
    assignment
        .into_iter()
        .enumerate()
        .filter(|&(r, c)| r < rows && c < columns && weight(r, c).is_some())
        .collect()
}

/// CLEAR MOT over the frames: (matches, false positives, misses, switches, ground truth).
fn clear_mot(frames: &[MotFrame]) -> (usize, usize, usize, usize, usize) {
    let mut last: HashMap<u64, u64> = HashMap::new();
    let (mut matches, mut fp, mut misses, mut switches, mut gt) = (0, 0, 0, 0, 0);
    for frame in frames {
        let pairs = frame_pairs(frame, &last);
        for &(f, t) in &pairs {
            let (identity, track) = (frame.truth[f].identity, frame.tracks[t].track);
            if last.insert(identity, track).is_some_and(|p| p != track) {
                switches += 1;
            }
        }
        matches += pairs.len();
        misses += frame.truth.len() - pairs.len();
        fp += frame.tracks.len() - pairs.len();
        gt += frame.truth.len();
    }
    (matches, fp, misses, switches, gt)
}

/// A frame's (face, track) pairs: each face with its last track while they may match, then
/// the least-distance assignment of the rest.
fn frame_pairs(frame: &MotFrame, last: &HashMap<u64, u64>) -> Vec<(usize, usize)> {
    let mut face_taken = vec![false; frame.truth.len()];
    let mut track_taken = vec![false; frame.tracks.len()];
    let mut pairs = Vec::new();
    for (f, face) in frame.truth.iter().enumerate() {
        let Some(&previous) = last.get(&face.identity) else {
            continue;
        };
        if let Some(t) = frame.tracks.iter().position(|h| h.track == previous)
            && !track_taken[t]
            && distance(face, &frame.tracks[t]).is_some()
        {
            face_taken[f] = true;
            track_taken[t] = true;
            pairs.push((f, t));
        }
    }
    let free_faces: Vec<usize> = (0..frame.truth.len()).filter(|&f| !face_taken[f]).collect();
    let free_tracks: Vec<usize> = (0..frame.tracks.len())
        .filter(|&t| !track_taken[t])
        .collect();
    let assigned = best_pairs(
        free_faces.len(),
        free_tracks.len(),
        Rank::MostPairs,
        |r, c| distance(&frame.truth[free_faces[r]], &frame.tracks[free_tracks[c]]).map(|d| -d),
    );
    pairs.extend(
        assigned
            .into_iter()
            .map(|(r, c)| (free_faces[r], free_tracks[c])),
    );
    pairs
}

/// The identity measures: IDTP of the trajectories' best one-to-one assignment.
fn identity_true_positives(frames: &[MotFrame]) -> usize {
    let mut together: BTreeMap<(u64, u64), usize> = BTreeMap::new();
    let (mut identities, mut tracks) = (BTreeSet::new(), BTreeSet::new());
    for frame in frames {
        for face in &frame.truth {
            identities.insert(face.identity);
            for track in &frame.tracks {
                if distance(face, track).is_some() {
                    *together.entry((face.identity, track.track)).or_default() += 1;
                }
            }
        }
        tracks.extend(frame.tracks.iter().map(|t| t.track));
    }
    let identities: Vec<u64> = identities.into_iter().collect();
    let tracks: Vec<u64> = tracks.into_iter().collect();
    best_pairs(identities.len(), tracks.len(), Rank::Weight, |r, c| {
        together.get(&(identities[r], tracks[c])).map(|&n| n as f64)
    })
    .into_iter()
    .map(|(r, c)| together[&(identities[r], tracks[c])])
    .sum()
}

/// The scores of `frames`.
pub fn score(frames: &[MotFrame]) -> MotScores {
    let (matches, false_positives, misses, id_switches, ground_truth) = clear_mot(frames);
    let hypotheses: usize = frames.iter().map(|f| f.tracks.len()).sum();
    let idtp = identity_true_positives(frames);
    // 0/0 (no true faces, or none and no tracks) is NaN, as py-motmetrics has it.
    let ratio = |a: usize, b: usize| a as f64 / b as f64;
    MotScores {
        ground_truth,
        matches,
        false_positives,
        misses,
        id_switches,
        mota: 1.0 - ratio(misses + false_positives + id_switches, ground_truth),
        idtp,
        idf1: ratio(2 * idtp, ground_truth + hypotheses),
        idp: ratio(idtp, hypotheses),
        idr: ratio(idtp, ground_truth),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn face(identity: u64, x: f32) -> TrueFace {
        TrueFace {
            identity,
            centre: [x, 100.0],
            radius: 30.0,
        }
    }

    fn track(track: u64, x: f32) -> TrackedFace {
        TrackedFace {
            track,
            centre: [x, 100.0],
        }
    }

    #[test]
    fn perfect_tracks_score_one_and_a_swap_is_two_switches() {
        // Two faces 200 px apart, ten frames, each track on its face.
        let frames: Vec<MotFrame> = (0..10)
            .map(|_| MotFrame {
                truth: vec![face(0, 100.0), face(1, 300.0)],
                tracks: vec![track(7, 105.0), track(9, 290.0)],
            })
            .collect();
        let s = score(&frames);
        assert_eq!((s.ground_truth, s.matches, s.id_switches), (20, 20, 0));
        assert_eq!((s.mota, s.idf1, s.idp, s.idr), (1.0, 1.0, 1.0, 1.0));
        // The tracks swap faces after frame 5: each face switches once, and the trajectories'
        // best assignment keeps 6 of each face's 10 frames.
        let mut swapped = frames.clone();
        for f in &mut swapped[6..] {
            f.tracks = vec![track(7, 295.0), track(9, 102.0)];
        }
        let s = score(&swapped);
        assert_eq!((s.matches, s.id_switches, s.idtp), (20, 2, 12));
        assert!((s.mota - (1.0 - 2.0 / 20.0)).abs() < 1e-12);
        assert!((s.idf1 - 24.0 / 40.0).abs() < 1e-12);
    }

    #[test]
    fn misses_and_false_positives_count_and_a_track_too_far_does_not_match() {
        let frames = vec![
            MotFrame {
                truth: vec![face(0, 100.0)],
                tracks: vec![track(1, 100.0), track(2, 500.0)],
            },
            MotFrame {
                truth: vec![face(0, 100.0)],
                // 31 px away: beyond the face's radius.
                tracks: vec![track(1, 131.0)],
            },
            MotFrame {
                truth: vec![],
                tracks: vec![],
            },
        ];
        let s = score(&frames);
        assert_eq!(
            (s.ground_truth, s.matches, s.misses, s.false_positives),
            (2, 1, 1, 2)
        );
        assert!((s.mota - (1.0 - 3.0 / 2.0)).abs() < 1e-12);
        assert_eq!(s.idtp, 1);
        assert!((s.idf1 - 2.0 / 5.0).abs() < 1e-12);
        let empty = score(&[]);
        assert_eq!(empty.ground_truth, 0);
        assert!(empty.idf1.is_nan() && empty.mota.is_nan());
    }

    /// The largest IDTP over every one-to-one assignment of identities to tracks, by trying
    /// them all (few identities and tracks).
    fn brute_force_idtp(frames: &[MotFrame]) -> usize {
        let mut together: BTreeMap<(u64, u64), usize> = BTreeMap::new();
        let (mut ids, mut tracks) = (BTreeSet::new(), BTreeSet::new());
        for f in frames {
            ids.extend(f.truth.iter().map(|t| t.identity));
            tracks.extend(f.tracks.iter().map(|t| t.track));
            for face in &f.truth {
                for track in f.tracks.iter().filter(|t| distance(face, t).is_some()) {
                    *together.entry((face.identity, track.track)).or_default() += 1;
                }
            }
        }
        let (ids, tracks): (Vec<u64>, Vec<u64>) =
            (ids.into_iter().collect(), tracks.into_iter().collect());
        fn best(
            i: usize,
            ids: &[u64],
            tracks: &[u64],
            used: &mut Vec<bool>,
            t: &BTreeMap<(u64, u64), usize>,
        ) -> usize {
            if i == ids.len() {
                return 0;
            }
            let mut most = best(i + 1, ids, tracks, used, t);
            for c in 0..tracks.len() {
                if !used[c] {
                    used[c] = true;
                    let here = t.get(&(ids[i], tracks[c])).copied().unwrap_or(0);
                    most = most.max(here + best(i + 1, ids, tracks, used, t));
                    used[c] = false;
                }
            }
            most
        }
        best(0, &ids, &tracks, &mut vec![false; tracks.len()], &together)
    }

    #[test]
    fn idf1_assigns_trajectories_by_frames_matched_not_by_pairs() {
        // Identity 0 is with track 7 in ten frames and with track 8 in one; identity 1 with
        // track 7 in one: 0–7 (IDTP 10) beats 0–8 and 1–7 (IDTP 2, two pairs).
        let mut frames: Vec<MotFrame> = (0..10)
            .map(|_| MotFrame {
                truth: vec![face(0, 100.0)],
                tracks: vec![track(7, 100.0)],
            })
            .collect();
        frames.push(MotFrame {
            truth: vec![face(0, 100.0), face(1, 300.0)],
            tracks: vec![track(8, 100.0), track(7, 300.0)],
        });
        let s = score(&frames);
        assert_eq!(s.idtp, 10);
        assert!((s.idf1 - 20.0 / 24.0).abs() < 1e-12);
    }

    fn frames_strategy() -> impl Strategy<Value = Vec<MotFrame>> {
        let frame = (
            prop::collection::vec((0u64..5, 0.0f32..400.0, 5.0f32..60.0), 0..5),
            prop::collection::vec((0u64..7, 0.0f32..400.0), 0..6),
        )
            .prop_map(|(truth, tracks)| {
                let mut seen = BTreeSet::new();
                let truth = truth
                    .into_iter()
                    .filter(|(id, ..)| seen.insert(*id))
                    .map(|(identity, x, radius)| TrueFace {
                        identity,
                        centre: [x, 0.0],
                        radius,
                    })
                    .collect();
                let mut seen = BTreeSet::new();
                let tracks = tracks
                    .into_iter()
                    .filter(|(id, _)| seen.insert(*id))
                    .map(|(track, x)| TrackedFace {
                        track,
                        centre: [x, 0.0],
                    })
                    .collect();
                MotFrame { truth, tracks }
            });
        prop::collection::vec(frame, 0..30)
    }

    proptest! {
        /// The counts add up, the ratios stay in range, and renaming the tracks (a one-to-one
        /// relabelling) changes no score.
        #[test]
        fn scores_are_consistent_and_do_not_depend_on_track_names(frames in frames_strategy()) {
            let s = score(&frames);
            let hypotheses: usize = frames.iter().map(|f| f.tracks.len()).sum();
            prop_assert_eq!(s.matches + s.misses, s.ground_truth);
            prop_assert_eq!(s.matches + s.false_positives, hypotheses);
            prop_assert!(s.idtp <= s.ground_truth.min(hypotheses));
            prop_assert!(s.idf1.is_nan() || (0.0..=1.0).contains(&s.idf1));
            prop_assert!(s.mota.is_nan() || s.mota <= 1.0);
            // IDTP is the most any one-to-one assignment of identities to tracks gets.
            prop_assert_eq!(s.idtp, brute_force_idtp(&frames));
            prop_assert!(s.id_switches <= s.matches);
            let renamed: Vec<MotFrame> = frames
                .iter()
                .map(|f| MotFrame {
                    truth: f.truth.clone(),
                    tracks: f
                        .tracks
                        .iter()
                        .map(|t| TrackedFace { track: 1000 - 3 * t.track, ..*t })
                        .collect(),
                })
                .collect();
            // (Debug, so that NaN scores compare equal.)
            prop_assert_eq!(format!("{:?}", score(&renamed)), format!("{s:?}"));
        }
    }
}
