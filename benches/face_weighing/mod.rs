//! The face likelihood alone against the lanes a particle of its packed kernel
//! (`FaceDispatch::Packed { lanes }`): the same fixed particle clouds around each face of the
//! 16-head frame, 1 000 particles a face, weighed as the filter's likelihood stage alone. Under
//! `--bench` it prints the GPU's own time (timestamps, median of 50 submissions) beside
//! criterion's, which includes the submission and the wait.

use criterion::{BenchmarkId, Criterion};
use face_tracker::FaceTrackerConfig;
use face_tracker::extraction::extract_template;
use face_tracker::likelihood::gpu::{FaceDispatch, FaceLikelihoodGpu};
use face_tracker::likelihood::{Lens, MIN_ERROR, MIN_VISIBLE_SHARE};
use face_tracker::projection::DIMS;
use face_tracker::synth::face_state;
use pf_core::batch::{BatchConfig, BatchShape, gaussian_clouds};
use pf_gpu::{GpuContext, GpuFilter, GpuLikelihood, GpuResampler, GpuStage};

/// The particles' spread about each face's true pose (Fig. 6's).
const SIGMA: [f32; DIMS] = [4.0, 4.0, 0.02, 0.05, 0.05, 0.05, 0.02];

pub fn weighing_vs_lanes(c: &mut Criterion, ctx: &GpuContext) {
    let mut group = c.benchmark_group("face_weighing_vs_lanes");
    group.sample_size(10);
    let full = super::full_size();
    let counts: &[usize] = if full { &[1, 16, 64] } else { &[2] };
    let lanes: &[u32] = if full {
        &[4, 8, 16, 32, 64, 128, 256]
    } else {
        &[8, 64]
    };
    let particles = if full { 1000 } else { 50 };
    for &faces in counts {
        let (frame, rects, model, config) = super::scene(faces);
        let extraction = FaceTrackerConfig::default().extraction;
        let templates: Vec<_> = rects
            .iter()
            .map(|r| extract_template(&frame, r, &model, &extraction).unwrap())
            .collect();
        let max_points = templates.iter().map(|t| t.len()).max().unwrap_or(1);
        let shape = BatchShape::new(faces, particles, DIMS).unwrap();
        let mut states = vec![0.0; shape.state_len()];
        for t in 0..faces {
            let one = BatchShape::new(1, particles, DIMS).unwrap();
            let truth = face_state(&config, t % config.faces, 0);
            let cloud = gaussian_clouds(&one, t as u64 + 3, &truth, &SIGMA);
            for d in 0..DIMS {
                for m in 0..particles {
                    states[shape.state_index(t, d, m)] = cloud[one.state_index(0, d, m)];
                }
            }
        }
        let batch = BatchConfig::new(shape, 1, SIGMA.to_vec());
        for &lanes in lanes {
            let mut filter =
                GpuFilter::new(ctx, &batch, GpuResampler::Systematic, &states).unwrap();
            let mut gpu = FaceLikelihoodGpu::new(
                ctx,
                FaceDispatch::Packed { lanes },
                faces,
                max_points,
                frame.width,
                frame.height,
                1.0,
                MIN_ERROR,
                MIN_VISIBLE_SHARE,
                Lens::WEAK,
            )
            .unwrap();
            gpu.upload_frame(ctx, &frame.data).unwrap();
            for (t, template) in templates.iter().enumerate() {
                gpu.upload_template(ctx, t, &template.gpu_layout()).unwrap();
            }
            gpu.prepare(ctx, &filter.likelihood_inputs()).unwrap();
            let mut weigh = || {
                filter
                    .run_stages(ctx, &[GpuStage::Likelihood], &gpu)
                    .unwrap()
            };
            group.bench_function(BenchmarkId::new(format!("{lanes}_lanes"), faces), |b| {
                b.iter(|| std::hint::black_box(weigh()))
            });
            if full {
                let mut own: Vec<f64> = (0..50)
                    .map(|_| weigh().time.duration().as_secs_f64() * 1e6)
                    .collect();
                own.sort_by(f64::total_cmp);
                eprintln!(
                    "face_weighing_vs_lanes/{lanes}_lanes/{faces}: GPU's own time {:.1} us ({max_points} points a face at most)",
                    own[own.len() / 2]
                );
            }
        }
    }
    group.finish();
}
