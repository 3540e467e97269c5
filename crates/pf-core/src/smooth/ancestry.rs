//! Smoothing from the particles' ancestry (the genealogy, or path, smoother of Kitagawa 1996):
//! each particle of frame t descends from one particle of frame t − 1 (its lineage through the
//! frame's resamplings, every annealing layer's composed), so the particles of frame t with
//! their weights are also a sample of the whole path's posterior. An earlier frame s's particle
//! i is smoothed by the weights of its descendants at frame t:
//!
//! w_{s|t}^i = Σ_{m : A_{t→s}(m) = i} w_t^m
//!
//! O(M) a frame traced back: L frames behind is O(M·L), where the marginal smoother
//! ([`super::fixed_lag`]) is O(M²·L). The price is path degeneracy: the further back, the fewer
//! of frame s's particles still have descendants, and the narrower (over-confident) its
//! intervals. A lag of a few frames keeps most of them.
//!
//! A lineage entry [`NO_ANCESTOR`] says that the particle has none in the frame before (its
//! target was restarted from new particles): the trace stops there.

use crate::error::PfError;

/// The lineage entry of a particle with no ancestor in the previous frame (a restarted target).
pub const NO_ANCESTOR: u32 = u32::MAX;

/// Each earlier frame's smoothed weights given the newest's, traced back through the lineages.
///
/// `newest_weights` are the last frame's normalised weights (M of them); `lineages[k]` maps
/// frame k + 1's particles to frame k's (`lineages.len()` frames back: the result has
/// `lineages.len() + 1` rows, oldest first, the last the newest weights themselves). Every
/// frame has the same M particles. An error for a lineage of the wrong length, an index out of
/// range or [`NO_ANCESTOR`] (a trace cannot cross a restart: cut the window there first).
pub fn trace_back(newest_weights: &[f64], lineages: &[&[u32]]) -> Result<Vec<Vec<f64>>, PfError> {
    let particles = newest_weights.len();
    let mut rows = vec![newest_weights.to_vec()];
    for (k, lineage) in lineages.iter().enumerate().rev() {
        if lineage.len() != particles {
            return Err(PfError::LengthMismatch {
                what: "a frame's lineage",
                expected: particles,
                got: lineage.len(),
            });
        }
        let later = rows.last().map(Vec::as_slice).unwrap_or_default();
        let mut earlier = vec![0.0; particles];
        for (&ancestor, &w) in lineage.iter().zip(later) {
            let slot = earlier.get_mut(ancestor as usize).ok_or_else(|| {
                PfError::InvalidConfig(format!(
                    "lineage {k}: ancestor {ancestor} of {particles} particles (a restart or a bad index)"
                ))
            })?;
            *slot += w;
        }
        rows.push(earlier);
    }
    rows.reverse();
    Ok(rows)
}

/// Whether a lineage can be traced (no particle without an ancestor).
pub fn traceable(lineage: &[u32]) -> bool {
    !lineage.contains(&NO_ANCESTOR)
}

/// The lineage composed with one more resampling: `lineage[ancestors[k]]` for each new particle
/// k (`NO_ANCESTOR` stays so). Starting from the identity, a frame's layers composed in order give
/// the frame's lineage. The twin of `shaders/engine/lineage.wgsl`.
pub fn compose(lineage: &[u32], ancestors: &[u32], out: &mut [u32]) {
    for (o, &a) in out.iter_mut().zip(ancestors) {
        *o = lineage.get(a as usize).copied().unwrap_or(NO_ANCESTOR);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn assert_close(a: &[f64], b: &[f64]) {
        assert!(
            a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-12),
            "{a:?} vs {b:?}"
        );
    }

    #[test]
    fn weights_flow_to_ancestors_and_keep_their_sum() {
        let newest = [0.1, 0.2, 0.3, 0.4];
        let lineages: [&[u32]; 2] = [&[1, 1, 3, 0], &[2, 2, 0, 3]];
        let rows = trace_back(&newest, &lineages).unwrap();
        assert_eq!(rows.len(), 3);
        assert_eq!(rows[2], newest.to_vec());
        // Frame 1: particles 2 and 0, 3 descend.
        assert_close(&rows[1], &[0.3, 0.0, 0.3, 0.4]);
        // Frame 0: frame 1's 0 -> 1, 2 -> 3, 3 -> 0.
        assert_close(&rows[0], &[0.4, 0.3, 0.0, 0.3]);
        for row in &rows {
            assert!((row.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn a_restart_or_a_bad_index_is_an_error() {
        let newest = [0.5, 0.5];
        assert!(trace_back(&newest, &[&[0, NO_ANCESTOR]]).is_err());
        assert!(trace_back(&newest, &[&[0, 2]]).is_err());
        assert!(trace_back(&newest, &[&[0]]).is_err());
        assert!(!traceable(&[0, NO_ANCESTOR]));
        assert!(traceable(&[0, 1]));
    }

    #[test]
    fn composing_follows_each_resampling_back() {
        let identity = [0, 1, 2, 3];
        let (mut a, mut b) = ([0; 4], [0; 4]);
        compose(&identity, &[3, 3, 1, 0], &mut a);
        assert_eq!(a, [3, 3, 1, 0]);
        compose(&a, &[2, 0, 0, 1], &mut b);
        assert_eq!(b, [1, 3, 3, 3]);
        compose(&[NO_ANCESTOR, 1, 2, 3], &[0, 1, 9, 0], &mut a);
        assert_eq!(a, [NO_ANCESTOR, 1, NO_ANCESTOR, NO_ANCESTOR]);
    }
}
