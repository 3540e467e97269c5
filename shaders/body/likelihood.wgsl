// The ray-cast capsule likelihood of the body paper on the GPU: M_j = sum_i (min_k d_ik)^2 for
// every sample j, with d_ik the truncated distance (eq. 6) between point i's depth and the first
// hit of its camera ray on capsule k (Appendix A). Launcher:
// body_tracker::likelihood::gpu::CapsuleLikelihoodGpu.
//
// Layouts (plain, see body_tracker::likelihood::gpu): capsules[(j * K + k) * 2] = (a.xyz, r) and
// [.. + 1] = (b.xyz, 0); rays[i] = (unit direction from the camera origin, depth), for the fast
// kernel in levels of whole tiles (level 0 every point, later levels subsets; a dispatch weighs
// the level whose tiles start at first_tile); partials[j * tiles + tile]; sums[j]. Samples j = sample_offset + workgroup_id.y, so that any J fits the
// adapter's dispatch limit (the launcher dispatches sample tiles).
//
// Two kernels with the grid of the paper (point tile x sample; capsules and points staged in
// workgroup memory; partial sums per tile, then a reduction kernel):
// - paper_layout: every (point, capsule) pair solves the quadratics from a, b, r (Listing 1.2's
//   arithmetic);
// - fast: capsule_terms first computes each capsule's per-sample terms once (axis, length, and
//   every camera-origin term of P_c, P_a, P_b, since every ray starts at the camera), then each
//   pair tests the capsule's bounding sphere before any quadratic: a ray that misses it, or meets
//   it only farther than tau from the point's depth, has d = tau without solving anything.
// CPU twin: body_tracker::likelihood::listing_1_2.

struct CapsuleParams {
    samples: u32,
    points: u32,
    capsules: u32,
    tiles: u32,
    sample_offset: u32,
    // The fast kernel's first tile of the level it weighs (its rays and cones start there).
    first_tile: u32,
    _pad1: u32,
    _pad2: u32,
    origin: vec3<f32>,
    tau: f32,
}

// Per (sample, capsule): everything about the capsule that does not depend on the ray.
struct CapsuleTerms {
    // Unit axis u and length L (u = 0 for a zero-length bone).
    axis: vec4<f32>,
    // w_perp, the part of w = p - a orthogonal to the axis, and w.u. The cylinder's q1 is
    // v_perp.w_perp = v.w_perp: one dot product, and no cancellation (v.w - (v.u)(w.u) loses
    // digits for bones that point at the camera).
    w_perp: vec4<f32>,
    // w = p - a (sphere a); w unused.
    wa: vec4<f32>,
    // p - b (sphere b); w unused.
    wb: vec4<f32>,
    // p - c for the bounding sphere's centre c = (a + b) / 2, and |p - c|^2 - R^2, R = L/2 + r.
    wc: vec4<f32>,
    // x: r^2, negated when the camera lies inside the infinite cylinder (the cylinder's
    // q0 = |w_perp|^2 - r^2 <= 0: the same for every ray, read with the terms a pair needs
    // anyway) or the bone has no length; yzw: n = w_perp x u, whose dot with the ray's direction gives the cylinder's
    // discriminant as q2 r^2 - (dir.n)^2 (see first_nonnegative_root) in one dot product.
    q0: vec4<f32>,
}

@group(0) @binding(0) var<uniform> cp: CapsuleParams;
@group(0) @binding(1) var<storage, read> capsules: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> rays: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> partials: array<f32>;
@group(0) @binding(4) var<storage, read_write> terms: array<CapsuleTerms>;
@group(0) @binding(5) var<storage, read_write> sums: array<f32>;
// Per fast tile: the cone holding its rays, (unit axis, half-angle); computed by the launcher
// when the rays are uploaded.
@group(0) @binding(6) var<storage, read> tile_cones: array<vec4<f32>>;

const TILE: u32 = 256u;
const MAX_CAPSULES: u32 = 128u;
const NO_HIT: f32 = -1.0;
const PI_F: f32 = 3.14159265358979;

var<workgroup> staged_capsules: array<vec4<f32>, 256>;
var<workgroup> staged_rays: array<vec4<f32>, 256>;
var<workgroup> staged_terms: array<CapsuleTerms, 128>;
var<workgroup> partial_sum: array<f32, 256>;
var<workgroup> candidates: array<u32, 128>;
var<workgroup> candidate_count: atomic<u32>;

// The smallest root >= 0 of q2 D^2 + 2 q1 D + q0 = 0, or NO_HIT, given its discriminant
// disc = q1^2 - q2 q0 computed without that subtraction, which loses most of f32's digits near a
// silhouette: q2 r^2 - (dir.(w_perp x u))^2 for the cylinder (|v_perp x w_perp|^2 by Lagrange's
// identity, and v_perp x w_perp is along u), r^2 - |dir x w|^2 for a sphere (the CPU twin is
// body_tracker::capsule::first_nonnegative_root).
fn first_nonnegative_root(q2: f32, q1: f32, disc: f32) -> f32 {
    if (disc < 0.0) {
        return NO_HIT;
    }
    let s = sqrt(disc);
    let near = (-q1 - s) / q2;
    if (near >= 0.0) {
        return near;
    }
    let far = (-q1 + s) / q2;
    if (far >= 0.0) {
        return far;
    }
    return NO_HIT;
}

fn keep_nearest(best: f32, hit: f32) -> f32 {
    if (hit < 0.0) {
        return best;
    }
    if (best < 0.0) {
        return hit;
    }
    return min(best, hit);
}

fn truncated(hit: f32, depth: f32) -> f32 {
    if (hit < 0.0) {
        return cp.tau;
    }
    return min(abs(hit - depth), cp.tau);
}

// Appendix A from a, b, r, as the CPU's ray_capsule.
fn ray_capsule(dir: vec3<f32>, a: vec3<f32>, b: vec3<f32>, r: f32) -> f32 {
    let axis = b - a;
    let len = length(axis);
    var best = NO_HIT;
    if (len > 0.0) {
        let u = axis / len;
        let w = cp.origin - a;
        let v_perp = dir - u * dot(dir, u);
        let w_perp = w - u * dot(w, u);
        let q2 = dot(v_perp, v_perp);
        if (q2 > 0.0) {
            let n = dot(dir, cross(w_perp, u));
            let hit = first_nonnegative_root(q2, dot(v_perp, w_perp), q2 * r * r - n * n);
            if (hit >= 0.0) {
                let along = dot(w + dir * hit, u);
                if (along >= 0.0 && along <= len) {
                    best = keep_nearest(best, hit);
                }
            }
        }
    }
    best = keep_nearest(best, ray_sphere(dir, cp.origin - a, r * r));
    best = keep_nearest(best, ray_sphere(dir, cp.origin - b, r * r));
    return best;
}

// The first hit Δ >= 0 on the sphere of radius^2 r2 about a centre w = origin - centre away,
// or NO_HIT (unit dir).
fn ray_sphere(dir: vec3<f32>, w: vec3<f32>, r2: f32) -> f32 {
    let c = cross(dir, w);
    return first_nonnegative_root(1.0, dot(dir, w), r2 - dot(c, c));
}

// The sum of `value` over the workgroup (valid in every invocation).
fn workgroup_sum(lid: u32, value: f32) -> f32 {
    partial_sum[lid] = value;
    workgroupBarrier();
    for (var stride = TILE / 2u; stride > 0u; stride = stride / 2u) {
        if (lid < stride) {
            partial_sum[lid] = partial_sum[lid] + partial_sum[lid + stride];
        }
        workgroupBarrier();
    }
    return partial_sum[0];
}

fn finish_tile(lid: u32, tile: u32, j: u32, value: f32) {
    let total = workgroup_sum(lid, value);
    if (lid == 0u) {
        partials[j * cp.tiles + tile] = total;
    }
}

@compute @workgroup_size(256)
fn paper_layout(@builtin(local_invocation_id) lid3: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    let lid = lid3.x;
    let tile = wid.x;
    let j = cp.sample_offset + wid.y;
    let i = tile * TILE + lid;
    if (j >= cp.samples) {
        return;
    }
    let k_count = min(cp.capsules, MAX_CAPSULES);
    for (var s = lid; s < 2u * k_count; s = s + TILE) {
        staged_capsules[s] = capsules[j * cp.capsules * 2u + s];
    }
    if (i < cp.points) {
        staged_rays[lid] = rays[i];
    }
    workgroupBarrier();
    var value = 0.0;
    if (i < cp.points) {
        let ray = staged_rays[lid];
        var best = cp.tau;
        for (var k = 0u; k < k_count; k = k + 1u) {
            let a = staged_capsules[2u * k];
            let b = staged_capsules[2u * k + 1u];
            best = min(best, truncated(ray_capsule(ray.xyz, a.xyz, b.xyz, a.w), ray.w));
        }
        value = best * best;
    }
    finish_tile(lid, tile, j, value);
}

// Per-capsule terms, once per (sample, capsule).
@compute @workgroup_size(64)
fn capsule_terms(@builtin(global_invocation_id) gid: vec3<u32>) {
    let flat = gid.x;
    let j = cp.sample_offset + gid.y;
    if (flat >= cp.capsules || j >= cp.samples) {
        return;
    }
    let index = j * cp.capsules + flat;
    let a4 = capsules[index * 2u];
    let b4 = capsules[index * 2u + 1u];
    let a = a4.xyz;
    let b = b4.xyz;
    let r = a4.w;
    let axis = b - a;
    let len = length(axis);
    var u = vec3<f32>(0.0);
    if (len > 0.0) {
        u = axis / len;
    }
    let w = cp.origin - a;
    let wu = dot(w, u);
    let wb = cp.origin - b;
    let c = 0.5 * (a + b);
    let wc = cp.origin - c;
    // A hair larger than L/2 + r, so that rounding never culls a capsule the ray touches.
    let big_r = (0.5 * len + r) * 1.0001 + 1e-6;
    let w_perp = w - u * wu;
    var t: CapsuleTerms;
    t.axis = vec4<f32>(u, len);
    t.w_perp = vec4<f32>(w_perp, wu);
    t.wa = vec4<f32>(w, 0.0);
    t.wb = vec4<f32>(wb, 0.0);
    t.wc = vec4<f32>(wc, dot(wc, wc) - big_r * big_r);
    // A zero-length bone is a sphere: its degenerate axis (u = 0) makes n = 0, which is no
    // cylinder's, so it takes the general branch (which solves only the end spheres there).
    let outside = len > 0.0 && dot(w_perp, w_perp) - r * r > 0.0;
    t.q0 = vec4<f32>(select(-r * r, r * r, outside), cross(w_perp, u));
    terms[index] = t;
}

// Whether the ray can come within tau of its point's depth on the capsule with bounding-sphere
// term wc; if not, d = tau without solving anything.
fn may_matter(dir: vec3<f32>, depth: f32, wc: vec4<f32>) -> bool {
    let qc1 = dot(dir, wc.xyz);
    let disc = qc1 * qc1 - wc.w;
    if (disc < 0.0) {
        return false;
    }
    let s = sqrt(disc);
    let exit = -qc1 + s;
    return !(exit < 0.0 || -qc1 - s > depth + cp.tau || exit < depth - cp.tau);
}

// Appendix A from the precomputed terms of staged capsule k (after may_matter). The terms are
// read from workgroup memory only here, so that a culled pair reads 16 bytes, not 96. Whether
// the camera lies inside the capsule's infinite cylinder is the same for every ray, so the
// branch below does not split a subgroup; outside it (the usual case) at most two roots are
// solved, not three.
fn ray_capsule_fast(dir: vec3<f32>, depth: f32, k: u32) -> f32 {
    let t = staged_terms[k];
    if (t.q0.x > 0.0) {
        return truncated(ray_capsule_outside(dir, t), depth);
    }
    let r2 = abs(t.q0.x);
    var best = NO_HIT;
    let len = t.axis.w;
    if (len > 0.0) {
        let vu = dot(dir, t.axis.xyz);
        let v_perp = dir - t.axis.xyz * vu;
        let q2 = dot(v_perp, v_perp);
        if (q2 > 0.0) {
            let n = dot(dir, t.q0.yzw);
            let hit = first_nonnegative_root(q2, dot(dir, t.w_perp.xyz), q2 * r2 - n * n);
            if (hit >= 0.0) {
                let along = t.w_perp.w + hit * vu;
                if (along >= 0.0 && along <= len) {
                    best = hit;
                }
            }
        }
    }
    best = keep_nearest(best, ray_sphere(dir, t.wa.xyz, r2));
    best = keep_nearest(best, ray_sphere(dir, t.wb.xyz, r2));
    return truncated(best, depth);
}

// The first hit on a capsule whose infinite cylinder does not hold the camera (q0 > 0, the
// same for every ray): the ray's entry into the infinite cylinder if it lies along the segment;
// otherwise the end sphere on the side where it entered, or nothing. A ray that misses the
// infinite cylinder misses the capsule, which lies inside it.
fn ray_capsule_outside(dir: vec3<f32>, t: CapsuleTerms) -> f32 {
    let vu = dot(dir, t.axis.xyz);
    let v_perp = dir - t.axis.xyz * vu;
    let q2 = dot(v_perp, v_perp);
    let q1 = dot(dir, t.w_perp.xyz);
    let n = dot(dir, t.q0.yzw);
    let disc = q2 * t.q0.x - n * n;
    if (disc < 0.0 || q1 >= 0.0 || q2 <= 0.0) {
        return NO_HIT;
    }
    let entry = (-q1 - sqrt(disc)) / q2;
    let along = t.w_perp.w + entry * vu;
    if (along >= 0.0 && along <= t.axis.w) {
        return entry;
    }
    var end = t.wb;
    if (along < 0.0) {
        end = t.wa;
    }
    let s1 = dot(dir, end.xyz);
    let e = cross(dir, end.xyz);
    let s_disc = t.q0.x - dot(e, e);
    if (s_disc < 0.0) {
        return NO_HIT;
    }
    let hit = -s1 - sqrt(s_disc);
    if (hit < 0.0) {
        return NO_HIT;
    }
    return hit;
}

// Points per invocation of the fast kernel (a fast tile is FAST_POINTS * TILE points).
const FAST_POINTS: u32 = 4u;

// Ray i, or a marker (depth -1) past the last point.
fn load_ray(i: u32) -> vec4<f32> {
    if (i < cp.points) {
        return rays[i];
    }
    return vec4<f32>(0.0, 0.0, 1.0, -1.0);
}

// The point's min distance so far, updated with staged capsule k.
fn nearer(ray: vec4<f32>, best: f32, wc: vec4<f32>, k: u32) -> f32 {
    if (ray.w >= 0.0 && may_matter(ray.xyz, ray.w, wc)) {
        return min(best, ray_capsule_fast(ray.xyz, ray.w, k));
    }
    return best;
}

// The point's squared distance (0 for a marker).
fn term(ray: vec4<f32>, best: f32) -> f32 {
    if (ray.w >= 0.0) {
        return best * best;
    }
    return 0.0;
}

@compute @workgroup_size(256)
fn fast(@builtin(local_invocation_id) lid3: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    let lid = lid3.x;
    let tile = wid.x;
    let j = cp.sample_offset + wid.y;
    if (j >= cp.samples) {
        return;
    }
    let k_count = min(cp.capsules, MAX_CAPSULES);
    if (lid == 0u) {
        atomicStore(&candidate_count, 0u);
    }
    workgroupBarrier();
    // Stage the capsules whose bounding sphere meets the tile's cone of rays; the others are at
    // tau from every point of the tile. (Candidate order varies; the min over them does not.)
    let cone = tile_cones[cp.first_tile + tile];
    for (var k = lid; k < k_count; k = k + TILE) {
        let t = terms[j * cp.capsules + k];
        let to_centre = -t.wc.xyz;
        let dist = length(to_centre);
        let radius_sq = dot(t.wc.xyz, t.wc.xyz) - t.wc.w;
        // The sphere meets the cone when the angle to its centre is at most alpha + beta, with
        // sin(beta) = R / dist; compared as cosines (acos is ill-conditioned near 1), with a margin.
        var meets = dist * dist <= radius_sq;
        if (!meets) {
            let sin_beta = sqrt(max(radius_sq, 0.0)) / dist;
            let cos_beta = sqrt(max(1.0 - sin_beta * sin_beta, 0.0));
            let cos_limit = cos(cone.w) * cos_beta - sin(cone.w) * sin_beta;
            let beyond_half_turn = cone.w + asin(min(sin_beta, 1.0)) >= PI_F;
            meets = beyond_half_turn || dot(cone.xyz, to_centre) / dist >= cos_limit - 1e-4;
        }
        if (meets) {
            let slot = atomicAdd(&candidate_count, 1u);
            staged_terms[slot] = t;
        }
    }
    let n_candidates = workgroupUniformLoad(&candidate_count);
    // Points (tile * FAST_POINTS + p) * TILE + lid, p < FAST_POINTS: coalesced loads, and each
    // bounding-sphere term read from workgroup memory serves four points. Four named registers
    // rather than an array, which a compiler may place in (slow) local memory.
    let base = (cp.first_tile + tile) * FAST_POINTS * TILE + lid;
    let ray0 = load_ray(base);
    let ray1 = load_ray(base + TILE);
    let ray2 = load_ray(base + 2u * TILE);
    let ray3 = load_ray(base + 3u * TILE);
    var best0 = cp.tau;
    var best1 = cp.tau;
    var best2 = cp.tau;
    var best3 = cp.tau;
    for (var k = 0u; k < n_candidates; k = k + 1u) {
        let wc = staged_terms[k].wc;
        best0 = nearer(ray0, best0, wc, k);
        best1 = nearer(ray1, best1, wc, k);
        best2 = nearer(ray2, best2, wc, k);
        best3 = nearer(ray3, best3, wc, k);
    }
    let value = term(ray0, best0) + term(ray1, best1) + term(ray2, best2) + term(ray3, best3);
    finish_tile(lid, tile, j, value);
}

// sums[j] = the sum of sample j's tile partials. One workgroup per sample.
@compute @workgroup_size(256)
fn reduce_partials(@builtin(local_invocation_id) lid3: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    let lid = lid3.x;
    let j = cp.sample_offset + wid.y;
    if (j >= cp.samples) {
        return;
    }
    var value = 0.0;
    for (var tile = lid; tile < cp.tiles; tile = tile + TILE) {
        value = value + partials[j * cp.tiles + tile];
    }
    let total = workgroup_sum(lid, value);
    if (lid == 0u) {
        sums[j] = total;
    }
}
