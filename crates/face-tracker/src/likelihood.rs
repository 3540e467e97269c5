//! The sparse-template likelihood (eq. 10–13 of the face paper) on the CPU: the reference the GPU
//! kernel is tested against, on one thread (the Fig. 6 baseline) and on all cores.
//!
//! For a particle x and a template {(P, N, J)}: each point that faces the camera is projected to
//! p, the frame is sampled bilinearly there, and κ = (α·I(p) − J)/J; ε = (1/N) Σ ρ(κ) with
//! ρ(κ) = κ²/(κ² + 1) over the N points that face the camera. A point that projects outside the
//! frame counts with ρ = 1, the largest value ρ takes, so a face leaving the frame loses weight.
//! A pose that shows less than [`MIN_VISIBLE_SHARE`] of the template's points has ε = 1: the
//! paper skips self-occluded points, and without this floor a face turned edge-on, showing a
//! handful of points that match by chance, would outweigh the true pose. The paper's weight is π ∝ 1/ε; the tracker allows
//! π ∝ ε^−γ (γ, the sharpness, is 1 in the paper), so log π = −γ·ln ε, ε floored at
//! [`MIN_ERROR`].

use nalgebra::Vector3;
use rayon::prelude::*;

use crate::image::GrayImage;
use crate::projection::{DIMS, Pose};
use crate::template::Template;

/// The floor of ε, so that a perfect match has a finite weight.
pub const MIN_ERROR: f32 = 1e-6;

/// The smallest share of a template's points a pose must show to be weighed (else ε = 1).
pub const MIN_VISIBLE_SHARE: f32 = 0.25;

/// ρ(κ) = κ²/(κ² + 1).
pub fn rho(kappa: f32) -> f32 {
    let k2 = kappa * kappa;
    k2 / (k2 + 1.0)
}

/// ε of one particle, accumulated in f64.
pub fn residual_error(state: &[f32; DIMS], template: &Template, frame: &GrayImage) -> f64 {
    let pose = Pose::new(state);
    let mut sum = 0.0f64;
    let mut count = 0usize;
    for q in &template.points {
        if !pose.faces_camera(&Vector3::from(q.normal)) {
            continue;
        }
        count += 1;
        let p = pose.project(&Vector3::from(q.position));
        sum += match frame.bilinear(p.x, p.y) {
            Some(i) => f64::from(rho((pose.alpha * i - q.gray) / q.gray)),
            None => 1.0,
        };
    }
    if count == 0 || (count as f32) < MIN_VISIBLE_SHARE * template.points.len() as f32 {
        1.0
    } else {
        sum / count as f64
    }
}

/// log π = −γ·ln max(ε, [`MIN_ERROR`]).
pub fn log_weight(error: f64, sharpness: f32) -> f32 {
    (-f64::from(sharpness) * error.max(f64::from(MIN_ERROR)).ln()) as f32
}

/// ε for every particle on one thread: the paper's CPU baseline (Fig. 6).
pub fn weigh_single_thread(
    states: &[[f32; DIMS]],
    template: &Template,
    frame: &GrayImage,
) -> Vec<f64> {
    states
        .iter()
        .map(|s| residual_error(s, template, frame))
        .collect()
}

/// The same on all cores.
pub fn weigh_parallel(states: &[[f32; DIMS]], template: &Template, frame: &GrayImage) -> Vec<f64> {
    states
        .par_iter()
        .map(|s| residual_error(s, template, frame))
        .collect()
}
