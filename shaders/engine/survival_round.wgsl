// One round of the survival rule's search (survival_search.wgsl): one workgroup per (node,
// target) tests the node's midpoint, tempered_ess over the layer's log-weights and
// log-likelihoods in storage, and writes whether it kept survival_rate * M effective particles.
// Dispatched after a layer's likelihood, once a round, in the fused step (pf_gpu::filter::survival);
// the next select (or settle_last_layer) walks the decisions (layer.wgsl). Round 0's last slot
// tests max_beta.
// CPU twin: pf_core::anneal::survival_beta.

@group(0) @binding(0) var<uniform> params: Params;
// The round this dispatch searches (x; a slice of a small uniform buffer, one per round).
@group(0) @binding(1) var<uniform> search_round: vec4<u32>;
@group(0) @binding(2) var<storage, read> log_weights: array<f32>;
@group(0) @binding(3) var<storage, read> log_likelihood: array<f32>;
@group(0) @binding(4) var<storage, read_write> survival_decisions: array<u32>;

fn prior_at(base: u32, i: u32) -> f32 {
    return log_weights[base + i];
}

fn likelihood_at(base: u32, i: u32) -> f32 {
    return log_likelihood[base + i];
}

@compute @workgroup_size(256)
fn survival_round(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    let node = wid.x;
    let t = wid.y;
    let round = search_round.x;
    let n = params.particles;
    var beta = params.max_beta;
    if (node != MAX_BETA_SLOT) {
        beta = node_midpoint(round_start(t, round, params.max_beta), node);
    }
    let kept = tempered_ess(lid.x, t * n, n, beta) >= params.survival_rate * f32(n);
    if (lid.x == 0u) {
        survival_decisions[decision_index(t, round, node)] = select(0u, 1u, kept);
    }
}
