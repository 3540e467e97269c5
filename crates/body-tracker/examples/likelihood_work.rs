//! Where the fast capsule kernel's work goes, counted on the host for the benchmark scene of
//! `benches/capsule_likelihood.rs` (the body paper's Fig. 5 and 6): how many capsules survive each
//! tile's cone test (and how many would also survive a test of the tile's depth range ± τ), how
//! many (point, capsule) pairs pass the bounding-sphere test and have their roots solved, and how
//! many of a subgroup's 32 lanes do useful work when any lane solves (the kernel runs a
//! subgroup's lanes in step, so one lane's solve costs all 32).
//!
//! `cargo run --release -p body-tracker --example likelihood_work [SAMPLES] [POINTS]`

use body_tracker::benchmark_scene::{perturbed_samples, raster_cloud};
use body_tracker::capsule::Capsule;
use body_tracker::likelihood::gpu::prepare_rays;
use nalgebra::Vector3;

const K: usize = 48;
const TAU: f32 = 0.1;
const TILE: usize = 256;
const FAST_POINTS: usize = 4;
const SUBGROUP: usize = 32;

/// A capsule's bounding sphere as the kernel's `capsule_terms` gives it: p − c and
/// |p − c|² − R², with the camera p at the origin.
fn bounding_sphere(c: &Capsule) -> (Vector3<f32>, f32) {
    let len = (c.b - c.a).norm();
    let centre = 0.5 * (c.a + c.b);
    let wc = -centre;
    let big_r = (0.5 * len + c.radius) * 1.0001 + 1e-6;
    (wc, wc.norm_squared() - big_r * big_r)
}

/// The kernel's cone test: does the bounding sphere meet the tile's cone of rays?
fn meets_cone(cone: &[f32; 4], wc: &(Vector3<f32>, f32)) -> bool {
    let to_centre = -wc.0;
    let dist = to_centre.norm();
    let radius_sq = wc.0.norm_squared() - wc.1;
    if dist * dist <= radius_sq {
        return true;
    }
    let sin_beta = radius_sq.max(0.0).sqrt() / dist;
    let cos_beta = (1.0 - sin_beta * sin_beta).max(0.0).sqrt();
    let cos_limit = cone[3].cos() * cos_beta - cone[3].sin() * sin_beta;
    let axis = Vector3::new(cone[0], cone[1], cone[2]);
    cone[3] + sin_beta.min(1.0).asin() >= std::f32::consts::PI
        || axis.dot(&to_centre) / dist >= cos_limit - 1e-4
}

/// The kernel's `may_matter`.
fn may_matter(ray: &[f32; 4], wc: &(Vector3<f32>, f32)) -> bool {
    let dir = Vector3::new(ray[0], ray[1], ray[2]);
    let depth = ray[3];
    let qc1 = dir.dot(&wc.0);
    let disc = qc1 * qc1 - wc.1;
    if disc < 0.0 {
        return false;
    }
    let s = disc.sqrt();
    let exit = -qc1 + s;
    !(exit < 0.0 || -qc1 - s > depth + TAU || exit < depth - TAU)
}

#[derive(Default)]
struct Counts {
    tiles: u64,
    candidates: u64,
    pair_tests: u64,
    solves: u64,
    near: u64,
    subgroup_steps: u64,
    subgroup_steps_solving: u64,
    points: u64,
    sphere_hits: u64,
    split_candidates: [u64; 3],
    depth_candidates: u64,
}

/// The bounding spheres of a capsule cut into `pieces` equal lengths.
fn piece_spheres(c: &Capsule, pieces: usize) -> Vec<(Vector3<f32>, f32)> {
    let step = (c.b - c.a) / pieces as f32;
    (0..pieces)
        .map(|n| {
            let a = c.a + step * n as f32;
            bounding_sphere(&Capsule {
                a,
                b: a + step,
                radius: c.radius,
            })
        })
        .collect()
}

fn main() {
    let mut args = std::env::args().skip(1);
    let samples: usize = args.next().and_then(|a| a.parse().ok()).unwrap_or(200);
    let points: usize = args.next().and_then(|a| a.parse().ok()).unwrap_or(43_000);
    let rays = raster_cloud(K, points).expect("the benchmark scene");
    let prepared = prepare_rays(&rays.gpu_layout());
    let ordered = prepared.ordered();
    let cones = prepared.tile_cones();
    let all = perturbed_samples(K, samples).expect("the benchmark samples");
    let mut n = Counts::default();
    for capsules in &all {
        let spheres: Vec<_> = capsules.iter().map(bounding_sphere).collect();
        for (tile, cone) in cones.iter().enumerate() {
            let candidates: Vec<usize> =
                (0..K).filter(|&k| meets_cone(cone, &spheres[k])).collect();
            n.tiles += 1;
            let base = tile * FAST_POINTS * TILE;
            let depths = ordered[base..(base + FAST_POINTS * TILE).min(ordered.len())]
                .iter()
                .filter(|r| r[3] >= 0.0)
                .map(|r| r[3]);
            let (lo, hi) = depths.fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), d| {
                (lo.min(d), hi.max(d))
            });
            n.depth_candidates += candidates
                .iter()
                .filter(|&&k| {
                    let dist = spheres[k].0.norm();
                    let big_r = (spheres[k].0.norm_squared() - spheres[k].1).max(0.0).sqrt();
                    !(dist + big_r < lo - TAU || dist - big_r > hi + TAU)
                })
                .count() as u64;
            n.candidates += candidates.len() as u64;
            for (slot, pieces) in [2usize, 3, 4].into_iter().enumerate() {
                n.split_candidates[slot] += capsules
                    .iter()
                    .filter(|c| piece_spheres(c, pieces).iter().any(|s| meets_cone(cone, s)))
                    .count() as u64;
            }
            for &k in &candidates {
                let capsule = std::slice::from_ref(&capsules[k]);
                for p in 0..FAST_POINTS {
                    for lanes in (0..TILE).step_by(SUBGROUP) {
                        let mut any = false;
                        for lane in lanes..lanes + SUBGROUP {
                            let ray = &ordered[base + p * TILE + lane];
                            if ray[3] < 0.0 {
                                continue;
                            }
                            n.pair_tests += 1;
                            let dir = Vector3::new(ray[0], ray[1], ray[2]);
                            let qc1 = dir.dot(&spheres[k].0);
                            if qc1 * qc1 >= spheres[k].1 {
                                n.sphere_hits += 1;
                            }
                            if may_matter(ray, &spheres[k]) {
                                n.solves += 1;
                                any = true;
                                let dir = Vector3::new(ray[0], ray[1], ray[2]);
                                let d = body_tracker::capsule::ray_capsule(
                                    &Vector3::zeros(),
                                    &dir,
                                    &capsule[0],
                                )
                                .map_or(TAU, |hit| (hit - ray[3]).abs());
                                if d < TAU {
                                    n.near += 1;
                                }
                            }
                        }
                        n.subgroup_steps += 1;
                        if any {
                            n.subgroup_steps_solving += 1;
                        }
                    }
                }
            }
        }
    }
    n.points = (ordered.iter().filter(|r| r[3] >= 0.0).count() * samples) as u64;
    let per_point = |x: u64| x as f64 / n.points as f64;
    println!("benchmark scene: {samples} samples x {points} points x {K} capsules, tau {TAU} m");
    println!(
        "tiles of {} rays: {} a sample; capsules meeting a tile's cone: {:.1} of {K} on average",
        FAST_POINTS * TILE,
        cones.len(),
        n.candidates as f64 / n.tiles as f64
    );
    println!(
        "the same with each capsule cut in 2 / 3 / 4 pieces, each with its sphere: {:.1} / {:.1} / {:.1}",
        n.split_candidates[0] as f64 / n.tiles as f64,
        n.split_candidates[1] as f64 / n.tiles as f64,
        n.split_candidates[2] as f64 / n.tiles as f64
    );
    println!(
        "capsules meeting a tile's cone and its depth range (+-tau): {:.1}",
        n.depth_candidates as f64 / n.tiles as f64
    );
    println!(
        "per point: {:.2} rays meet the bounding sphere",
        per_point(n.sphere_hits)
    );
    println!(
        "per point: {:.2} bounding-sphere tests, {:.2} pairs solved, {:.2} capsules within tau",
        per_point(n.pair_tests),
        per_point(n.solves),
        per_point(n.near)
    );
    println!(
        "subgroups of {SUBGROUP}: {:.1} % of the steps solve for some lane; in those, {:.1} % of the lanes solve",
        100.0 * n.subgroup_steps_solving as f64 / n.subgroup_steps as f64,
        100.0 * n.solves as f64 / (n.subgroup_steps_solving * SUBGROUP as u64) as f64
    );
}
