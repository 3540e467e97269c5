//! The cascade laid out for the scan: its trees and leaves in flat arrays (one allocation each,
//! thresholds already widened to f64), and per pyramid level each feature's rectangles as
//! offsets into the level's integral image. The scan visits millions of windows a frame; this
//! is the same arithmetic in the same order as walking [`Cascade`]'s nested vectors by
//! coordinates, so the detections are the same.

use super::cascade::{Cascade, WeightedRect};

/// One tree node: its feature, its threshold, and its children (≤ 0: leaf −child).
struct Node {
    feature: usize,
    threshold: f64,
    left: i32,
    right: i32,
}

/// The cascade's stages, trees and leaves in flat arrays.
pub(super) struct CompiledCascade {
    /// Per stage: its threshold and its trees `trees[first..end]`.
    stages: Vec<(f64, usize, usize)>,
    /// Per tree: its first node in `nodes` and its first leaf in `leaves`.
    trees: Vec<(usize, usize)>,
    nodes: Vec<Node>,
    leaves: Vec<f64>,
}

impl CompiledCascade {
    pub fn new(cascade: &Cascade) -> Self {
        let (mut stages, mut trees, mut nodes, mut leaves) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for stage in &cascade.stages {
            let first = trees.len();
            for weak in &stage.classifiers {
                trees.push((nodes.len(), leaves.len()));
                nodes.extend(weak.nodes.iter().map(|n| Node {
                    feature: n.feature,
                    threshold: f64::from(n.threshold),
                    left: n.left,
                    right: n.right,
                }));
                leaves.extend(weak.leaves.iter().map(|&l| f64::from(l)));
            }
            stages.push((f64::from(stage.threshold), first, trees.len()));
        }
        Self {
            stages,
            trees,
            nodes,
            leaves,
        }
    }

    /// The first stage whose sum falls below its threshold, `None` when every stage passes (a
    /// face); `feature(f)` is feature f's normalised value at the window.
    pub fn first_failing_stage(&self, feature: impl Fn(usize) -> f64) -> Option<usize> {
        for (s, &(threshold, first, end)) in self.stages.iter().enumerate() {
            let mut total = 0.0f64;
            for &(first_node, first_leaf) in &self.trees[first..end] {
                let mut index = 0i32;
                loop {
                    let node = &self.nodes[first_node + index as usize];
                    index = if feature(node.feature) < node.threshold {
                        node.left
                    } else {
                        node.right
                    };
                    if index <= 0 {
                        break;
                    }
                }
                total += self.leaves[first_leaf + index.unsigned_abs() as usize];
            }
            if total < threshold {
                return Some(s);
            }
        }
        None
    }
}

/// The cascade's features for one pyramid level: each rectangle's four corners as offsets into
/// the level's integral image from a window's corner, so that a rectangle's sum is four loads.
pub(super) struct LevelFeatures {
    /// (top-left, top-right, bottom-left, bottom-right) offsets and the weight, per rectangle.
    rects: Vec<([usize; 4], f64)>,
    /// Feature f's rectangles are `rects[starts[f]..starts[f + 1]]`.
    starts: Vec<usize>,
}

impl LevelFeatures {
    pub fn new(features: &[Vec<WeightedRect>], stride: usize) -> Self {
        let mut rects = Vec::new();
        let mut starts = vec![0];
        for feature in features {
            for r in feature {
                let (x, y, w, h) = (
                    r.x as usize,
                    r.y as usize,
                    r.width as usize,
                    r.height as usize,
                );
                let corners = [
                    y * stride + x,
                    y * stride + x + w,
                    (y + h) * stride + x,
                    (y + h) * stride + x + w,
                ];
                rects.push((corners, f64::from(r.weight)));
            }
            starts.push(rects.len());
        }
        Self { rects, starts }
    }

    /// Feature `f`'s weighted sum for the window whose corner is at `origin` in `integral`.
    pub fn value(&self, f: usize, integral: &[i64], origin: usize) -> f64 {
        self.rects[self.starts[f]..self.starts[f + 1]]
            .iter()
            .map(|&([tl, tr, bl, br], weight)| {
                let at = |corner: usize| integral[origin + corner];
                weight * (at(br) - at(tr) - at(bl) + at(tl)) as f64
            })
            .sum::<f64>()
    }
}
