// One annealing layer's selection and moving, fused into one dispatch of one workgroup (256
// invocations) per target: layers after the first normalise the previous layer's weights first
// (normalise_target), then the target resamples (prefix_sum_and_search), gathers its ancestors'
// states through workgroup memory one dimension at a time (in place: no second buffer and no
// copy back) and moves them (moved_value). With the likelihood's dispatch after it, a layer is
// two dispatches where the staged step records five and a copy (resample, gather, copy, diffuse,
// likelihood, normalise); the driver then normalises the last layer and estimates.
// One workgroup's chain of dependent loads is this kernel's time (a few targets leave the GPU
// idle but for it), so the resampling works in workgroup memory: the weights are copied in once,
// the CDF's binary searches and the gather's ancestor lookups never wait on a storage buffer.
// The same arithmetic in the same order as the staged stages: the same random numbers, hence
// the same particles. CPU twins: those of
// the libraries it calls — pf_core::batch::normalise_target, pf_core::resample::{Systematic,
// Stratified}, pf_core::ParticleSet::select, pf_core::batch::diffuse.
// Systematic and stratified resampling of at most STAGE_CAPACITY particles a target; the driver
// builds the kernel with STAGE_CAPACITY set to the filter's M (pf_gpu::filter::fused).

// This layer's parameters, and the previous layer's (whose weights this dispatch normalises;
// unused in layer 0).
@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<uniform> settle_params: Params;
@group(0) @binding(2) var<storage, read_write> log_weights: array<f32>;
@group(0) @binding(3) var<storage, read> log_likelihood: array<f32>;
@group(0) @binding(4) var<storage, read_write> weights: array<f32>;
@group(0) @binding(5) var<storage, read_write> stats: array<TargetStats>;
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
// The CDF while the target resamples; then one dimension of its particles, read before any of
// them is overwritten.
var<workgroup> staged: array<f32, STAGE_CAPACITY>;
// The target's normalised weights, and the ancestor of each offspring.
var<workgroup> local_weights: array<f32, STAGE_CAPACITY>;
var<workgroup> local_ancestors: array<u32, STAGE_CAPACITY>;

// Where normalise_target's bisection reads a layer's log-weights and log-likelihoods: the
// copies that load_for_normalise puts in workgroup memory (local_weights and staged are free
// until the resampling).
fn prior_at(base: u32, i: u32) -> f32 {
    return local_weights[i];
}

fn likelihood_at(base: u32, i: u32) -> f32 {
    return staged[i];
}

// Normalises target t's weights after the layer `p` weighed (its log-weights and log-likelihoods
// first copied into workgroup memory for the survival rule's passes).
fn settle(lid: u32, t: u32, p: Params) {
    let n = p.particles;
    let base = t * n;
    for (var k = lid; k < n; k = k + LAYER_WG) {
        local_weights[k] = log_weights[base + k];
        staged[k] = log_likelihood[base + k];
    }
    workgroupBarrier();
    normalise_target(lid, t, p);
}

// Where prefix_sum_and_search (resample_target.wgsl) keeps the weights, the CDF and the
// ancestors: workgroup memory (the ancestors also go to their buffer, for the lineage and the
// tests that read them).
fn weight_at(base: u32, i: u32) -> f32 {
    return local_weights[i];
}

fn cdf_at(base: u32, i: u32) -> f32 {
    return staged[i];
}

fn set_cdf(base: u32, i: u32, value: f32) {
    staged[i] = value;
}

fn set_ancestor(base: u32, k: u32, ancestor: u32) {
    ancestors[base + k] = ancestor;
    local_ancestors[k] = ancestor;
}

// Normalise (after the first layer), resample, then gather and (when `diffuses`) move every
// dimension of target t.
fn select_and_move(lid: u32, t: u32, stratified: bool, diffuses: bool) {
    if (params.layer > 0u) {
        settle(lid, t, settle_params);
        storageBarrier();
        workgroupBarrier();
    }
    let n = params.particles;
    let base = t * n;
    // Each invocation reads back the weights it normalised itself (or the last frame's).
    for (var k = lid; k < n; k = k + LAYER_WG) {
        local_weights[k] = weights[base + k];
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
    let step = vec2<u32>(params.step_lo, params.step_hi);
    for (var d = 0u; d < params.dims; d = d + 1u) {
        for (var m = lid; m < n; m = m + LAYER_WG) {
            staged[m] = states[state_index(t, d, m)];
        }
        workgroupBarrier();
        for (var k = lid; k < n; k = k + LAYER_WG) {
            var x = staged[local_ancestors[k]];
            if (diffuses) {
                x = moved_value(t, d, k, x, step);
            }
            states[state_index(t, d, k)] = x;
        }
        workgroupBarrier();
    }
}

@compute @workgroup_size(256)
fn systematic_layer(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    select_and_move(lid.x, wid.y, false, true);
}

@compute @workgroup_size(256)
fn stratified_layer(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    select_and_move(lid.x, wid.y, true, true);
}

// Layer 0 of a likelihood that brings its own dynamics: select only (its Propagate follows).
@compute @workgroup_size(256)
fn systematic_select(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    select_and_move(lid.x, wid.y, false, false);
}

@compute @workgroup_size(256)
fn stratified_select(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    select_and_move(lid.x, wid.y, true, false);
}

// The frame's last layer normalised (`params`: that layer's), after its likelihood: the step's
// final weights, before the estimate.
@compute @workgroup_size(256)
fn settle_last_layer(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    settle(lid.x, wid.y, params);
}
