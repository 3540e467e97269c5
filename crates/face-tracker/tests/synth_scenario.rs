//! The identity scenario of the synthetic video (`FaceSynthConfig::exits_and_crossings`): the
//! first face leaves the picture and comes back to its place, faces 1 and 2 end in each other's
//! place, and face 3 stays.

use face_tracker::projection::{TX, TY};
use face_tracker::synth::{FaceSynthConfig, face_state};

#[test]
fn the_first_face_leaves_and_returns_and_two_faces_cross() {
    for (frames, width, height) in [(90, 640, 480), (300, 1024, 768), (400, 1920, 1080)] {
        let config = FaceSynthConfig {
            width,
            height,
            ..FaceSynthConfig::paper(1)
        }
        .exits_and_crossings(frames);
        config.validate().unwrap();
        let seen: Vec<bool> = (0..frames).map(|f| config.visible(0, f)).collect();
        // In the picture, then out for a stretch, then back in to the end.
        let first_out = seen.iter().position(|v| !v).expect("face 0 never leaves");
        let back = first_out
            + seen[first_out..]
                .iter()
                .position(|v| *v)
                .expect("never back");
        assert!(
            first_out > 0 && back > first_out + 3,
            "{frames}: out {first_out}, back {back}"
        );
        assert!(seen[back..].iter().all(|v| *v), "{frames}: leaves again");
        let start = face_state(&config, 0, 0);
        let end = face_state(&config, 0, frames - 1);
        assert!(
            (end[TX] - start[TX]).abs() < 90.0,
            "face 0 ends near its place"
        );
        // Faces 1 and 2 end in each other's place (within their wobble); face 3 is always in.
        for (k, other) in [(1, 2), (2, 1)] {
            let from = face_state(&config, other, 0);
            let to = face_state(&config, k, frames - 1);
            let apart = ((to[TX] - from[TX]).powi(2) + (to[TY] - from[TY]).powi(2)).sqrt();
            assert!(
                apart < 100.0,
                "{frames}: face {k} is {apart} px from face {other}'s place"
            );
        }
        assert!((0..frames).all(|f| config.visible(3, f)));
    }
}
