//! Prints the face model's 68 landmarks in 3D, one per line: u and v (model coordinates, the
//! generic head's landmarks, dlib's mean shape placed on the model as `Personaliser` places it),
//! then the photographed head's height there and the generic head's (towards the camera).
//! `tools/fov_from_landmarks.py` reads it.
//!
//!     cargo run --release -p face-tracker --example landmarks_3d > landmarks_3d.txt
//!
//! Takes dlib's model from its default place (Debian's libdlib-data) or the path given.

use std::path::PathBuf;
use std::sync::Arc;

use face_tracker::landmarks::{DEFAULT_PREDICTOR, ShapePredictor};
use face_tracker::model::{generic_height, photographed_height};
use face_tracker::personal::Personaliser;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path = std::env::args()
        .nth(1)
        .map_or_else(|| PathBuf::from(DEFAULT_PREDICTOR), PathBuf::from);
    let predictor = ShapePredictor::load(&path)?;
    let personaliser = Personaliser::new(Arc::new(predictor))?;
    println!("# u v photographed_height generic_height");
    for &[u, v] in personaliser.generic_landmarks() {
        println!(
            "{u} {v} {} {}",
            photographed_height(u, v),
            generic_height(u, v)
        );
    }
    Ok(())
}
