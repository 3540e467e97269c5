//! The scene of the body paper's speed figures (Fig. 5 and 6): stereo points ray-cast onto the
//! standing human, and pose samples around it. Shared by `benches/capsule_likelihood.rs` and
//! `reproduce-figures`, so that the benchmark and the figure measure the same work.

use nalgebra::{Vector3, vector};

use crate::capsule::{Capsule, ray_capsule};
use crate::error::BodyError;
use crate::human::{human_skeleton, standing_pose};
use crate::likelihood::Rays;

/// Distance of the standing body from the camera (m).
const DEPTH: f32 = 3.0;

/// `count` points ray-cast from the camera at the origin onto the standing pose of the default
/// human with `capsules` capsules, with 1 cm depth noise, in raster order (row by row, as a
/// stereo or depth camera delivers them): a grid of pixel directions over the body, the hits
/// kept, then an evenly strided subset of `count`. The grid doubles until it has enough hits.
pub fn raster_cloud(capsules: usize, count: usize) -> Result<Rays, BodyError> {
    if count == 0 {
        return Err(BodyError::InvalidInput(
            "a cloud needs at least one point".into(),
        ));
    }
    let skeleton = human_skeleton(capsules)?;
    let caps = skeleton.capsules(&standing_pose(&skeleton, DEPTH))?;
    let mut rng = pf_core::RandomStreams::new(7).stream(0, pf_core::Stage::Model(0));
    let mut side = 128;
    loop {
        let mut hits = Vec::new();
        for row in 0..side {
            for col in 0..side {
                let x = -0.35 + 0.7 * (col as f32 + 0.5) / side as f32;
                let y = 0.45 - 0.9 * (row as f32 + 0.5) / side as f32;
                let dir = vector![x, y, 1.0].normalize();
                let hit = caps
                    .iter()
                    .filter_map(|c| ray_capsule(&Vector3::zeros(), &dir, c))
                    .fold(f32::INFINITY, f32::min);
                if hit.is_finite() {
                    hits.push(dir * (hit + 0.01 * rng.gaussian_f32()));
                }
            }
        }
        if hits.len() >= count {
            let points: Vec<_> = (0..count).map(|n| hits[n * hits.len() / count]).collect();
            return Rays::through(Vector3::zeros(), &points);
        }
        side *= 2;
    }
}

/// `count` pose samples of the same human: the standing pose with every value perturbed by
/// 0.05 (rad or m), as capsules.
pub fn perturbed_samples(capsules: usize, count: usize) -> Result<Vec<Vec<Capsule>>, BodyError> {
    let skeleton = human_skeleton(capsules)?;
    let base = standing_pose(&skeleton, DEPTH);
    let mut rng = pf_core::RandomStreams::new(8).stream(0, pf_core::Stage::Model(0));
    (0..count)
        .map(|_| {
            let theta: Vec<f32> = base.iter().map(|x| x + 0.05 * rng.gaussian_f32()).collect();
            skeleton.capsules(&theta)
        })
        .collect()
}
