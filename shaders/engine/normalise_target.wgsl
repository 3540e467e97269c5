// Log-weight normalisation of one target in one workgroup of 256 invocations (NORMALISE_WG):
// lw += beta * log-likelihood, then max and log-sum-exp reductions, normalised weights and
// log-weights, and ESS = 1 / sum w^2. beta is the annealing layer's (1 without annealing): fixed, or
// chosen by the survival rule, a bisection for ESS = survival_rate * M (pf_core::anneal::survival_beta).
// A NaN or +inf log-weight, or every log-weight -inf, sets the target's status and leaves its
// weights uniform (the failure policy of pf-core). Layer 0 also writes the frame's log evidence,
// log sum exp(lw + ll) at beta = 1 (CPU twin: pf_core::batch::frame_log_evidence).
// A library, parameterised by the layer's Params p: the including kernel declares log_weights,
// log_likelihood, weights and stats (normalise.wgsl for the stage, layer.wgsl for the fused layer),
// and where the passes read and keep their values: prior_at(base, i) / likelihood_at(base, i),
// the log-weights and log-likelihoods (read by every pass before the tempering, the survival
// rule's eleven among them); set_tempered / tempered_at, the tempered log-weights (read by the
// two passes after it); keep_weight, each normalised weight once it is written to `weights`.
// normalise.wgsl keeps them all in the storage buffers; the fused layer in workgroup memory
// (copies it loads before calling normalise_target), whose round trip is a fraction of a storage
// buffer's when one target's workgroup is alone on its SM, and keeps the weights there for its
// resampling.
// CPU twin: pf_core::batch::normalise_target.

const NORMALISE_WG: u32 = 256u;
// The reductions' four-way steps (strides NORMALISE_WG / 4, / 16, ... 1) cover every invocation
// only when NORMALISE_WG is a power of four.
const_assert ((NORMALISE_WG & (NORMALISE_WG - 1u)) == 0u && (NORMALISE_WG & 0x55555555u) != 0u);
// The survival rule's bisection steps: pf_core::anneal::SURVIVAL_BISECTION_STEPS (a pf-gpu test
// holds the two equal).
const SURVIVAL_BISECTION_STEPS: u32 = 10u;
// Each reduction is a tree of four-way steps (strides 64, 16, 4, 1: four barriers and a
// closing one, where halving steps take nine): one target's select runs alone on its SM when a
// frame has few targets, and there the reduction's time is its chain of dependent steps, each
// a barrier and a round trip to workgroup memory; a four-way step's four loads are in flight
// together. (Folding 16 values a step in a loop measured twice as slow.)
var<workgroup> partial: array<f32, 256>;
// (max, sum exp(x - max), sum exp(2 (x - max))) per invocation, for the survival rule's ESS.
var<workgroup> partial_ess: array<vec3<f32>, 256>;
var<workgroup> first_nan: atomic<u32>;
var<workgroup> first_inf: atomic<u32>;

fn reduce_max(lid: u32, value: f32) -> f32 {
    partial[lid] = value;
    workgroupBarrier();
    for (var stride = NORMALISE_WG / 4u; stride > 0u; stride = stride / 4u) {
        if (lid < stride) {
            partial[lid] = max(
                max(partial[lid], partial[lid + stride]),
                max(partial[lid + 2u * stride], partial[lid + 3u * stride]),
            );
        }
        workgroupBarrier();
    }
    let result = partial[0];
    workgroupBarrier();
    return result;
}

fn reduce_sum(lid: u32, value: f32) -> f32 {
    partial[lid] = value;
    workgroupBarrier();
    for (var stride = NORMALISE_WG / 4u; stride > 0u; stride = stride / 4u) {
        if (lid < stride) {
            partial[lid] = (partial[lid] + partial[lid + stride])
                + (partial[lid + 2u * stride] + partial[lid + 3u * stride]);
        }
        workgroupBarrier();
    }
    let result = partial[0];
    workgroupBarrier();
    return result;
}

// prior + beta * ll (beta > 0 always, so NaN, +inf and zero weights stay so). Twin of
// pf_core::anneal::tempered.
fn tempered(prior: f32, ll: f32, beta: f32) -> f32 {
    return prior + beta * ll;
}

// A (max, s1, s2) triple's two sums shifted to a max `m` at least its own (finite); a triple
// whose max is -inf (no weight) adds nothing.
fn shifted_to(triple: vec3<f32>, m: f32) -> vec2<f32> {
    if (is_neg_inf(triple.x)) {
        return vec2<f32>(0.0, 0.0);
    }
    let e = exp(triple.x - m);
    return vec2<f32>(triple.y * e, triple.z * e * e);
}

// Four triples of shifted sums merged into one at their largest max: the max first, then the
// four exponentials independent of each other (merging pairwise would chain them).
fn merge_four(a: vec3<f32>, b: vec3<f32>, c: vec3<f32>, d: vec3<f32>) -> vec3<f32> {
    let m = max(max(a.x, b.x), max(c.x, d.x));
    if (is_neg_inf(m)) {
        return vec3<f32>(m, 0.0, 0.0);
    }
    let sums = (shifted_to(a, m) + shifted_to(b, m)) + (shifted_to(c, m) + shifted_to(d, m));
    return vec3<f32>(m, sums);
}

// The effective sample size of exp(prior + beta * ll) over target t's particles (0 when every
// weight is zero): each invocation's particles' (max, s1, s2), the max first and then the
// sums, then a tree of four-way merges (reduce_sum's shape). Twin of
// pf_core::anneal::tempered_ess.
fn tempered_ess(lid: u32, base: u32, n: u32, beta: f32) -> f32 {
    var m = bitcast<f32>(0xff800000u);
    for (var i = lid; i < n; i = i + NORMALISE_WG) {
        m = max(m, tempered(prior_at(base, i), likelihood_at(base, i), beta));
    }
    var sums = vec2<f32>(0.0, 0.0);
    if (!is_neg_inf(m)) {
        for (var i = lid; i < n; i = i + NORMALISE_WG) {
            let x = tempered(prior_at(base, i), likelihood_at(base, i), beta);
            if (!is_neg_inf(x)) {
                let e = exp(x - m);
                sums = sums + vec2<f32>(e, e * e);
            }
        }
    }
    partial_ess[lid] = vec3<f32>(m, sums);
    workgroupBarrier();
    for (var stride = NORMALISE_WG / 4u; stride > 0u; stride = stride / 4u) {
        if (lid < stride) {
            partial_ess[lid] = merge_four(
                partial_ess[lid],
                partial_ess[lid + stride],
                partial_ess[lid + 2u * stride],
                partial_ess[lid + 3u * stride],
            );
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

// This invocation's share of sum exp(lw + ll - max_at_one) over target t's particles (beta = 1).
fn sum_exp_at_one(lid: u32, base: u32, n: u32, max_at_one: f32) -> f32 {
    var acc = 0.0;
    for (var i = lid; i < n; i = i + NORMALISE_WG) {
        let x = prior_at(base, i) + likelihood_at(base, i);
        if (!is_neg_inf(x)) {
            acc = acc + exp(x - max_at_one);
        }
    }
    return acc;
}

// The survival rule: max_beta when it keeps rate * M effective particles, else the midpoint of
// a SURVIVAL_BISECTION_STEPS-step bisection on (0, max_beta]. Twin of pf_core::anneal::survival_beta.
fn survival_beta(lid: u32, base: u32, n: u32, p: Params) -> f32 {
    let wanted = p.survival_rate * f32(n);
    if (tempered_ess(lid, base, n, p.max_beta) >= wanted) {
        return p.max_beta;
    }
    var lo = 0.0;
    var hi = p.max_beta;
    for (var k = 0u; k < SURVIVAL_BISECTION_STEPS; k = k + 1u) {
        let mid = 0.5 * (lo + hi);
        if (tempered_ess(lid, base, n, mid) >= wanted) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    return 0.5 * (lo + hi);
}

// Normalises target t's log-weights after layer p.layer's likelihood (the whole stage for one
// target; called by the 256 invocations of its workgroup, lid = 0 .. 255).
fn normalise_target(lid: u32, t: u32, p: Params) {
    let n = p.particles;
    let base = t * n;
    if (lid == 0u) {
        atomicStore(&first_nan, 0xffffffffu);
        atomicStore(&first_inf, 0xffffffffu);
    }
    workgroupBarrier();

    // Pass 1: find any NaN / +inf and whether every weight is zero (the same at every beta > 0,
    // so judged at beta = 1), and the max at beta = 1.
    var local_max = bitcast<f32>(0xff800000u);
    for (var i = lid; i < n; i = i + NORMALISE_WG) {
        let lw = prior_at(base, i) + likelihood_at(base, i);
        if (is_nan(lw)) {
            atomicMin(&first_nan, i);
        } else if (is_pos_inf(lw)) {
            atomicMin(&first_inf, i);
        } else {
            local_max = max(local_max, lw);
        }
    }
    let max_at_one = reduce_max(lid, local_max);
    let nan_at = atomicLoad(&first_nan);
    let inf_at = atomicLoad(&first_inf);
    var status = 0u;
    var bad = 0xffffffffu;
    // The first bad particle in index order names the cause (as pf-core does).
    if (nan_at != 0xffffffffu && nan_at < inf_at) {
        status = 2u;
        bad = nan_at;
    } else if (inf_at != 0xffffffffu) {
        status = 3u;
        bad = inf_at;
    } else if (is_neg_inf(max_at_one)) {
        status = 1u;
    }
    if (p.layer == 0u && lid == 0u) {
        // A failed frame's evidence: NaN, +inf, or -inf (every weight zero); else set below.
        if (nan_at != 0xffffffffu) {
            stats[t].log_evidence = bitcast<f32>(0x7fc00000u);
        } else if (inf_at != 0xffffffffu) {
            stats[t].log_evidence = bitcast<f32>(0x7f800000u);
        } else {
            stats[t].log_evidence = max_at_one;
        }
    }
    if (status != 0u) {
        let uniform_w = 1.0 / f32(n);
        let uniform_lw = -log(f32(n));
        for (var i = lid; i < n; i = i + NORMALISE_WG) {
            weights[base + i] = uniform_w;
            log_weights[base + i] = uniform_lw;
            keep_weight(base, i, uniform_w);
        }
        if (lid == 0u) {
            stats[t].max_log_weight = max_at_one;
            stats[t].log_sum_shifted = 0.0;
            stats[t].ess = f32(n);
            stats[t].status = status;
            stats[t].bad_particle = bad;
            stats[t].beta = p.beta;
        }
        return;
    }

    // The layer's beta, then the tempered log-weights and their max (at beta = 1 exactly the
    // sums of pass 1).
    var beta = p.beta;
    if (p.survival_rate > 0.0) {
        beta = survival_beta(lid, base, n, p);
    }
    // Layer 0's evidence at beta = 1, before tempering (at beta = 1 it is pass 2's sum).
    if (p.layer == 0u && beta != 1.0) {
        let sum_at_one = reduce_sum(lid, sum_exp_at_one(lid, base, n, max_at_one));
        if (lid == 0u) {
            stats[t].log_evidence = max_at_one + log(sum_at_one);
        }
    }
    var local_tempered_max = bitcast<f32>(0xff800000u);
    for (var i = lid; i < n; i = i + NORMALISE_WG) {
        let lw = tempered(prior_at(base, i), likelihood_at(base, i), beta);
        set_tempered(base, i, lw);
        local_tempered_max = max(local_tempered_max, lw);
    }
    var max_lw = max_at_one;
    if (beta != 1.0) {
        max_lw = reduce_max(lid, local_tempered_max);
    }

    // Pass 2: sum of exp(lw - max); every term is in [0, 1] and the max contributes 1.
    var local_sum = 0.0;
    for (var i = lid; i < n; i = i + NORMALISE_WG) {
        let lw = tempered_at(base, i);
        if (!is_neg_inf(lw)) {
            local_sum = local_sum + exp(lw - max_lw);
        }
    }
    let sum = reduce_sum(lid, local_sum);
    let log_sum_shifted = log(sum);
    if (p.layer == 0u && beta == 1.0 && lid == 0u) {
        stats[t].log_evidence = max_lw + log_sum_shifted;
    }

    // Pass 3: normalised weights and log-weights, and sum w^2 for the ESS.
    var local_sq = 0.0;
    for (var i = lid; i < n; i = i + NORMALISE_WG) {
        let lw = tempered_at(base, i);
        var w = 0.0;
        var normalised = lw;
        if (!is_neg_inf(lw)) {
            w = exp(lw - max_lw) / sum;
            normalised = (lw - max_lw) - log_sum_shifted;
        }
        weights[base + i] = w;
        log_weights[base + i] = normalised;
        keep_weight(base, i, w);
        local_sq = local_sq + w * w;
    }
    let sum_sq = reduce_sum(lid, local_sq);
    if (lid == 0u) {
        stats[t].max_log_weight = max_lw;
        stats[t].log_sum_shifted = log_sum_shifted;
        stats[t].ess = 1.0 / sum_sq;
        stats[t].status = 0u;
        stats[t].bad_particle = 0xffffffffu;
        stats[t].beta = beta;
    }
}
