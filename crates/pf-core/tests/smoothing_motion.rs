//! The smoother's motion chosen by the evidence (`pf_core::smooth::motion`) against the exact
//! answers on a linear-Gaussian model: a random walk x_t = x_{t−1} + q·n observed as
//! y_t = x_t + r·n, filtered by the engine with a diffusion σ far wider than q (as a tracker's
//! search is), by K filters with their own random numbers.
//!
//! - The evidence gain of each candidate scale s (the filter re-weighted to motion s·σ) must
//!   match the Kalman filter's exact log p(y | s·σ) − log p(y | σ) (frames 1 on, both from the
//!   σ filter's posterior at frame 0): the filters' average within four standard errors plus
//!   2 % of the gain, for the candidates whose re-weighted filter keeps enough particles.
//! - Each filter's chosen scale lies within one candidate of the exact evidence's best.
//! - The smoothed means lie nearer the truth than the tracker's motion's smoother's, and within
//!   10 % (in RMS error) of the exact RTS smoother's at the chosen scale.
//! - The 95 % intervals (the chosen motion's widened to take in the tracker's motion's) hold the
//!   truth at least 95 % of the time: never narrower than honest.
//! - A walk that does move at the filter's own σ keeps a scale of at least ½.

use pf_core::batch::{BatchConfig, BatchFilter, BatchShape, gaussian_clouds};
use pf_core::kalman::RandomWalk;
use pf_core::resample::Systematic;
use pf_core::smooth::motion::{CANDIDATE_SCALES, OnlineMotion, smooth_values_by_evidence};
use pf_core::smooth::{Cloud, GaussianTransition};
use pf_core::{RandomStreams, Stage};

const NOISE: f64 = 0.5;
const FILTER_SIGMA: f64 = 0.8;
const FRAMES: usize = 150;
const FILTERS: usize = 8;
const PARTICLES: usize = 1000;

/// The true walk and its observations.
fn simulate(step: f64, seed: u64) -> (Vec<f64>, Vec<f64>) {
    let mut rng = RandomStreams::new(seed).stream(0, Stage::Model(0));
    let mut x = 0.0;
    (0..FRAMES)
        .map(|_| {
            x += step * rng.gaussian();
            (x, x + NOISE * rng.gaussian())
        })
        .unzip()
}

/// `[filter][frame]` clouds of K engine filters with diffusion FILTER_SIGMA.
fn filtered(ys: &[f64], seed: u64) -> Vec<Vec<Cloud>> {
    let shape = BatchShape::new(FILTERS, PARTICLES, 1).unwrap();
    let config = BatchConfig::new(shape, seed, vec![FILTER_SIGMA as f32]);
    let start = gaussian_clouds(&shape, seed, &[0.0; FILTERS], &[1.0]);
    let mut filter = BatchFilter::new(&config, Systematic, start).unwrap();
    let mut out = vec![Vec::new(); FILTERS];
    for &y in ys {
        filter
            .step(|_, _, x| -0.5 * ((x[0] - y as f32) / NOISE as f32).powi(2))
            .unwrap();
        for (k, run) in out.iter_mut().enumerate() {
            run.push(
                Cloud::of_target(
                    1,
                    PARTICLES,
                    k,
                    &filter.states,
                    &filter.log_weights,
                    vec![0.0],
                )
                .unwrap(),
            );
        }
    }
    out
}

fn transition() -> GaussianTransition {
    GaussianTransition {
        sigma: vec![FILTER_SIGMA as f32],
        angular: vec![false],
    }
}

/// The exact log p(y_1: | step) from the σ filter's posterior at frame 0.
fn exact_log_evidence(ys: &[f64], step: f64) -> f64 {
    let first = RandomWalk {
        step: FILTER_SIGMA,
        noise: NOISE,
        prior: (0.0, 1.0),
    }
    .filter(&ys[..1])[0]
        .filtered;
    let walk = RandomWalk {
        step,
        noise: NOISE,
        prior: first,
    };
    walk.filter(&ys[1..]).iter().map(|f| f.log_likelihood).sum()
}

/// The exact RTS smoother's means for a walk of `step`, from the prior N(0, 1).
fn rts_means(ys: &[f64], step: f64) -> Vec<f64> {
    let walk = RandomWalk {
        step,
        noise: NOISE,
        prior: (0.0, 1.0),
    };
    walk.smooth(ys).iter().map(|s| s.0).collect()
}

fn rms(a: &[f64], b: &[f64]) -> f64 {
    (a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>() / a.len() as f64).sqrt()
}

#[test]
fn the_evidence_chooses_the_walks_own_motion_and_smooths_as_rts_does() {
    let step = 0.1;
    let (truth, ys) = simulate(step, 3);
    let runs = filtered(&ys, 29);
    let exact_gain =
        |s: f64| exact_log_evidence(&ys, FILTER_SIGMA * s) - exact_log_evidence(&ys, FILTER_SIGMA);
    let exact_best = (CANDIDATE_SCALES.iter().copied())
        .max_by(|a, b| exact_gain(f64::from(*a)).total_cmp(&exact_gain(f64::from(*b))))
        .unwrap();
    let best_index = CANDIDATE_SCALES
        .iter()
        .position(|s| *s == exact_best)
        .unwrap();
    let tracker_rts = rts_means(&ys, FILTER_SIGMA);
    let mut gains = Vec::new();
    let (mut covered, mut scored) = (0usize, 0usize);
    for run in &runs {
        let (rows, choices) = smooth_values_by_evidence(run, &transition()).unwrap();
        let chosen = choices[0].scale;
        let at = CANDIDATE_SCALES.iter().position(|s| *s == chosen).unwrap();
        assert!(
            at.abs_diff(best_index) <= 1,
            "chose {chosen}, the exact evidence's best is {exact_best}"
        );
        let means: Vec<f64> = rows.iter().map(|r| f64::from(r[0].mean)).collect();
        for (row, x) in rows.iter().zip(&truth) {
            covered += usize::from(f64::from(row[0].lower) <= *x && *x <= f64::from(row[0].upper));
            scored += 1;
        }
        let rts_at_choice = rts_means(&ys, FILTER_SIGMA * f64::from(chosen));
        let (ours, exact, wide) = (
            rms(&means, &truth),
            rms(&rts_at_choice, &truth),
            rms(&tracker_rts, &truth),
        );
        eprintln!(
            "chose {chosen} (exact best {exact_best}): rms {ours:.4}, rts at choice {exact:.4}, tracker motion rts {wide:.4}"
        );
        assert!(
            ours < 0.9 * wide,
            "smoothed RMS error {ours:.3}, the tracker's motion's RTS {wide:.3}"
        );
        assert!(
            ours < 1.1 * exact,
            "smoothed RMS error {ours:.3}, RTS at scale {chosen}: {exact:.3}"
        );
        gains.push(choices[0].log_evidence_gain);
    }
    let coverage = covered as f64 / scored as f64;
    eprintln!(
        "the smoothed 95 % intervals held the truth {:.1} % of the time",
        100.0 * coverage
    );
    assert!(
        coverage >= 0.95,
        "the smoothed 95 % intervals held the truth {:.1} % of the time",
        100.0 * coverage
    );
    // Each filter's gain against the exact gain of the scale it chose.
    let mut chosen_exact = Vec::new();
    for (run, gain) in runs.iter().zip(&gains) {
        let (_, choices) = smooth_values_by_evidence(run, &transition()).unwrap();
        assert!(gain.is_finite() && *gain > 0.0, "gain {gain}");
        chosen_exact.push(exact_gain(f64::from(choices[0].scale)));
    }
    let n = FILTERS as f64;
    let differences: Vec<f64> = gains
        .iter()
        .zip(&chosen_exact)
        .map(|(g, e)| g - e)
        .collect();
    let average = differences.iter().sum::<f64>() / n;
    let spread = (differences
        .iter()
        .map(|d| (d - average).powi(2))
        .sum::<f64>()
        / (n - 1.0))
        .sqrt();
    let scale = chosen_exact.iter().sum::<f64>() / n;
    eprintln!("evidence gains: particles {gains:?}, exact {chosen_exact:?}");
    assert!(
        average.abs() < 4.0 * spread / n.sqrt() + 0.02 * scale.abs(),
        "the gains differ from the exact ones by {average:.2} on average (spread {spread:.2})"
    );
}

#[test]
fn a_walk_at_the_filters_own_motion_keeps_it() {
    let (_, ys) = simulate(FILTER_SIGMA, 5);
    for run in filtered(&ys, 31) {
        let (_, choices) = smooth_values_by_evidence(&run, &transition()).unwrap();
        assert!(choices[0].scale >= 0.5, "chose {:?}", choices[0]);
    }
}

/// A track's clouds in two values: the walk as it is, and the walk as an angle (wrapped into
/// [−π, π), so that its particles cross ±π), each frame drifting on by `drift`.
fn with_an_angle(run: &[Cloud], drift: [f32; 2]) -> Vec<Cloud> {
    (run.iter())
        .map(|c| {
            let wrapped = c.states.iter().map(|&x| {
                let turns = ((x + std::f32::consts::PI) / std::f32::consts::TAU).floor();
                x - turns * std::f32::consts::TAU
            });
            Cloud {
                states: c.states.iter().copied().chain(wrapped).collect(),
                weights: c.weights.clone(),
                drift: drift.to_vec(),
            }
        })
        .collect()
}

/// The evidence taken frame by frame (`OnlineMotion`, what `--smooth-lag L --smooth-motion auto`
/// runs), each window's first frame smoothed as it fills: fed a whole track, it chooses what the
/// whole track's evidence chooses, and the frames left in its last window are smoothed as the
/// whole track's smoother smooths them (the backward pass from the last frame is the same),
/// bit for bit; the lagged rows' means lie within their intervals. Walks that move slower than
/// the filter's search and at its pace, a value that is an angle, drifts.
#[test]
fn the_evidence_frame_by_frame_chooses_and_smooths_as_the_whole_tracks() {
    const LAG: usize = 5;
    let transition = GaussianTransition {
        sigma: vec![FILTER_SIGMA as f32; 2],
        angular: vec![false, true],
    };
    for (step, seed, drift) in [(0.1, 11, [0.0, 0.0]), (FILTER_SIGMA, 12, [0.05, -0.1])] {
        let (_, ys) = simulate(step, seed);
        for run in filtered(&ys, seed + 100).iter().take(3) {
            let run = with_an_angle(run, drift);
            let (whole, choices) = smooth_values_by_evidence(&run, &transition).unwrap();
            let mut online = OnlineMotion::new(transition.clone());
            let mut first = 0;
            for (t, cloud) in run.iter().enumerate() {
                online.push(cloud).unwrap();
                if t + 1 - first > LAG {
                    let row = online.smooth_first(&run[first..=t]).unwrap();
                    for s in &row {
                        assert!(
                            s.lower <= s.mean && s.mean <= s.upper,
                            "frame {first}: {s:?}"
                        );
                    }
                    first += 1;
                }
            }
            assert_eq!(online.choices(), choices, "step {step}");
            if step < 0.5 {
                // The slow walk's motion is not the search's: a re-weighted filter smooths it.
                assert!(choices.iter().all(|c| c.scale < 1.0), "{choices:?}");
            }
            let rest = online.smooth_all(&run[first..]).unwrap();
            assert_eq!(rest.len(), LAG);
            assert_eq!(rest[..], whole[first..], "step {step}");
            // A window that is not the one the evidence holds is an error, not garbage.
            assert!(online.smooth_all(&run[first + 1..]).is_err());
            // Each frame smoothed as soon as it comes (the window emptied every time): the
            // evidence's chain goes on all the same.
            let mut at_once = OnlineMotion::new(transition.clone());
            for (t, cloud) in run.iter().enumerate() {
                at_once.push(cloud).unwrap();
                at_once.smooth_first(&run[t..=t]).unwrap();
            }
            assert_eq!(at_once.choices(), choices, "step {step}, no lag");
        }
    }
}
