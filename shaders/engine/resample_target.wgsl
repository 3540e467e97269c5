// Resampling one target in one workgroup of 256 invocations (SCAN_WG): the ancestors of the
// target's M offspring from its normalised weights, by a parallel prefix sum into the CDF (set_cdf) and a
// binary search per offspring (systematic: one uniform per target; stratified: one per offspring).
// A library: the including kernel declares params, stats and resample_keys, and where the weights,
// the CDF and the ancestors live: weight_at(base, i), cdf_at(base, i), set_cdf(base, i, value) and
// set_ancestor(base, k, ancestor) (resample.wgsl: the storage buffers, for the resample stage;
// layer.wgsl: workgroup memory, whose latency is a fraction of a storage buffer's, for the fused
// layer, where one workgroup's serial chain of loads is the layer's time).
// CPU twins: pf_core::resample::{Systematic, Stratified} fed CounterUniforms with the target's
// resampling key.

const SCAN_WG: u32 = 256u;
// The invocations' chunk sums, scanned Hillis-Steele reading one half while writing the other:
// one barrier a step, where an in-place scan needs two (its barriers are most of its time when
// one target's workgroup runs alone on its SM).
var<workgroup> chunk_scan: array<array<f32, 256>, 2>;
var<workgroup> due: u32;

fn resampling_due(t: u32) -> bool {
    return stats[t].ess < params.ess_threshold * f32(params.particles);
}

// The CDF is summed in parallel, so rounding can leave a zero-weight particle a hair above its
// predecessor (or a point a hair past the end); the search would then pick a particle that must
// never be picked. Move to the nearest positive weight: forward first, then backward.
fn positive_weight_near(base: u32, i: u32, n: u32) -> u32 {
    for (var j = i; j < n; j = j + 1u) {
        if (weight_at(base, j) > 0.0) {
            return j;
        }
    }
    var j = i;
    while (j > 0u && !(weight_at(base, j) > 0.0)) {
        j = j - 1u;
    }
    return j;
}

// The uniform of offspring k: one per target (systematic) or one per offspring (stratified).
fn ordered_uniform(t: u32, k: u32, stratified: bool) -> f32 {
    var particle = 0u;
    if (stratified) {
        particle = k;
    }
    let block = philox4x32_10(vec4<u32>(particle, 0u, params.step_lo, params.step_hi), resample_keys[t]);
    return unit_from_word(block.x);
}

// The smallest i with point < cdf_at(base, i) (n - 1 when none), moved to a positive weight.
fn search_cdf(base: u32, n: u32, point: f32) -> u32 {
    var lo = 0u;
    var hi = n - 1u;
    while (lo < hi) {
        let mid = (lo + hi) / 2u;
        if (cdf_at(base, mid) <= point) {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    return positive_weight_near(base, lo, n);
}

fn prefix_sum_and_search(lid: u32, t: u32, stratified: bool) {
    let n = params.particles;
    let base = t * n;
    if (lid == 0u) {
        due = select(0u, 1u, resampling_due(t));
        stats[t].resampled = due;
    }
    workgroupBarrier();
    if (workgroupUniformLoad(&due) == 0u) {
        for (var k = lid; k < n; k = k + SCAN_WG) {
            set_ancestor(base, k, k);
        }
        return;
    }
    // Chunk sums, then an inclusive scan over the 256 chunks.
    let chunk = (n + SCAN_WG - 1u) / SCAN_WG;
    let begin = min(lid * chunk, n);
    let end = min(begin + chunk, n);
    var sum = 0.0;
    for (var i = begin; i < end; i = i + 1u) {
        sum = sum + weight_at(base, i);
    }
    chunk_scan[0][lid] = sum;
    workgroupBarrier();
    var source = 0u;
    for (var offset = 1u; offset < SCAN_WG; offset = offset * 2u) {
        var scanned = chunk_scan[source][lid];
        if (lid >= offset) {
            scanned = scanned + chunk_scan[source][lid - offset];
        }
        chunk_scan[1u - source][lid] = scanned;
        workgroupBarrier();
        source = 1u - source;
    }
    var running = 0.0;
    if (lid > 0u) {
        running = chunk_scan[source][lid - 1u];
    }
    let total = chunk_scan[source][SCAN_WG - 1u];
    for (var i = begin; i < end; i = i + 1u) {
        running = running + weight_at(base, i);
        set_cdf(base, i, running);
    }
    storageBarrier();
    workgroupBarrier();

    // Systematic resampling's one uniform, drawn once per invocation (a Philox block each).
    var systematic_uniform = 0.0;
    if (!stratified) {
        systematic_uniform = ordered_uniform(t, 0u, false);
    }
    for (var k = lid; k < n; k = k + SCAN_WG) {
        var uniform = systematic_uniform;
        if (stratified) {
            uniform = ordered_uniform(t, k, true);
        }
        let point = (f32(k) + uniform) / f32(n) * total;
        set_ancestor(base, k, search_cdf(base, n, point));
    }
}
