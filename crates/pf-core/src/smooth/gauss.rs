//! The one-dimensional Gauss transform, Σ_k w_k exp(−(y − x_k)² / 2σ²) at every target y, in
//! O(M + B) instead of O(M²): the sources' weights spread onto a grid of spacing σ / 10 (linear
//! binning: each weight shared between its two nearest nodes, which keeps the mass and the mean),
//! the grid convolved with the Gaussian cut at 8σ, and the result read at each target by linear
//! interpolation. Its error is a small share of the total weight (property-tested below against
//! the direct sum: at most 1 % of Σw, and 1 % of a value where it is not small against Σw).
//! When σ is tiny against the points' range the grid would be huge; then the sum runs directly
//! over the sources within 8σ of each target, which are few.
//! What [`super::motion`]'s blocked smoother is made of: a value's predictive density and its
//! backward pass are each one transform a frame.

/// Grid nodes per σ.
const NODES_PER_SIGMA: f64 = 10.0;
/// Where the Gaussian is cut, in σ (exp(−32) ≈ 1e−14 of its peak).
const CUT_SIGMAS: f64 = 8.0;
/// The largest grid; past it the direct sum over the sources near each target is cheaper.
const MAX_NODES: usize = 1 << 15;

/// Σ_k `weights[k]` · exp(−(y − `sources[k]`)² / 2σ²) for each y in `targets` (no 1/σ factor).
/// Needs `sources` and `weights` of one length, every point finite, weights ≥ 0 and σ > 0
/// (the caller's values: unchecked here beyond a debug assertion).
pub(crate) fn gauss_transform(
    sources: &[f64],
    weights: &[f64],
    targets: &[f64],
    sigma: f64,
) -> Vec<f64> {
    debug_assert_eq!(sources.len(), weights.len());
    debug_assert!(sigma > 0.0 && sigma.is_finite());
    let (lo, hi) = (sources.iter().chain(targets))
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &x| {
            (l.min(x), h.max(x))
        });
    if !(lo.is_finite() && hi.is_finite()) {
        return vec![0.0; targets.len()];
    }
    let step = sigma / NODES_PER_SIGMA;
    let span = (hi - lo) / step;
    if span + 2.0 > MAX_NODES as f64 {
        return direct_near(sources, weights, targets, sigma);
    }
    let nodes = span as usize + 2;
    let mut grid = vec![0.0f64; nodes];
    for (&x, &w) in sources.iter().zip(weights) {
        let at = (x - lo) / step;
        let i = (at as usize).min(nodes - 2);
        let f = at - i as f64;
        grid[i] += w * (1.0 - f);
        grid[i + 1] += w * f;
    }
    let reach = (CUT_SIGMAS * NODES_PER_SIGMA) as usize;
    let taps: Vec<f64> = (0..=reach)
        .map(|k| {
            let z = k as f64 / NODES_PER_SIGMA;
            (-0.5 * z * z).exp()
        })
        .collect();
    let occupied: Vec<usize> = (0..nodes).filter(|&i| grid[i] != 0.0).collect();
    let mut smoothed = vec![0.0f64; nodes];
    for &i in &occupied {
        let g = grid[i];
        let (first, last) = (i.saturating_sub(reach), (i + reach).min(nodes - 1));
        for (j, out) in smoothed[first..=last].iter_mut().enumerate() {
            *out += g * taps[(first + j).abs_diff(i)];
        }
    }
    targets
        .iter()
        .map(|&y| {
            let at = (y - lo) / step;
            let i = (at as usize).min(nodes - 2);
            let f = at - i as f64;
            smoothed[i] * (1.0 - f) + smoothed[i + 1] * f
        })
        .collect()
}

/// The transform summed directly over the sources within 8σ of each target (sorted sources,
/// a binary search for each window's start).
fn direct_near(sources: &[f64], weights: &[f64], targets: &[f64], sigma: f64) -> Vec<f64> {
    let mut sorted: Vec<(f64, f64)> = sources
        .iter()
        .copied()
        .zip(weights.iter().copied())
        .collect();
    sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
    let cut = CUT_SIGMAS * sigma;
    targets
        .iter()
        .map(|&y| {
            let start = sorted.partition_point(|&(x, _)| x < y - cut);
            (sorted[start..].iter())
                .take_while(|&&(x, _)| x <= y + cut)
                .map(|&(x, w)| {
                    let z = (y - x) / sigma;
                    w * (-0.5 * z * z).exp()
                })
                .sum()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn exact(sources: &[f64], weights: &[f64], targets: &[f64], sigma: f64) -> Vec<f64> {
        targets
            .iter()
            .map(|&y| {
                (sources.iter().zip(weights))
                    .map(|(&x, &w)| {
                        let z = (y - x) / sigma;
                        w * (-0.5 * z * z).exp()
                    })
                    .sum()
            })
            .collect()
    }

    /// Points spread over `spread`, some of them repeated (a resampled cloud), some far out.
    fn cloud(max: usize) -> impl Strategy<Value = Vec<f64>> {
        (
            1..max,
            -1e3f64..1e3,
            prop_oneof![Just(0.0), 1e-6f64..1.0, 1.0f64..1e4],
        )
            .prop_flat_map(|(n, centre, spread)| {
                proptest::collection::vec(
                    prop_oneof![
                        4 => (-1.0f64..1.0).prop_map(move |u| centre + spread * u),
                        1 => Just(centre),
                        1 => (-1.0f64..1.0).prop_map(move |u| centre + 20.0 * spread * u),
                    ],
                    n,
                )
            })
    }

    proptest! {
        /// The binned transform (and, for a σ tiny against the range, the direct one near each
        /// target) is within 1 % of the total weight of the direct sum everywhere, and within
        /// 1 % of the value itself wherever that is at least a tenth of the total weight.
        #[test]
        fn the_fast_transform_is_the_direct_sum_within_a_percent(
            sources in cloud(300),
            targets in cloud(300),
            seed_weights in proptest::collection::vec(prop_oneof![Just(0.0f64), 1e-6f64..1.0], 300),
            sigma in prop_oneof![1e-7f64..1e-3, 1e-3f64..1.0, 1.0f64..1e5],
        ) {
            let weights = &seed_weights[..sources.len()];
            let total: f64 = weights.iter().sum();
            let fast = gauss_transform(&sources, weights, &targets, sigma);
            let want = exact(&sources, weights, &targets, sigma);
            for (f, e) in fast.iter().zip(&want) {
                prop_assert!(f.is_finite() && *f >= -1e-12 * total);
                prop_assert!((f - e).abs() <= 0.01 * total + 1e-12, "{f} against {e} of {total}");
                if *e >= 0.1 * total {
                    prop_assert!((f - e).abs() <= 0.01 * e, "{f} against {e}");
                }
            }
        }
    }

    #[test]
    fn no_sources_or_no_targets() {
        assert_eq!(gauss_transform(&[], &[], &[1.0, 2.0], 1.0), vec![0.0, 0.0]);
        assert!(gauss_transform(&[1.0], &[1.0], &[], 1.0).is_empty());
        let one = gauss_transform(&[0.0], &[2.0], &[0.0, 1.0], 1.0);
        assert!((one[0] - 2.0).abs() < 1e-9 && (one[1] - 2.0 * (-0.5f64).exp()).abs() < 0.01);
    }
}
