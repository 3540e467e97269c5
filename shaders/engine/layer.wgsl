// One annealing layer's selection and moving in two dispatches. `select_*`: one workgroup (256
// invocations) per target normalises the previous layer's weights (normalise_target; layers after
// the first), resamples (prefix_sum_and_search) and gathers the ancestors' states into `selected`.
// `move_selected`: one invocation per particle and pair of dimensions, across the whole GPU, moves
// the particles from `selected` back into `states` (moved_by), drawing each pair of dimensions'
// noise from one Philox block; `copy_selected` copies them back unmoved (layer 0 of a likelihood with its own
// dynamics, whose Propagate follows). With the likelihood's dispatch after them a layer is three
// dispatches where the staged step records five and a copy (resample, gather, copy, diffuse,
// likelihood, normalise); the driver then settles the last layer (settle_last_layer) and
// estimates.
// Why this shape: one workgroup's serial chain is the layer's time when a frame has few targets
// (the GPU is idle but for it). So the selecting workgroup keeps the resampling in workgroup
// memory (the weights copied in once, the CDF built and searched there; the ancestors are written
// to their buffer for the gather and the lineage) and leaves the random numbers, most of a layer's arithmetic (a Philox block is some
// 350 instructions), to a dispatch that spreads them over every SM.
// The same arithmetic in the same order as the staged stages: the same random numbers, hence
// the same particles. CPU twins: those of the libraries it calls — pf_core::batch::normalise_target,
// pf_core::resample::{Systematic, Stratified}, pf_core::ParticleSet::select,
// pf_core::batch::diffuse.
// Systematic and stratified resampling of at most STAGE_CAPACITY particles a target; the driver
// builds the kernel with STAGE_CAPACITY set to the filter's M (pf_gpu::filter::fused).

// This layer's parameters, and the previous layer's (whose weights select_* normalises; unused
// in layer 0).
@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<uniform> settle_params: Params;
@group(0) @binding(2) var<storage, read_write> log_weights: array<f32>;
@group(0) @binding(3) var<storage, read> log_likelihood: array<f32>;
@group(0) @binding(4) var<storage, read_write> weights: array<f32>;
@group(0) @binding(5) var<storage, read_write> stats: array<TargetStats>;
@group(0) @binding(6) var<storage, read_write> selected: array<f32>;
@group(0) @binding(7) var<storage, read_write> ancestors: array<u32>;
@group(0) @binding(8) var<storage, read> resample_keys: array<vec2<u32>>;
@group(0) @binding(9) var<storage, read_write> states: array<f32>;
@group(0) @binding(10) var<storage, read> sigma: array<f32>;
@group(0) @binding(11) var<storage, read> lower: array<f32>;
@group(0) @binding(12) var<storage, read> upper: array<f32>;
@group(0) @binding(13) var<storage, read> diffusion_keys: array<vec2<u32>>;
@group(0) @binding(14) var<storage, read> velocity: array<f32>;

const STAGE_CAPACITY: u32 = 4096u;
const LAYER_WG: u32 = 256u;
// Whether select_* gathers the ancestors' values into `selected` (false: move_gathering reads
// them itself, from the snapshot the layer before wrote).
override GATHER: bool = true;
// Whether move_gathering also keeps the values it writes in the next layer's snapshot.
override WRITES_SNAPSHOT: bool = false;
// Two snapshots of every target's values, each state_len long, written by the moves of layers
// 0, 1, ... in turn (layer l writes half (l + 1) % 2 and, from layer 1 on, reads half l % 2):
// what move_gathering reads its ancestors from, kept apart from the `states` it writes.
@group(0) @binding(18) var<storage, read_write> snapshots: array<f32>;
// The layer's log-likelihoods while the previous layer settles; then the CDF while the target
// resamples.
var<workgroup> scratch: array<f32, STAGE_CAPACITY>;
// The layer's log-weights while it settles; then its normalised weights.
var<workgroup> local_weights: array<f32, STAGE_CAPACITY>;

// Where normalise_target reads and keeps its values: the copies settle puts in workgroup memory.
// The log-likelihoods stay in `scratch`; `local_weights` holds each particle's log-weight, then
// its tempered log-weight, then its normalised weight (each invocation reads a particle's value
// before it writes the next, and only its own particles', between two reductions' barriers), which
// select_target resamples from without reading `weights` back.
fn prior_at(base: u32, i: u32) -> f32 {
    return local_weights[i];
}

fn likelihood_at(base: u32, i: u32) -> f32 {
    return scratch[i];
}

fn set_tempered(base: u32, i: u32, value: f32) {
    local_weights[i] = value;
}

fn tempered_at(base: u32, i: u32) -> f32 {
    return local_weights[i];
}

fn keep_weight(base: u32, i: u32, w: f32) {
    local_weights[i] = w;
}

// Normalises target t's weights after the layer `p` weighed (its log-weights and log-likelihoods
// first copied into workgroup memory, where every pass reads them).
fn settle(lid: u32, t: u32, p: Params) {
    let n = p.particles;
    let base = t * n;
    // Four particles a step, their loads issued before any store (as gather_selected's): the
    // loads at indices held within the target, the stores only for particles that exist.
    for (var k = lid; k < n; k = k + 4u * LAYER_WG) {
        let ks = vec4<u32>(k, k + LAYER_WG, k + 2u * LAYER_WG, k + 3u * LAYER_WG);
        let at = min(ks, vec4<u32>(n - 1u));
        let lw = vec4<f32>(log_weights[base + at.x], log_weights[base + at.y], log_weights[base + at.z], log_weights[base + at.w]);
        let ll = vec4<f32>(log_likelihood[base + at.x], log_likelihood[base + at.y], log_likelihood[base + at.z], log_likelihood[base + at.w]);
        for (var c = 0u; c < 4u; c = c + 1u) {
            if (ks[c] < n) {
                local_weights[ks[c]] = lw[c];
                scratch[ks[c]] = ll[c];
            }
        }
    }
    workgroupBarrier();
    normalise_target(lid, t, p);
}

// Where prefix_sum_and_search (resample_target.wgsl) keeps the weights, the CDF and the
// ancestors: workgroup memory, and the ancestors' buffer (the gather, the lineage and the tests
// read it).
fn weight_at(base: u32, i: u32) -> f32 {
    return local_weights[i];
}

fn cdf_at(base: u32, i: u32) -> f32 {
    return scratch[i];
}

fn set_cdf(base: u32, i: u32, value: f32) {
    scratch[i] = value;
}

fn set_ancestor(base: u32, k: u32, ancestor: u32) {
    ancestors[base + k] = ancestor;
}

// Normalise (after the first layer), resample, then gather every dimension of target t's
// ancestors into `selected`.
fn select_target(lid: u32, t: u32, stratified: bool) {
    let n = params.particles;
    let base = t * n;
    if (params.layer > 0u) {
        // Leaves the normalised weights in local_weights (keep_weight).
        settle(lid, t, settle_params);
        storageBarrier();
    } else {
        // The last frame's weights.
        for (var k = lid; k < n; k = k + LAYER_WG) {
            local_weights[k] = weights[base + k];
        }
    }
    workgroupBarrier();
    prefix_sum_and_search(lid, t, stratified);
    storageBarrier();
    workgroupBarrier();

    // `due` is prefix_sum_and_search's: whether this target resampled (the gather's equal weights).
    if (workgroupUniformLoad(&due) == 1u) {
        let equal = -log(f32(n));
        for (var k = lid; k < n; k = k + LAYER_WG) {
            log_weights[base + k] = equal;
        }
    }
    if (GATHER) {
        gather_selected(lid, t);
    }
}

// Every dimension of target t's ancestors into `selected`. The ancestors go to workgroup memory
// first (`local_weights`: the weights are not read after the search; each invocation copies the
// ancestors it searched for, its own writes), then the (offspring, dimension) pairs are spread
// over the workgroup four at a time, their four loads issued before any store: one target's
// workgroup is alone on its SM, and a load that waits for the one before is the gather's time.
fn gather_selected(lid: u32, t: u32) {
    let n = params.particles;
    let base = t * n;
    for (var k = lid; k < n; k = k + LAYER_WG) {
        local_weights[k] = bitcast<f32>(ancestors[base + k]);
    }
    workgroupBarrier();
    let pairs = n * params.dims;
    for (var j = lid; j < pairs; j = j + 4u * LAYER_WG) {
        let v0 = ancestor_value(t, n, pairs, j);
        let v1 = ancestor_value(t, n, pairs, j + LAYER_WG);
        let v2 = ancestor_value(t, n, pairs, j + 2u * LAYER_WG);
        let v3 = ancestor_value(t, n, pairs, j + 3u * LAYER_WG);
        put_selected(t, n, pairs, j, v0);
        put_selected(t, n, pairs, j + LAYER_WG, v1);
        put_selected(t, n, pairs, j + 2u * LAYER_WG, v2);
        put_selected(t, n, pairs, j + 3u * LAYER_WG, v3);
    }
}

// Pair j's (offspring j mod n, dimension j / n) value at its ancestor; 0 past the last pair.
fn ancestor_value(t: u32, n: u32, pairs: u32, j: u32) -> f32 {
    if (j >= pairs) {
        return 0.0;
    }
    let a = bitcast<u32>(local_weights[j % n]);
    return states[state_index(t, j / n, a)];
}

fn put_selected(t: u32, n: u32, pairs: u32, j: u32, value: f32) {
    if (j < pairs) {
        selected[state_index(t, j / n, j % n)] = value;
    }
}

// The lineage composed in the select, for a filter that keeps it (pf_gpu::filter::lineage; the
// same values as lineage.wgsl's own dispatches, which the staged step and adapters with fewer
// storage bindings use): the layer before's lineage, this layer's, and each target's restart
// flag, read by layer 0 and cleared there (only this target's workgroup reads it).
@group(0) @binding(15) var<storage, read> lineage_before: array<u32>;
@group(0) @binding(16) var<storage, read_write> lineage_after: array<u32>;
@group(0) @binding(17) var<storage, read_write> restarts: array<u32>;
var<workgroup> restarted: u32;

// Each particle's ancestor among the previous frame's particles after this layer's resampling,
// from the ancestors select_target wrote (each invocation reads its own writes).
fn compose_lineage(lid: u32, t: u32) {
    let n = params.particles;
    let base = t * n;
    if (params.layer > 0u) {
        // Four particles a step, their loads issued before any is used (as settle's): a
        // particle's lineage is two dependent loads, and one particle at a time an invocation
        // waited for eight. A lane past the particles reads particle k (this invocation's own
        // write) and stores nothing.
        for (var k = lid; k < n; k = k + 4u * LAYER_WG) {
            let ks = vec4<u32>(k, k + LAYER_WG, k + 2u * LAYER_WG, k + 3u * LAYER_WG);
            let live = ks < vec4<u32>(n);
            let at = base + select(vec4<u32>(k), ks, live);
            let a = vec4<u32>(ancestors[at.x], ancestors[at.y], ancestors[at.z], ancestors[at.w]);
            let composed = vec4<u32>(lineage_before[base + a.x], lineage_before[base + a.y], lineage_before[base + a.z], lineage_before[base + a.w]);
            for (var c = 0u; c < 4u; c = c + 1u) {
                if (live[c]) {
                    lineage_after[base + ks[c]] = composed[c];
                }
            }
        }
        return;
    }
    if (lid == 0u) {
        restarted = restarts[t];
    }
    let fresh = workgroupUniformLoad(&restarted) != 0u;
    for (var k = lid; k < n; k = k + LAYER_WG) {
        lineage_after[base + k] = select(ancestors[base + k], NO_ANCESTOR, fresh);
    }
    if (lid == 0u) {
        restarts[t] = 0u;
    }
}

@compute @workgroup_size(256)
fn select_systematic_keeping_lineage(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    select_target(lid.x, wid.y, false);
    compose_lineage(lid.x, wid.y);
}

@compute @workgroup_size(256)
fn select_stratified_keeping_lineage(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    select_target(lid.x, wid.y, true);
    compose_lineage(lid.x, wid.y);
}

@compute @workgroup_size(256)
fn select_systematic(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    select_target(lid.x, wid.y, false);
}

@compute @workgroup_size(256)
fn select_stratified(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    select_target(lid.x, wid.y, true);
}

// The start of snapshot half `layer % 2`.
fn snapshot_half(layer: u32) -> u32 {
    return (layer % 2u) * params.targets * params.particles * params.dims;
}

// A move's invocation: dimensions d and d + 1 of particle m of target t, and their Philox
// block (counter_gaussian's draws, computed once a pair).
struct MovedPair {
    live: bool,
    t: u32,
    m: u32,
    d: u32,
    block: vec4<u32>,
}

fn moved_pair(gid: vec3<u32>) -> MovedPair {
    let n = params.particles;
    let t = gid.y;
    let pairs = (params.dims + 1u) / 2u;
    if (gid.x >= n * pairs || t >= params.targets) {
        return MovedPair(false, 0u, 0u, 0u, vec4<u32>(0u));
    }
    let m = gid.x % n;
    let d = 2u * (gid.x / n);
    let step = vec2<u32>(params.step_lo, params.step_hi);
    return MovedPair(true, t, m, d, gaussian_block(diffusion_keys[t], m, d, step));
}

// Dimensions 2j and 2j + 1 of particle m of target t moved from `selected` into `states`, both
// from one Philox block; one invocation per (particle, pair) so that even one target's move
// fills many SMs.
@compute @workgroup_size(64)
fn move_selected(@builtin(global_invocation_id) gid: vec3<u32>) {
    let p = moved_pair(gid);
    if (!p.live) {
        return;
    }
    let i = state_index(p.t, p.d, p.m);
    states[i] = moved_by(p.t, p.d, selected[i], gaussian_of_block(p.block, p.d));
    if (p.d + 1u < params.dims) {
        let j = state_index(p.t, p.d + 1u, p.m);
        states[j] = moved_by(p.t, p.d + 1u, selected[j], gaussian_of_block(p.block, p.d + 1u));
    }
}

// move_selected keeping what it writes in the next layer's snapshot too (layer 0 of a step
// whose later layers gather as they move).
@compute @workgroup_size(64)
fn move_keeping_snapshot(@builtin(global_invocation_id) gid: vec3<u32>) {
    let p = moved_pair(gid);
    if (!p.live) {
        return;
    }
    let kept = snapshot_half(params.layer + 1u);
    let i = state_index(p.t, p.d, p.m);
    let first = moved_by(p.t, p.d, selected[i], gaussian_of_block(p.block, p.d));
    states[i] = first;
    snapshots[kept + i] = first;
    if (p.d + 1u < params.dims) {
        let j = state_index(p.t, p.d + 1u, p.m);
        let second = moved_by(p.t, p.d + 1u, selected[j], gaussian_of_block(p.block, p.d + 1u));
        states[j] = second;
        snapshots[kept + j] = second;
    }
}

// move_selected for a layer after the first whose select did not gather (GATHER false): the
// particle's ancestor read from `ancestors`, its values from the snapshot the layer before
// wrote, and (WRITES_SNAPSHOT, all but the last layer) the moved values kept in the next one.
// The same values as a gather then move_selected; the gather's loads, serial in the select's
// one workgroup, spread over the GPU here.
@compute @workgroup_size(64)
fn move_gathering(@builtin(global_invocation_id) gid: vec3<u32>) {
    let p = moved_pair(gid);
    if (!p.live) {
        return;
    }
    let a = ancestors[p.t * params.particles + p.m];
    let earlier = snapshot_half(params.layer);
    let kept = snapshot_half(params.layer + 1u);
    let i = state_index(p.t, p.d, p.m);
    let first = moved_by(p.t, p.d, snapshots[earlier + state_index(p.t, p.d, a)], gaussian_of_block(p.block, p.d));
    states[i] = first;
    if (WRITES_SNAPSHOT) {
        snapshots[kept + i] = first;
    }
    if (p.d + 1u < params.dims) {
        let j = state_index(p.t, p.d + 1u, p.m);
        let second = moved_by(p.t, p.d + 1u, snapshots[earlier + state_index(p.t, p.d + 1u, a)], gaussian_of_block(p.block, p.d + 1u));
        states[j] = second;
        if (WRITES_SNAPSHOT) {
            snapshots[kept + j] = second;
        }
    }
}

// Layer 0 of a likelihood that brings its own dynamics: the selected states back unmoved (its
// Propagate follows).
@compute @workgroup_size(64)
fn copy_selected(@builtin(global_invocation_id) gid: vec3<u32>) {
    let m = gid.x;
    let t = gid.y;
    if (m >= params.particles || t >= params.targets) {
        return;
    }
    for (var d = 0u; d < params.dims; d = d + 1u) {
        let i = state_index(t, d, m);
        states[i] = selected[i];
    }
}

// The frame's last layer normalised (`params`: that layer's), after its likelihood: the step's
// final weights, before the estimate.
@compute @workgroup_size(256)
fn settle_last_layer(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    settle(lid.x, wid.y, params);
}
