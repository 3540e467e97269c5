//! The track smoother's windows, lags, restarts and lineages.

use super::*;
use crate::smooth::ancestry::NO_ANCESTOR;

const M: usize = 4;

fn transition() -> GaussianTransition {
    GaussianTransition {
        sigma: vec![0.1],
        angular: vec![false],
    }
}

fn cloud(track: usize, lineage: Option<Vec<u32>>) -> TrackCloud {
    TrackCloud {
        track,
        states: vec![0.0, 1.0, 2.0, 3.0],
        log_weights: vec![0.1f32.ln(), 0.2f32.ln(), 0.3f32.ln(), 0.4f32.ln()],
        lineage,
    }
}

#[test]
fn a_lag_writes_each_frame_lag_frames_late_and_the_rest_at_the_end() {
    let mut smoother = TrackSmoother::new(Some(2), transition(), 0.0);
    let mut due = Vec::new();
    for frame in 0..5 {
        let rows = smoother.add_frame(frame, vec![cloud(7, Some(vec![3, 3, 0, 1]))]);
        due.push(rows.unwrap().iter().map(|r| r.frame).collect::<Vec<_>>());
    }
    assert_eq!(due, [vec![], vec![], vec![0], vec![1], vec![2]]);
    let rest: Vec<usize> = smoother.finish().unwrap().iter().map(|r| r.frame).collect();
    assert_eq!(rest, [3, 4]);
}

#[test]
fn lagged_weights_are_the_descendants_weights() {
    let mut smoother = TrackSmoother::new(Some(1), transition(), 0.0).comparing_filtered();
    smoother.add_frame(0, vec![cloud(0, None)]).unwrap();
    // Frame 1's particles 0 and 1 descend from frame 0's 3, 2 and 3 from its 0: frame 0 is
    // smoothed to weights (0.7, 0, 0, 0.3), its mean 0.9.
    let rows = smoother
        .add_frame(1, vec![cloud(0, Some(vec![3, 3, 0, 0]))])
        .unwrap();
    assert!((rows[0].values[0].mean - 0.9).abs() < 1e-5, "{rows:?}");
    assert!((rows[0].filtered[0].mean - 2.0).abs() < 1e-5);
}

#[test]
fn a_restart_ends_the_window_and_a_missing_lineage_is_an_error() {
    let mut smoother = TrackSmoother::new(Some(3), transition(), 0.0);
    smoother.add_frame(0, vec![cloud(0, None)]).unwrap();
    smoother
        .add_frame(1, vec![cloud(0, Some(vec![0, 1, 2, 3]))])
        .unwrap();
    let rows = smoother
        .add_frame(2, vec![cloud(0, Some(vec![NO_ANCESTOR; M]))])
        .unwrap();
    assert_eq!(rows.iter().map(|r| r.frame).collect::<Vec<_>>(), [0, 1]);
    let error = smoother.add_frame(3, vec![cloud(0, None)]).unwrap_err();
    assert!(error.to_string().contains("lineage"), "{error}");
    // The whole-track smoother does not need it.
    let mut whole = TrackSmoother::new(None, transition(), 0.0);
    whole.add_frame(0, vec![cloud(0, None)]).unwrap();
    whole.add_frame(1, vec![cloud(0, None)]).unwrap();
    assert_eq!(whole.finish().unwrap().len(), 2);
}

#[test]
fn a_marginal_lag_smooths_each_window_as_the_marginal_smoother_does() {
    let mut smoother =
        TrackSmoother::new(Some(2), transition(), 0.0).lagging_by(LagSmoother::Marginal);
    let clouds: Vec<TrackCloud> = (0..4)
        .map(|k| TrackCloud {
            states: (0..M).map(|m| (m * (k + 1)) as f32 * 0.05).collect(),
            ..cloud(3, None)
        })
        .collect();
    let mut rows = Vec::new();
    for (frame, c) in clouds.iter().enumerate() {
        rows.extend(smoother.add_frame(frame, vec![c.clone()]).unwrap());
    }
    assert_eq!(rows.iter().map(|r| r.frame).collect::<Vec<_>>(), [0, 1]);
    assert_eq!(smoother.ancestry_health(), None);
    let window: Vec<Cloud> = (clouds[0..3].iter())
        .map(|c| Cloud::of_target(1, M, 0, &c.states, &c.log_weights, vec![0.0]).unwrap())
        .collect();
    let expected = crate::smooth::smooth_first_values(&window, &transition()).unwrap();
    assert_eq!(rows[0].values, expected);
}

#[test]
fn the_ancestry_health_compares_the_traced_and_filtered_sample_sizes() {
    let mut smoother = TrackSmoother::new(Some(1), transition(), 0.0);
    smoother.add_frame(0, vec![cloud(0, None)]).unwrap();
    // Every particle of frame 1 descends from frame 0's particle 2: an effective one particle
    // of the filtered 1 / 0.3.
    smoother
        .add_frame(1, vec![cloud(0, Some(vec![2; M]))])
        .unwrap();
    // A permutation keeps the weights' sizes: all of them.
    smoother
        .add_frame(2, vec![cloud(0, Some(vec![3, 2, 1, 0]))])
        .unwrap();
    let health = smoother.ancestry_health().unwrap();
    assert_eq!(health.rows, 2);
    assert_eq!(health.below_a_tenth, 0, "{health:?}");
    let expected = (0.3 + 1.0) / 2.0;
    assert!((health.mean_kept - expected).abs() < 1e-6, "{health:?}");
}
