//! The face tracker smoothing a lag behind on its GPUs (`FaceTracker::keep_lag_window`,
//! `pf_core::smooth_tracks::LaggedTracks`) gives the rows of the host smoother that reads every
//! frame's particles back (`FaceTracker::track_clouds`, `TrackSmoother` from the ancestry), on
//! one GPU and on two contexts splitting the slots, through a track that ends and a face added
//! in its slot (whose frames before it cannot be traced from after it).
//!
//! Tolerances: the means within 1e-4 of their magnitude (the GPU sums in f32, the host in f64);
//! an interval's end is the value of one particle in sorted order, and an f32 cumulative sum
//! may reach the 2.5 % or 97.5 % mark one particle earlier or later than the f64 one, so up to
//! 1 % of the interval ends may differ (in the runs measured none did).

mod common;

use face_tracker::model::FaceModel;
use face_tracker::synth::{FaceSynthConfig, FaceVideoRenderer, initial_rect};
use face_tracker::{FaceBackend, FaceTracker, FaceTrackerConfig};
use pf_core::smooth::lag_window::LagFrame;
use pf_core::smooth_tracks::{LagSmoother, LaggedTracks, SmoothedRow, TrackSmoother};

const LAG: usize = 3;
const FRAMES: usize = 14;
/// Track 1 ends before this frame, and a face is added in its slot two frames later.
const END_BEFORE: usize = 5;

fn rows_both_ways(backend: FaceBackend) -> (Vec<SmoothedRow>, Vec<SmoothedRow>) {
    let video = FaceSynthConfig {
        width: 640,
        height: 480,
        faces: 2,
        half_width: 50.0,
        ..FaceSynthConfig::paper(FRAMES)
    };
    let config = FaceTrackerConfig {
        particles: 200,
        best: 20,
        ..FaceTrackerConfig::default()
    };
    let model = FaceModel::generic(129).unwrap();
    let renderer = FaceVideoRenderer::new(&video, &model).unwrap();
    let first = renderer.render(0).unwrap();
    let rects: Vec<_> = (0..2).map(|k| initial_rect(&video, k)).collect();
    let mut tracker = FaceTracker::new(&first, &rects, &model, config, backend).unwrap();
    tracker.keep_lineage().unwrap();
    tracker.keep_lag_window(LAG, true).unwrap();
    let mut host = TrackSmoother::new(Some(LAG), tracker.transition(), tracker.motion_gain())
        .lagging_by(LagSmoother::Ancestry)
        .comparing_filtered();
    let angular = tracker.transition().angular;
    let mut device = LaggedTracks::new(LAG, angular.len(), angular, true);
    let (mut on_host, mut on_device) = (Vec::new(), Vec::new());
    let mut reads = 0;
    for frame in 0..FRAMES {
        let image = renderer.render(frame).unwrap();
        if frame == END_BEFORE {
            tracker.end_track(1).unwrap();
        }
        if frame == END_BEFORE + 2 {
            tracker.add_face(&image, &initial_rect(&video, 1)).unwrap();
        }
        let estimates = tracker.step(&image).unwrap();
        on_host.extend(
            host.add_frame(frame, tracker.track_clouds(&estimates).unwrap())
                .unwrap(),
        );
        let tracking = tracker.slot_tracks(&estimates);
        let mut read =
            |slot: usize, first: u64, n: usize| -> Result<Vec<LagFrame>, pf_core::PfError> {
                reads += 1;
                (tracker.lag_frames(slot, first, n))
                    .map_err(|e| pf_core::PfError::InvalidConfig(e.to_string()))
            };
        let rows = device
            .add_frame(frame, &tracking, tracker.lagged(), &mut read)
            .unwrap();
        on_device.extend(rows);
        if frame >= LAG {
            assert!(tracker.lagged().is_some(), "frame {frame}: no summaries");
        }
    }
    // Only the ended track's frames were read back while tracking: the rest came as summaries.
    assert_eq!(reads, 1, "slots read back while tracking");
    // A step neither smoother is given (a run that fails between a step and its smoothing): the
    // device is a step ahead, and its window's spare slot still holds the host's frames.
    tracker.step(&renderer.render(FRAMES - 1).unwrap()).unwrap();
    on_host.extend(host.finish().unwrap());
    let mut read = |slot: usize, first: u64, n: usize| -> Result<Vec<LagFrame>, pf_core::PfError> {
        (tracker.lag_frames(slot, first, n))
            .map_err(|e| pf_core::PfError::InvalidConfig(e.to_string()))
    };
    let (rest, unsmoothed) = device.finish(&mut read).unwrap();
    assert!(unsmoothed.is_empty(), "{unsmoothed:?}");
    on_device.extend(rest);
    (on_host, on_device)
}

fn assert_same_rows(mut host: Vec<SmoothedRow>, mut device: Vec<SmoothedRow>) {
    let key = |r: &SmoothedRow| (r.frame, r.track);
    host.sort_by_key(key);
    device.sort_by_key(key);
    let keys = |rows: &[SmoothedRow]| rows.iter().map(key).collect::<Vec<_>>();
    assert_eq!(keys(&host), keys(&device));
    // Three tracks: 0 through the run, 1 until it ends, 2 from the face added in its slot.
    let tracks: std::collections::BTreeSet<usize> = host.iter().map(|r| r.track).collect();
    assert_eq!(tracks.into_iter().collect::<Vec<_>>(), [0, 1, 2]);
    assert_eq!(host.len(), FRAMES + END_BEFORE + (FRAMES - END_BEFORE - 2));
    let (mut ends, mut differing) = (0, 0);
    for (h, d) in host.iter().zip(&device) {
        for (hv, dv) in (h.values.iter().chain(&h.filtered)).zip(d.values.iter().chain(&d.filtered))
        {
            let close = |a: f32, b: f32| (a - b).abs() <= 1e-4 * (1.0 + a.abs());
            assert!(
                close(hv.mean, dv.mean),
                "frame {} track {}: {hv:?} against {dv:?}",
                h.frame,
                h.track
            );
            ends += 2;
            differing +=
                usize::from(!close(hv.lower, dv.lower)) + usize::from(!close(hv.upper, dv.upper));
        }
    }
    assert!(
        differing * 100 <= ends,
        "{differing} of {ends} interval ends differ"
    );
}

#[test]
fn smoothing_on_the_gpu_gives_the_host_smoothers_rows() {
    let Some(ctx) = common::gpu_context("lag smoothing on the GPU") else {
        return;
    };
    let (host, device) = rows_both_ways(FaceBackend::Gpu(Box::new(ctx)));
    assert_same_rows(host, device);
}

#[test]
fn smoothing_on_two_gpu_contexts_gives_the_host_smoothers_rows() {
    let context = || common::gpu_context("lag smoothing on two GPU contexts");
    let (Some(a), Some(b)) = (context(), context()) else {
        return;
    };
    let (host, device) = rows_both_ways(FaceBackend::Gpus(vec![a, b]));
    assert_same_rows(host, device);
}
