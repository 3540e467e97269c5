//! The body paper's likelihood on its figure axes (Fig. 5/6): time against points (I up to
//! 43 000) and against samples (J up to 3 500), K = 48 capsules. Variants: one CPU thread
//! (Listing 1.2), all CPU cores (rayon over samples), and the GPU (the paper's layout and the fast
//! kernel). Throughput is in (sample, point, capsule) pairs per second, so that the CPU runs,
//! which use a sub-sampled J (stated in their names), compare per pair with the GPU's full J.
//! GPU timings include the submission, the wait and the readback of the J sums; the capsules are
//! already on the device (`benches/body_step.rs` times the whole tracker step, forward kinematics
//! on the GPU included). The points come in raster order, as a camera delivers them: neighbouring
//! invocations see neighbouring rays, which is what lets the fast kernel's bounding-sphere test
//! skip work for whole warps.

mod common;

use body_tracker::benchmark_scene::{perturbed_samples, raster_cloud};
use body_tracker::capsule::Capsule;
use body_tracker::likelihood::gpu::{CapsuleKernel, CapsuleLikelihoodGpu};
use body_tracker::likelihood::{Rays, capsules_gpu_layout, listing_1_2, parallel_over_samples};
use common::context;
use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use pf_gpu::GpuContext;

const K: usize = 48;
const TAU: f32 = 0.1;

fn cloud(count: usize) -> Rays {
    raster_cloud(K, count).unwrap()
}

fn samples(count: usize) -> Vec<Vec<Capsule>> {
    perturbed_samples(K, count).unwrap()
}

fn gpu(
    ctx: &GpuContext,
    kind: CapsuleKernel,
    rays: &Rays,
    samples: &[Vec<Capsule>],
) -> CapsuleLikelihoodGpu {
    let g =
        CapsuleLikelihoodGpu::new(ctx, kind, samples.len(), rays.len(), K, [0.0; 3], TAU).unwrap();
    g.upload_rays(ctx, &rays.gpu_layout()).unwrap();
    let mut flat = Vec::new();
    for c in samples {
        capsules_gpu_layout(c, &mut flat);
    }
    g.upload_capsules(ctx, &flat).unwrap();
    g
}

fn run_axis(c: &mut Criterion, ctx: &GpuContext, group_name: &str, sizes: &[(usize, usize)]) {
    let mut group = c.benchmark_group(group_name);
    group.sample_size(10);
    let all = samples(3500);
    for &(j, i) in sizes {
        let rays = cloud(i);
        let label = if group_name.ends_with("points") { i } else { j };
        for (name, kind) in [
            ("gpu_paper_layout", CapsuleKernel::PaperLayout),
            ("gpu_fast", CapsuleKernel::Fast),
        ] {
            let g = gpu(ctx, kind, &rays, &all[..j]);
            group.throughput(Throughput::Elements((j * i * K) as u64));
            group.bench_function(BenchmarkId::new(name, label), |b| {
                b.iter(|| std::hint::black_box(g.evaluate(ctx).unwrap()))
            });
        }
        // CPU: sub-sampled J, same per-pair work.
        let j_cores = (j / 50).max(16).min(j);
        group.throughput(Throughput::Elements((j_cores * i * K) as u64));
        group.bench_function(
            BenchmarkId::new(format!("cpu_all_cores_j{j_cores}"), label),
            |b| b.iter(|| std::hint::black_box(parallel_over_samples(&all[..j_cores], &rays, TAU))),
        );
        let j_one = 2.min(j);
        group.throughput(Throughput::Elements((j_one * i * K) as u64));
        group.bench_function(
            BenchmarkId::new(format!("cpu_one_thread_listing_1_2_j{j_one}"), label),
            |b| b.iter(|| std::hint::black_box(listing_1_2(&all[..j_one], &rays, TAU))),
        );
    }
    group.finish();
}

/// `cargo bench` passes `--bench`; under `cargo test --benches` (CI, on a software adapter) each
/// benchmark runs once, so the sizes shrink by 100 to keep that a smoke test.
fn scale(n: usize) -> usize {
    if std::env::args().any(|a| a == "--bench") {
        n
    } else {
        (n / 100).max(1)
    }
}

/// The per-frame host cost of the fast kernel's ray upload (Morton sort, tile cones, queue write).
fn bench_upload(c: &mut Criterion, ctx: &GpuContext) {
    let mut group = c.benchmark_group("capsules_upload_rays");
    group.sample_size(20);
    let i = scale(43_000);
    let rays = cloud(i).gpu_layout();
    let g = CapsuleLikelihoodGpu::new(ctx, CapsuleKernel::Fast, 1, i, K, [0.0; 3], TAU).unwrap();
    group.throughput(Throughput::Elements(i as u64));
    group.bench_function(BenchmarkId::new("fast", i), |b| {
        b.iter(|| g.upload_rays(ctx, &rays).unwrap())
    });
    // The host's share alone: the Morton order and the tile cones.
    group.bench_function(BenchmarkId::new("host_preparation", i), |b| {
        b.iter(|| std::hint::black_box(body_tracker::likelihood::gpu::prepare_rays(&rays)))
    });
    group.finish();
}

fn bench(c: &mut Criterion) {
    let ctx = context();
    bench_upload(c, &ctx);
    let points = [1000, 5000, 10_000, 20_000, 43_000].map(|i| (scale(3500), scale(i)));
    let samples = [100, 500, 1000, 2000, 3500].map(|j| (scale(j), scale(43_000)));
    run_axis(c, &ctx, "capsules_vs_points", &points);
    run_axis(c, &ctx, "capsules_vs_samples", &samples);
}

criterion_group!(benches, bench);
criterion_main!(benches);
