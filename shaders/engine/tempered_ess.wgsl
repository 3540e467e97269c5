// The effective sample size of a target's tempered weights, reduced by one workgroup of
// NORMALISE_WG invocations in a fixed order: each invocation's particles lid, lid + 256, ... then a
// tree. A library shared by the normalisation (normalise_target.wgsl's survival rule) and the
// survival rule's search rounds (survival_round.wgsl), so that both reduce the same floats in the
// same order. The including kernel declares prior_at(base, i) and likelihood_at(base, i).
// CPU twins: pf_core::anneal::{tempered, tempered_ess}.

const NORMALISE_WG: u32 = 256u;
// (max, sum exp(x - max), sum exp(2 (x - max))) per invocation, for the survival rule's ESS.
var<workgroup> partial_ess: array<vec3<f32>, 256>;

// prior + beta * ll (beta > 0 always, so NaN, +inf and zero weights stay so). Twin of
// pf_core::anneal::tempered.
fn tempered(prior: f32, ll: f32, beta: f32) -> f32 {
    return prior + beta * ll;
}

// Merges two (max, s1, s2) triples of shifted sums into one at the larger max.
fn merge_ess(a: vec3<f32>, b: vec3<f32>) -> vec3<f32> {
    if (is_neg_inf(a.x)) {
        return b;
    }
    if (is_neg_inf(b.x)) {
        return a;
    }
    let m = max(a.x, b.x);
    let ea = exp(a.x - m);
    let eb = exp(b.x - m);
    return vec3<f32>(m, a.y * ea + b.y * eb, a.z * ea * ea + b.z * eb * eb);
}

// The effective sample size of exp(prior + beta * ll) over target t's particles (0 when every
// weight is zero): one pass, one reduction of (max, s1, s2). Twin of pf_core::anneal::tempered_ess.
fn tempered_ess(lid: u32, base: u32, n: u32, beta: f32) -> f32 {
    var acc = vec3<f32>(bitcast<f32>(0xff800000u), 0.0, 0.0);
    for (var i = lid; i < n; i = i + NORMALISE_WG) {
        let x = tempered(prior_at(base, i), likelihood_at(base, i), beta);
        if (!is_neg_inf(x)) {
            acc = merge_ess(acc, vec3<f32>(x, 1.0, 1.0));
        }
    }
    partial_ess[lid] = acc;
    workgroupBarrier();
    for (var stride = NORMALISE_WG / 2u; stride > 0u; stride = stride / 2u) {
        if (lid < stride) {
            partial_ess[lid] = merge_ess(partial_ess[lid], partial_ess[lid + stride]);
        }
        workgroupBarrier();
    }
    let total = partial_ess[0];
    workgroupBarrier();
    if (is_neg_inf(total.x)) {
        return 0.0;
    }
    return total.y * total.y / total.z;
}
