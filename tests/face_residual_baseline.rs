//! The benchmarks' plain C loop (benches/baseline/face_residual.c) computes the same ε as the
//! CPU reference, so that the speed comparison in `face_tracking`'s Fig. 6 group is of the same
//! work: fresh random poses, frames and templates, points off the frame and faces turned away
//! included.

#[path = "../benches/baseline/mod.rs"]
mod baseline;

use face_tracker::image::GrayImage;
use face_tracker::likelihood::residual_error;
use face_tracker::template::{FeaturePoint, Template};
use proptest::prelude::*;

fn unit(v: [f32; 3]) -> [f32; 3] {
    let len = v.iter().map(|c| c * c).sum::<f32>().sqrt().max(1e-3);
    v.map(|c| c / len)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]
    #[test]
    fn the_c_baseline_computes_the_reference_residual(
        (width, height) in (2u32..80, 2u32..60),
        seed in any::<u64>(),
        points in prop::collection::vec(
            (prop::array::uniform3(-40.0f32..40.0), prop::array::uniform3(-1.0f32..1.0), 1.0f32..255.0),
            1..120,
        ),
        tx in -20.0f32..100.0, ty in -20.0f32..80.0, scale in 0.3f32..2.0,
        angles in prop::array::uniform3(-1.6f32..1.6), alpha in 0.5f32..1.5,
    ) {
        let mut state_rng = seed;
        let pixels: Vec<u8> = (0..width * height)
            .map(|_| (pf_core::random::splitmix64({ state_rng += 1; state_rng }) >> 56) as u8)
            .collect();
        let frame = GrayImage::new(width, height, pixels).unwrap();
        let template = Template::new(
            points
                .into_iter()
                .map(|(p, n, j)| FeaturePoint::new(p, unit([n[0], n[1], n[2] + 1e-2]), j))
                .collect(),
        )
        .unwrap();
        let state = [tx, ty, scale, angles[0], angles[1], angles[2], alpha];
        let reference = residual_error(&state, &template, &frame);
        let plain_c = baseline::face_residual_c(&state, &template, &frame);
        // Agreement to rounding (the rotation's sines and cosines come from different libraries;
        // 2 000 cases passed at this bound).
        prop_assert!(
            (reference - plain_c).abs() <= 1e-4,
            "reference {reference}, C {plain_c}"
        );
    }
}
