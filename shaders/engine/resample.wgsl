// Resampling per target on the GPU, from normalised weights to ancestor indices, then the gather
// of the ancestors' states. A target resamples only when stats[t].ess < ess_threshold * M;
// otherwise its ancestors are the identity.
//
// - systematic / stratified: one workgroup per target; a parallel prefix sum of the weights
//   (each invocation scans a contiguous chunk, a workgroup scan joins the chunks) into cdf[], then
//   a binary search per offspring for the smallest i with point * total < cdf[i].
//   For more than 4096 particles per target the driver uses a device-wide scan instead, in four
//   dispatches: block_sums (one workgroup per 1024 weights), scan_block_sums (one workgroup per
//   target), block_cdf (each block's inclusive scan plus its offset) and search_* (one invocation
//   per offspring).
// - metropolis: one invocation per (offspring, target), B steps, no collective operation.
// CPU twins: pf_core::resample::{Systematic, Stratified, Metropolis} fed CounterUniforms with the
// target's resampling key (as pf_core::batch::BatchFilter does).

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> weights: array<f32>;
@group(0) @binding(2) var<storage, read_write> cdf: array<f32>;
@group(0) @binding(3) var<storage, read_write> ancestors: array<u32>;
@group(0) @binding(4) var<storage, read_write> stats: array<TargetStats>;
@group(0) @binding(5) var<storage, read> resample_keys: array<vec2<u32>>;
@group(0) @binding(6) var<storage, read_write> block_sums: array<f32>;

const WG: u32 = 256u;

// Where prefix_sum_and_search (resample_target.wgsl) keeps the weights, the CDF and the
// ancestors: this stage's storage buffers.
fn weight_at(base: u32, i: u32) -> f32 {
    return weights[base + i];
}

fn cdf_at(base: u32, i: u32) -> f32 {
    return cdf[base + i];
}

fn set_cdf(base: u32, i: u32, value: f32) {
    cdf[base + i] = value;
}

fn set_ancestor(base: u32, k: u32, ancestor: u32) {
    ancestors[base + k] = ancestor;
}

@compute @workgroup_size(256)
fn systematic(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    prefix_sum_and_search(lid.x, wid.y, false);
}

@compute @workgroup_size(256)
fn stratified(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    prefix_sum_and_search(lid.x, wid.y, true);
}

@compute @workgroup_size(64)
fn metropolis(@builtin(global_invocation_id) gid: vec3<u32>) {
    let k = gid.x;
    let t = gid.y;
    let n = params.particles;
    if (k >= n || t >= params.targets) {
        return;
    }
    let base = t * n;
    let is_due = resampling_due(t);
    if (!is_due) {
        ancestors[base + k] = k;
        return;
    }
    var current = k;
    var block = vec4<u32>(0u);
    for (var b = 0u; b < params.metropolis_steps; b = b + 1u) {
        if ((b & 1u) == 0u) {
            block = philox4x32_10(vec4<u32>(k, b / 2u, params.step_lo, params.step_hi), resample_keys[t]);
        }
        var index_word = block.x;
        var accept_word = block.y;
        if ((b & 1u) == 1u) {
            index_word = block.z;
            accept_word = block.w;
        }
        let proposal = uniform_index(index_word, n);
        let u = unit_from_word(accept_word);
        if (u * weights[base + current] < weights[base + proposal]) {
            current = proposal;
        }
    }
    ancestors[base + k] = current;
}

// Marks whether the target resamples this step, for the Metropolis path (whose invocations do
// not share a workgroup per target). One invocation per target.
@compute @workgroup_size(64)
fn mark_resampled(@builtin(global_invocation_id) gid: vec3<u32>) {
    let t = gid.x;
    if (t < params.targets) {
        stats[t].resampled = select(0u, 1u, resampling_due(t));
    }
}

// ---- device-wide scan for large targets ---------------------------------------------------------

const BLOCK: u32 = 1024u;
var<workgroup> block_partial: array<f32, 256>;

fn blocks_per_target() -> u32 {
    return (params.particles + BLOCK - 1u) / BLOCK;
}

// Inclusive Hillis-Steele scan of block_partial across the workgroup.
fn scan_block_partial(lid: u32) {
    workgroupBarrier();
    for (var offset = 1u; offset < WG; offset = offset * 2u) {
        var add = 0.0;
        if (lid >= offset) {
            add = block_partial[lid - offset];
        }
        workgroupBarrier();
        block_partial[lid] = block_partial[lid] + add;
        workgroupBarrier();
    }
}

// The weight of element i of target t, or 0 past the end.
fn weight_or_zero(t: u32, i: u32) -> f32 {
    if (i < params.particles) {
        return weights[t * params.particles + i];
    }
    return 0.0;
}

@compute @workgroup_size(256)
fn block_sums_kernel(@builtin(local_invocation_id) lid3: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    let lid = lid3.x;
    let b = wid.x;
    let t = wid.y;
    let first = b * BLOCK + lid * 4u;
    block_partial[lid] = weight_or_zero(t, first) + weight_or_zero(t, first + 1u)
        + weight_or_zero(t, first + 2u) + weight_or_zero(t, first + 3u);
    scan_block_partial(lid);
    if (lid == WG - 1u) {
        block_sums[t * blocks_per_target() + b] = block_partial[lid];
    }
}

// Turns each target's block sums into exclusive offsets, in place.
@compute @workgroup_size(256)
fn scan_block_sums(@builtin(local_invocation_id) lid3: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    let lid = lid3.x;
    let t = wid.y;
    let nb = blocks_per_target();
    let base = t * nb;
    let chunk = (nb + WG - 1u) / WG;
    let begin = min(lid * chunk, nb);
    let end = min(begin + chunk, nb);
    var sum = 0.0;
    for (var i = begin; i < end; i = i + 1u) {
        sum = sum + block_sums[base + i];
    }
    block_partial[lid] = sum;
    scan_block_partial(lid);
    var running = 0.0;
    if (lid > 0u) {
        running = block_partial[lid - 1u];
    }
    for (var i = begin; i < end; i = i + 1u) {
        let value = block_sums[base + i];
        block_sums[base + i] = running;
        running = running + value;
    }
}

@compute @workgroup_size(256)
fn block_cdf(@builtin(local_invocation_id) lid3: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    let lid = lid3.x;
    let b = wid.x;
    let t = wid.y;
    let first = b * BLOCK + lid * 4u;
    let w0 = weight_or_zero(t, first);
    let w1 = weight_or_zero(t, first + 1u);
    let w2 = weight_or_zero(t, first + 2u);
    let w3 = weight_or_zero(t, first + 3u);
    block_partial[lid] = w0 + w1 + w2 + w3;
    scan_block_partial(lid);
    var running = block_sums[t * blocks_per_target() + b];
    if (lid > 0u) {
        running = running + block_partial[lid - 1u];
    }
    let base = t * params.particles;
    let values = array<f32, 4>(w0, w1, w2, w3);
    for (var j = 0u; j < 4u; j = j + 1u) {
        running = running + values[j];
        if (first + j < params.particles) {
            cdf[base + first + j] = running;
        }
    }
}

fn search_offspring(k: u32, t: u32, stratified: bool) {
    let n = params.particles;
    if (k >= n || t >= params.targets) {
        return;
    }
    let base = t * n;
    if (!resampling_due(t)) {
        ancestors[base + k] = k;
        return;
    }
    let total = cdf[base + n - 1u];
    let point = (f32(k) + ordered_uniform(t, k, stratified)) / f32(n) * total;
    ancestors[base + k] = search_cdf(base, n, point);
}

@compute @workgroup_size(64)
fn search_systematic(@builtin(global_invocation_id) gid: vec3<u32>) {
    search_offspring(gid.x, gid.y, false);
}

@compute @workgroup_size(64)
fn search_stratified(@builtin(global_invocation_id) gid: vec3<u32>) {
    search_offspring(gid.x, gid.y, true);
}
