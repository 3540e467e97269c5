use face_tracker::extraction::{ExtractionConfig, extract_template};
use face_tracker::likelihood::residual_error;
use face_tracker::model::FaceModel;
use face_tracker::synth::{FaceSynthConfig, face_state, initial_rect, render_frame};
use rayon::prelude::*;
fn main() {
    let config = FaceSynthConfig {
        faces: 16,
        half_width: 30.0,
        occlusion: false,
        ..FaceSynthConfig::paper(2)
    };
    let model = FaceModel::generic(129).unwrap();
    let frame = render_frame(&config, &model, 0).unwrap();
    let templates: Vec<_> = (0..64)
        .map(|k| {
            extract_template(
                &frame,
                &initial_rect(&config, k % 16),
                &model,
                &ExtractionConfig::default(),
            )
            .unwrap()
        })
        .collect();
    let states: Vec<_> = (0..64).map(|k| face_state(&config, k % 16, 0)).collect();
    for _ in 0..3 {
        let t = std::time::Instant::now();
        let n = 200;
        let mut s = 0.0;
        for _ in 0..n {
            let v: Vec<f64> = (0..64)
                .into_par_iter()
                .map(|k| residual_error(&states[k], &templates[k], &frame))
                .collect();
            s += v[0];
        }
        let par = t.elapsed().as_secs_f64() * 1e6 / n as f64;
        let t = std::time::Instant::now();
        for _ in 0..n {
            let v: Vec<f64> = (0..64)
                .map(|k| residual_error(&states[k], &templates[k], &frame))
                .collect();
            s += v[0];
        }
        let seq = t.elapsed().as_secs_f64() * 1e6 / n as f64;
        println!("par {par:.1} us, one thread {seq:.1} us ({s})");
    }
}
