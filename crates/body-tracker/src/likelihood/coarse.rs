//! Coarse-to-fine annealing layers: the first layers of a frame weigh a subset of its points.
//!
//! The early annealing layers are broad (a small β, the full diffusion noise): they find the
//! body's rough place, which a few thousand of the frame's points show as well as all of them.
//! Weighing a subset there and every point in the last layers cuts an annealed step's
//! likelihood work roughly by the subset's share in the coarse layers. σ of eq. 3 is scaled to
//! the subset's size as it is to a frame's (σ ∝ √points), so that a subset's log-likelihood
//! estimates the whole frame's (the mean squared distance over the points, not their sum).
//! The GPU weighs the subset as a second level of the frame's prepared rays
//! ([`super::gpu::PreparedRays`]); the CPU as rays of their own.

use crate::error::BodyError;

/// Which layers weigh a subset of the points, and how large it is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CoarseLayers {
    /// The most points a coarse layer weighs: every k-th point of the frame, k the smallest
    /// that leaves at most this many (a frame with fewer points is weighed whole).
    pub points: usize,
    /// How many of a frame's annealing layers, from the first, are coarse; the last layer
    /// always weighs every point ([`Self::within`]): the estimate is taken from its weights.
    pub layers: usize,
}

impl CoarseLayers {
    /// A subset of at least one point, in some layers.
    pub fn validate(&self) -> Result<(), BodyError> {
        if self.points == 0 {
            return Err(BodyError::InvalidInput(
                "coarse annealing layers need at least one point".into(),
            ));
        }
        Ok(())
    }

    /// Every how many points the subset takes, of a frame of `frame_points`.
    pub fn stride(&self, frame_points: usize) -> usize {
        frame_points.div_ceil(self.points.max(1)).max(1)
    }

    /// The subset of `items` (a frame's points or rays): every [`Self::stride`]-th, from the
    /// first.
    pub fn subset<T: Copy>(&self, items: &[T]) -> Vec<T> {
        items
            .iter()
            .step_by(self.stride(items.len()))
            .copied()
            .collect()
    }

    /// These coarse layers in a frame of `annealing_layers`: at most all but the last, `None`
    /// when none is left (one layer, say: the plain step weighs every point).
    pub fn within(&self, annealing_layers: usize) -> Option<Self> {
        let layers = self.layers.min(annealing_layers.saturating_sub(1));
        (layers > 0).then_some(Self { layers, ..*self })
    }

    /// Whether annealing layer `layer` (from 0) weighs the subset.
    pub fn is_coarse(&self, layer: usize) -> bool {
        layer < self.layers
    }

    /// The most points the subset holds for frames of at most `max_points`.
    pub fn capacity(&self, max_points: usize) -> usize {
        self.points.min(max_points).max(1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_subset_never_holds_more_than_asked_and_spreads_over_the_frame() {
        let mut state = 0x5eed_u64;
        for _ in 0..200 {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1);
            let frame = (state >> 40) as usize % 50_000;
            let points = 1 + (state >> 20) as usize % 9_000;
            let coarse = CoarseLayers { points, layers: 3 };
            let items: Vec<usize> = (0..frame).collect();
            let subset = coarse.subset(&items);
            assert!(
                subset.len() <= coarse.capacity(frame.max(1)),
                "{frame} {points}"
            );
            if frame <= points {
                assert_eq!(subset, items, "a small frame is weighed whole");
            } else {
                // Every k-th: it starts at the first point and reaches the last stride.
                let k = coarse.stride(frame);
                assert_eq!(subset[0], 0);
                assert!(frame - 1 - subset[subset.len() - 1] < k);
                assert!(subset.windows(2).all(|w| w[1] - w[0] == k));
            }
        }
        assert!(
            CoarseLayers {
                points: 0,
                layers: 1
            }
            .validate()
            .is_err()
        );
        let c = CoarseLayers {
            points: 10,
            layers: 2,
        };
        assert_eq!((c.is_coarse(1), c.is_coarse(2)), (true, false));
        // The last layer always weighs every point.
        assert_eq!(c.within(8), Some(c));
        assert_eq!(c.within(2).map(|c| c.layers), Some(1));
        assert_eq!(c.within(1), None);
        assert_eq!(
            CoarseLayers {
                points: 10,
                layers: 0
            }
            .within(8),
            None
        );
    }
}
