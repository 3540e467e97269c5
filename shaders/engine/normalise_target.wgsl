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
// rule's search among them); set_tempered / tempered_at, the tempered log-weights (read by the
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
// (max, sum exp(x - max), sum exp(2 (x - max))) per invocation, for the survival rule's ESS
// (a slot's group's, then the slot's: survival_beta).
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

// The survival rule's search. The bisection's ten steps are a tree of midpoints, each step's
// midpoint chosen by the step before; a pass here weighs a whole subtree of SEARCH_LEVELS levels
// at once (its 2^SEARCH_LEVELS - 1 midpoints, a slot of invocations each), then walks it as the
// bisection would, reading the slots' answers: five passes of three midpoints take the place of
// ten dependent reductions. The midpoints are computed by the bisection's own arithmetic from
// the same interval and the walk takes its decisions, so the β is the CPU twin's bisection's
// (pf_core::anneal::survival_beta) whenever each ESS falls on the same side of the target.
// Slot c of SEARCH_SLOTS is invocations c, c + SEARCH_SLOTS, ...: the SEARCH_GROUPS invocations
// that share its particles (the particles i = g mod SEARCH_GROUPS to group g), neighbouring
// invocations weighing one particle at different β (one broadcast load). Wider subtrees (three
// and five levels a pass) measured slower on an NVIDIA H200: each slot's invocations loop over
// more particles (BENCHMARKS.md, "The survival rule's search").
const SEARCH_LEVELS: u32 = 2u;
const SEARCH_SLOTS: u32 = 1u << SEARCH_LEVELS;
const SEARCH_GROUPS: u32 = NORMALISE_WG / SEARCH_SLOTS;
const_assert SEARCH_SLOTS <= NORMALISE_WG;

// The effective sample size of exp(prior + beta * ll) over target t's particles (0 when every
// weight is zero): each invocation's particles' (max, s1, s2), the max first and then the
// sums, then merge_triples over the whole workgroup. The survival rule's first check,
// whether max_beta itself keeps enough (where it does, as for most layers of a smooth
// likelihood, it is the rule's only pass). Twin of pf_core::anneal::tempered_ess.
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
    merge_triples(lid, vec3<f32>(m, sums), 1u);
    let total = partial_ess[0];
    workgroupBarrier();
    return ess_of(total);
}

// Particle i's tempered log-weight at beta (-inf past the target's last particle).
fn tempered_or_none(base: u32, n: u32, i: u32, beta: f32) -> f32 {
    if (i >= n) {
        return bitcast<f32>(0xff800000u);
    }
    return tempered(prior_at(base, i), likelihood_at(base, i), beta);
}

// exp(x - m), 0 for a zero weight (x = -inf).
fn shifted_exp(x: f32, m: f32) -> f32 {
    if (is_neg_inf(x)) {
        return 0.0;
    }
    return exp(x - m);
}

// The (max, sum exp(x - max), sum exp(2 (x - max))) of exp(prior + beta * ll) over the
// particles of one group (i = group, group + SEARCH_GROUPS, ...): the max first, then the sums,
// each in four chains (four particles a step) so that neighbouring particles' loads and
// exponentials overlap: one invocation's loop is a long dependent chain otherwise, and there
// is little else on its SM to hide it.
fn tempered_triple(base: u32, n: u32, group: u32, beta: f32) -> vec3<f32> {
    let stride = SEARCH_GROUPS;
    var maxima = vec4<f32>(bitcast<f32>(0xff800000u));
    for (var i = group; i < n; i = i + 4u * stride) {
        maxima = max(maxima, vec4<f32>(
            tempered_or_none(base, n, i, beta),
            tempered_or_none(base, n, i + stride, beta),
            tempered_or_none(base, n, i + 2u * stride, beta),
            tempered_or_none(base, n, i + 3u * stride, beta),
        ));
    }
    let m = max(max(maxima.x, maxima.y), max(maxima.z, maxima.w));
    if (is_neg_inf(m)) {
        return vec3<f32>(m, 0.0, 0.0);
    }
    var s1 = vec4<f32>(0.0);
    var s2 = vec4<f32>(0.0);
    for (var i = group; i < n; i = i + 4u * stride) {
        let e = vec4<f32>(
            shifted_exp(tempered_or_none(base, n, i, beta), m),
            shifted_exp(tempered_or_none(base, n, i + stride, beta), m),
            shifted_exp(tempered_or_none(base, n, i + 2u * stride, beta), m),
            shifted_exp(tempered_or_none(base, n, i + 3u * stride, beta), m),
        );
        s1 = s1 + e;
        s2 = s2 + e * e;
    }
    return vec3<f32>(m, (s1.x + s1.y) + (s1.z + s1.w), (s2.x + s2.y) + (s2.z + s2.w));
}

// The ESS of a merged triple (0 when every weight is zero). Twin of pf_core::anneal::tempered_ess.
fn ess_of(total: vec3<f32>) -> f32 {
    if (is_neg_inf(total.x)) {
        return 0.0;
    }
    return total.y * total.y / total.z;
}

// Each invocation's triple merged with those of the other invocations of its slot (lid mod
// `slots`) into partial_ess[slot]: a tree of four-way merges over the NORMALISE_WG / slots
// groups (two-way where the groups left are not a multiple of four). One slot is the whole
// workgroup (tempered_ess: strides 64, 16, 4, 1, reduce_sum's shape); the survival rule's
// search has SEARCH_SLOTS.
fn merge_triples(lid: u32, triple: vec3<f32>, slots: u32) {
    partial_ess[lid] = triple;
    workgroupBarrier();
    var groups = NORMALISE_WG / slots;
    while (groups > 1u) {
        let empty = vec3<f32>(bitcast<f32>(0xff800000u), 0.0, 0.0);
        if (groups % 4u == 0u) {
            let stride = (groups / 4u) * slots;
            if (lid < stride) {
                partial_ess[lid] = merge_four(
                    partial_ess[lid],
                    partial_ess[lid + stride],
                    partial_ess[lid + 2u * stride],
                    partial_ess[lid + 3u * stride],
                );
            }
            groups = groups / 4u;
        } else {
            let stride = (groups / 2u) * slots;
            if (lid < stride) {
                partial_ess[lid] = merge_four(partial_ess[lid], partial_ess[lid + stride], empty, empty);
            }
            groups = groups / 2u;
        }
        workgroupBarrier();
    }
}

// The midpoint at in-order position `slot` (1 .. 2^levels - 1) of the bisection's subtree of
// `levels` levels below the interval (lo, hi): the bisection's steps down to it, by its arithmetic.
fn subtree_midpoint(slot: u32, levels: u32, lo: f32, hi: f32) -> f32 {
    var a = lo;
    var b = hi;
    var position = 0u;
    var bit = 1u << (levels - 1u);
    var mid = 0.5 * (a + b);
    while (bit > 0u) {
        mid = 0.5 * (a + b);
        if (slot == position + bit) {
            break;
        }
        if (slot > position + bit) {
            a = mid;
            position = position + bit;
        } else {
            b = mid;
        }
        bit = bit >> 1u;
    }
    return mid;
}

// The survival rule: max_beta when it keeps rate * M effective particles, else the midpoint of
// a SURVIVAL_BISECTION_STEPS-step bisection on (0, max_beta], taken SEARCH_LEVELS steps a pass
// (above). Twin of pf_core::anneal::survival_beta.
fn survival_beta(lid: u32, base: u32, n: u32, p: Params) -> f32 {
    let wanted = p.survival_rate * f32(n);
    if (tempered_ess(lid, base, n, p.max_beta) >= wanted) {
        return p.max_beta;
    }
    let slot = lid % SEARCH_SLOTS;
    let group = lid / SEARCH_SLOTS;
    var lo = 0.0;
    var hi = p.max_beta;
    var done = 0u;
    while (done < SURVIVAL_BISECTION_STEPS) {
        let levels = min(SEARCH_LEVELS, SURVIVAL_BISECTION_STEPS - done);
        var triple = vec3<f32>(bitcast<f32>(0xff800000u), 0.0, 0.0);
        if (slot > 0u && slot < (1u << levels)) {
            triple = tempered_triple(base, n, group, subtree_midpoint(slot, levels, lo, hi));
        }
        merge_triples(lid, triple, SEARCH_SLOTS);
        // The bisection's walk down the subtree, every invocation alike.
        var position = 0u;
        for (var bit = 1u << (levels - 1u); bit > 0u; bit = bit >> 1u) {
            let mid = 0.5 * (lo + hi);
            if (ess_of(partial_ess[position + bit]) >= wanted) {
                lo = mid;
                position = position + bit;
            } else {
                hi = mid;
            }
        }
        // The next pass writes partial_ess.
        workgroupBarrier();
        done = done + levels;
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
