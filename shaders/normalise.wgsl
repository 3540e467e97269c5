// Log-weight normalisation per target: lw += log-likelihood, then max and log-sum-exp reductions,
// normalised weights and log-weights, and ESS = 1 / sum w^2. One workgroup per target.
// A NaN or +inf log-weight, or every log-weight -inf, sets the target's status and leaves its
// weights uniform (the failure policy of pf-core). CPU twin: pf_core::batch::normalise_target.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read_write> log_weights: array<f32>;
@group(0) @binding(2) var<storage, read> log_likelihood: array<f32>;
@group(0) @binding(3) var<storage, read_write> weights: array<f32>;
@group(0) @binding(4) var<storage, read_write> stats: array<TargetStats>;

const WG: u32 = 256u;
var<workgroup> partial: array<f32, 256>;
var<workgroup> first_nan: atomic<u32>;
var<workgroup> first_inf: atomic<u32>;

fn reduce_max(lid: u32, value: f32) -> f32 {
    partial[lid] = value;
    workgroupBarrier();
    for (var stride = WG / 2u; stride > 0u; stride = stride / 2u) {
        if (lid < stride) {
            partial[lid] = max(partial[lid], partial[lid + stride]);
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
    for (var stride = WG / 2u; stride > 0u; stride = stride / 2u) {
        if (lid < stride) {
            partial[lid] = partial[lid] + partial[lid + stride];
        }
        workgroupBarrier();
    }
    let result = partial[0];
    workgroupBarrier();
    return result;
}

@compute @workgroup_size(256)
fn normalise(@builtin(local_invocation_id) lid3: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    let lid = lid3.x;
    let t = wid.y;
    let n = params.particles;
    let base = t * n;
    if (lid == 0u) {
        atomicStore(&first_nan, 0xffffffffu);
        atomicStore(&first_inf, 0xffffffffu);
    }
    workgroupBarrier();

    // Pass 1: accumulate the likelihood, find the max and any NaN / +inf.
    var local_max = bitcast<f32>(0xff800000u);
    for (var i = lid; i < n; i = i + WG) {
        let lw = log_weights[base + i] + log_likelihood[base + i];
        log_weights[base + i] = lw;
        if (is_nan(lw)) {
            atomicMin(&first_nan, i);
        } else if (is_pos_inf(lw)) {
            atomicMin(&first_inf, i);
        } else {
            local_max = max(local_max, lw);
        }
    }
    let max_lw = reduce_max(lid, local_max);
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
    } else if (is_neg_inf(max_lw)) {
        status = 1u;
    }
    if (status != 0u) {
        let uniform_w = 1.0 / f32(n);
        let uniform_lw = -log(f32(n));
        for (var i = lid; i < n; i = i + WG) {
            weights[base + i] = uniform_w;
            log_weights[base + i] = uniform_lw;
        }
        if (lid == 0u) {
            stats[t].max_log_weight = max_lw;
            stats[t].log_sum_shifted = 0.0;
            stats[t].ess = f32(n);
            stats[t].status = status;
            stats[t].bad_particle = bad;
        }
        return;
    }

    // Pass 2: sum of exp(lw - max); every term is in [0, 1] and the max contributes 1.
    var local_sum = 0.0;
    for (var i = lid; i < n; i = i + WG) {
        let lw = log_weights[base + i];
        if (!is_neg_inf(lw)) {
            local_sum = local_sum + exp(lw - max_lw);
        }
    }
    let sum = reduce_sum(lid, local_sum);
    let log_sum_shifted = log(sum);

    // Pass 3: normalised weights and log-weights, and sum w^2 for the ESS.
    var local_sq = 0.0;
    for (var i = lid; i < n; i = i + WG) {
        let lw = log_weights[base + i];
        var w = 0.0;
        var normalised = lw;
        if (!is_neg_inf(lw)) {
            w = exp(lw - max_lw) / sum;
            normalised = (lw - max_lw) - log_sum_shifted;
        }
        weights[base + i] = w;
        log_weights[base + i] = normalised;
        local_sq = local_sq + w * w;
    }
    let sum_sq = reduce_sum(lid, local_sq);
    if (lid == 0u) {
        stats[t].max_log_weight = max_lw;
        stats[t].log_sum_shifted = log_sum_shifted;
        stats[t].ess = 1.0 / sum_sq;
        stats[t].status = 0u;
        stats[t].bad_particle = 0xffffffffu;
    }
}
