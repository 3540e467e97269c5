// Fixed-lag smoothing from the ancestry, summarised on the GPU: the filter keeps its last frames'
// particles, normalised log-weights and lineages in a ring of `slots` frames, and after each step
// this kernel summarises the frame `lag` steps back by the newest frame's weights traced back
// through the lineages (the path smoother of Kitagawa 1996): each newest particle m carries its
// weight w_m to its ancestor A(m) in the lagged frame, so the lagged frame's smoothed cloud is
// {(x_A(m), w_m)}. Only the summaries leave the GPU: per target and value the mean (on the circle
// for an angle) and the 95 % interval's ends, the same for the lagged frame's own (filtered)
// weights where asked, and per target the share of the lagged frame's effective sample size the
// trace kept. A target whose trace meets a particle without an ancestor (restarted within the
// window) gets NaN throughout: the host smooths it from a download.
// The same dispatch keeps the step in the ring (keep_step): the newest frame is read from the
// step's own buffers and copied into ring slot `newest`, which no summary reads (the ring holds
// lag + 2 frames; the summary reads the lag frames before the newest). A dispatch of its own
// for the copy cost a face step 6 us and a barrier's wait before the summary on an NVIDIA H200.
// One workgroup of 256 invocations per (value, target), and one per target for the kept share
// (summarise_lagged); workgroup memory holds one target's particles (SORT_SIZE: M rounded up
// to a power of two, at least 256, set by the driver, pf_gpu::filter::lag_window). The newest
// particles that share an ancestor are merged into one entry (compact_by_ancestor: resampling
// in order keeps them consecutive), and the distinct ancestors ranked (ranked_ends) or, past
// 256, sorted by a bitonic sort for the quantiles. Why not count each particle's cumulative
// weight over all the others: O(M^2) a value took the four-face step that keeps the lineage from
// 0.46 to 0.93 ms on an NVIDIA H100, a loop of dependent workgroup-memory loads on one SM.
// The cloud's mean, interval and effective sample size: lag_cloud.wgsl, prepended.
// CPU twins: pf_core::smooth::ancestry::trace_back, pf_core::smooth::summarise (summary.rs) and
// pf_core::smooth_tracks::AncestryHealth; the ring is the frames pf_core::smooth::lag_window::
// LagWindow keeps.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<uniform> lag_params: LagParams;
// The ring, [((slot * T + t) * D + d) * M + m]: the frames before the newest, and slot `newest`
// written by keep_step.
@group(0) @binding(2) var<storage, read_write> window_states: array<f32>;
// [(slot * T + t) * M + m], normalised.
@group(0) @binding(3) var<storage, read_write> window_log_weights: array<f32>;
// [(slot * T + t) * M + m]: the particle's ancestor among the frame before's.
@group(0) @binding(4) var<storage, read_write> window_lineage: array<u32>;
// [(t * D + d) * 6 + k]: smoothed mean, lower, upper; filtered mean, lower, upper.
@group(0) @binding(5) var<storage, read_write> summaries: array<f32>;
// [t]: traced over filtered effective sample size of the lagged frame.
@group(0) @binding(6) var<storage, read_write> kept: array<f32>;
// The step's own particles [(t * D + d) * M + m], normalised log-weights and lineage [t * M + m]:
// the newest frame.
@group(0) @binding(7) var<storage, read> states: array<f32>;
@group(0) @binding(8) var<storage, read> log_weights: array<f32>;
@group(0) @binding(9) var<storage, read> lineage: array<u32>;

const SORT_SIZE: u32 = 4096u;
// The traced weights' fixed point: weights sum to 1, so 2^30 leaves room for rounding.
const FIXED_ONE: f32 = 1073741824.0;

// First each newest particle's ancestor in the lagged frame (the trace); then each run's summed
// weight (compact_by_ancestor), and where the ancestors do not rise with the index
// (ancestors_rise) each lagged particle's traced weight (the sum of its descendants'), both in
// FIXED_ONE units. One array for all three keeps the kernel within 32 KiB of workgroup memory
// at 2 048 particles a target.
var<workgroup> ancestor_weight: array<atomic<u32>, SORT_SIZE>;
// Set when the ancestors do not rise with the newest particles' index (ancestors_rise).
var<workgroup> unordered: atomic<u32>;
// `unordered` read once by one invocation, then by all through workgroupUniformLoad.
var<workgroup> unordered_flag: u32;
// How many entries compact_by_ancestor made, read uniformly.
var<workgroup> ancestors: u32;
var<workgroup> broken: atomic<u32>;
// `broken` read once by one invocation, then by all through workgroupUniformLoad (a value the
// WGSL spec lets the early return below depend on).
var<workgroup> broken_flag: u32;

fn ring_slot(frames_back: u32) -> u32 {
    return (lag_params.newest + lag_params.slots - frames_back) % lag_params.slots;
}

fn particle_at(slot: u32, t: u32, m: u32) -> u32 {
    return (slot * params.targets + t) * params.particles + m;
}

fn state_at(slot: u32, t: u32, d: u32, m: u32) -> f32 {
    return window_states[((slot * params.targets + t) * params.dims + d) * params.particles + m];
}

fn weight_of(log_weight: f32) -> f32 {
    if (is_neg_inf(log_weight)) {
        return 0.0;
    }
    return exp(log_weight);
}

// Target t's newest particles `lanes(first)`'s ancestors in the lagged frame (n, past the
// particles, where the trace meets a particle without an ancestor). The four traces advance
// together, their loads issued before any is used: a trace is `lag` dependent loads, and one
// particle at a time an invocation's four particles waited for four times as many (as
// layer.wgsl's settle). A lane past the particles traces particle `first` (< n).
fn lagged_ancestors(t: u32, first: u32, n: u32) -> vec4<u32> {
    let ms = lanes(first);
    let at = t * params.particles + select(vec4<u32>(first), ms, ms < vec4<u32>(n));
    var a = vec4<u32>(lineage[at.x], lineage[at.y], lineage[at.z], lineage[at.w]);
    for (var k = 1u; k < lag_params.lag; k = k + 1u) {
        let live = a < vec4<u32>(n);
        if (!any(live)) {
            break;
        }
        let ring_at = particle_at(ring_slot(k), t, 0u) + select(vec4<u32>(0u), a, live);
        let before = vec4<u32>(window_lineage[ring_at.x], window_lineage[ring_at.y], window_lineage[ring_at.z], window_lineage[ring_at.w]);
        a = select(a, before, live);
    }
    return min(a, vec4<u32>(n));
}

// The four newest particles an invocation takes at a time from `first`: LAG_WG apart, so that
// the workgroup's loads of each lane are consecutive.
fn lanes(first: u32) -> vec4<u32> {
    return first + vec4<u32>(0u, 1u, 2u, 3u) * LAG_WG;
}

// The effective sample size of the lagged frame's traced weights, each lagged particle's the
// sum of its descendants' (in FIXED_ONE units in ancestor_weight, whose ancestors it replaces):
// where the ancestors do not rise, so that one ancestor's descendants may be several runs.
fn traced_ess(lid: u32, t: u32, n: u32) -> f32 {
    for (var m = lid; m < n; m = m + LAG_WG) {
        atomicStore(&ancestor_weight[m], 0u);
    }
    workgroupBarrier();
    for (var first = lid; first < n; first = first + 4u * LAG_WG) {
        let a = lagged_ancestors(t, first, n);
        let ms = lanes(first);
        for (var c = 0u; c < 4u; c = c + 1u) {
            if (ms[c] < n) {
                let w = newest_weight(t, ms[c]);
                atomicAdd(&ancestor_weight[a[c]], u32(round(w * FIXED_ONE)));
            }
        }
    }
    workgroupBarrier();
    for (var m = lid; m < n; m = m + LAG_WG) {
        cloud_weights[m] = f32(atomicLoad(&ancestor_weight[m])) / FIXED_ONE;
    }
    workgroupBarrier();
    return weights_ess(lid, n);
}

// The most particles one invocation takes in compact_by_ancestor: SORT_SIZE / LAG_WG at most.
const MAX_CHUNK: u32 = 16u;

// Whether the newest particles' ancestors (in ancestor_weight) rise with their index, so that
// each ancestor's descendants are one run (then the runs' weights are the traced weights).
fn ancestors_rise(lid: u32, n: u32) -> bool {
    for (var m = lid + 1u; m < n; m = m + LAG_WG) {
        if (atomicLoad(&ancestor_weight[m]) < atomicLoad(&ancestor_weight[m - 1u])) {
            atomicStore(&unordered, 1u);
        }
    }
    workgroupBarrier();
    if (lid == 0u) {
        unordered_flag = atomicLoad(&unordered);
    }
    return workgroupUniformLoad(&unordered_flag) == 0u;
}

// The smoothed cloud with the newest particles of one ancestor merged where they are
// consecutive: each such run becomes one entry (in order of the runs), values[j] the ancestor's
// value and cloud_weights[j] the run's weights summed in FIXED_ONE units (in parallel: one
// ancestor's descendants may be all n), within n / 2^31 of their sum. The same weighted cloud,
// in fewer entries: systematic and stratified resampling draw their offspring in order, so each
// layer's ancestors rise with the offspring's index, and so do the lineages composed of them; a
// lag of frames back the particles then have few distinct ancestors (the trace keeps a few per
// cent of the effective sample size), each one run, and the sort that follows takes those
// instead of all n. Returns how many entries there are.
fn compact_by_ancestor(lid: u32, n: u32) -> u32 {
    // Each invocation a chunk of consecutive particles: which of them start a run, their
    // weights, and the value of each run starting there.
    let chunk = (n + LAG_WG - 1u) / LAG_WG;
    let begin = min(lid * chunk, n);
    let end = min(begin + chunk, n);
    var starts = 0u;
    var starting = 0u;
    var weight: array<f32, MAX_CHUNK>;
    var run_value: array<f32, MAX_CHUNK>;
    for (var m = begin; m < end; m = m + 1u) {
        weight[m - begin] = cloud_weights[m];
        if (m == 0u || atomicLoad(&ancestor_weight[m]) != atomicLoad(&ancestor_weight[m - 1u])) {
            starting = starting | (1u << (m - begin));
            run_value[starts] = values[m];
            starts = starts + 1u;
        }
    }
    // The scan's barriers end every read of the ancestors and the cloud before they are
    // overwritten: ancestor_weight then sums each run's weights in FIXED_ONE units (integer
    // sums, the same in any order), the run's index its start's rank among the starts.
    let first = u32(exclusive_scan(lid, f32(starts)));
    for (var j = lid; j < n; j = j + LAG_WG) {
        atomicStore(&ancestor_weight[j], 0u);
    }
    workgroupBarrier();
    var run = i32(first) - 1;
    for (var m = begin; m < end; m = m + 1u) {
        if ((starting & (1u << (m - begin))) != 0u) {
            run = run + 1;
            values[u32(run)] = run_value[u32(run) - first];
        }
        atomicAdd(&ancestor_weight[u32(run)], u32(round(weight[m - begin] * FIXED_ONE)));
    }
    if (lid == LAG_WG - 1u) {
        ancestors = first + starts;
    }
    let entries = workgroupUniformLoad(&ancestors);
    for (var j = lid; j < entries; j = j + LAG_WG) {
        cloud_weights[j] = f32(atomicLoad(&ancestor_weight[j])) / FIXED_ONE;
    }
    workgroupBarrier();
    return entries;
}

// The share of the lagged frame's effective sample size that the trace kept, for target t
// (after the trace, with the ancestors in ancestor_weight): the runs' weights where each
// ancestor is one run, else the traced weights summed per ancestor (traced_ess), against the
// lagged frame's own weights.
fn kept_share(lid: u32, t: u32, n: u32, lagged: u32) -> f32 {
    var traced = 0.0;
    if (ancestors_rise(lid, n)) {
        traced = weights_ess(lid, compact_by_ancestor(lid, n));
    } else {
        traced = traced_ess(lid, t, n);
    }
    for (var m = lid; m < n; m = m + LAG_WG) {
        cloud_weights[m] = weight_of(window_log_weights[particle_at(lagged, t, m)]);
    }
    workgroupBarrier();
    let own = weights_ess(lid, n);
    if (own > 0.0) {
        return traced / own;
    }
    return 0.0;
}

// The newest frame's normalised weight of target t's particle m (the step's own buffer).
fn newest_weight(t: u32, m: u32) -> f32 {
    return weight_of(log_weights[t * params.particles + m]);
}

// Summarises value d of target t (d < D), or gives target t's kept share (d == D), into
// `summaries` or `kept`.
fn summarise_target(lid: u32, d: u32, t: u32) {
    let n = params.particles;
    let sharing = d == params.dims;
    if (lid == 0u) {
        atomicStore(&broken, 0u);
        atomicStore(&unordered, 0u);
    }
    workgroupBarrier();
    let lagged = ring_slot(lag_params.lag);
    // Each newest particle's ancestor lag frames back: the ancestor's value with the newest
    // particle's weight.
    // Four particles at a time (lagged_ancestors), the ancestors' values loaded before any is
    // stored; a broken trace's (ancestor n) reads particle 0's.
    for (var first = lid; first < n; first = first + 4u * LAG_WG) {
        let traced = lagged_ancestors(t, first, n);
        let a = select(vec4<u32>(0u), traced, traced < vec4<u32>(n));
        var value = vec4<f32>(0.0);
        if (!sharing) {
            value = vec4<f32>(state_at(lagged, t, d, a.x), state_at(lagged, t, d, a.y), state_at(lagged, t, d, a.z), state_at(lagged, t, d, a.w));
        }
        let ms = lanes(first);
        for (var c = 0u; c < 4u; c = c + 1u) {
            let m = ms[c];
            if (m < n) {
                if (traced[c] == n) {
                    atomicStore(&broken, 1u);
                }
                cloud_weights[m] = newest_weight(t, m);
                values[m] = value[c];
                atomicStore(&ancestor_weight[m], a[c]);
            }
        }
    }
    workgroupBarrier();
    if (lid == 0u) {
        broken_flag = atomicLoad(&broken);
    }
    let out = (t * params.dims + d) * 6u;
    if (workgroupUniformLoad(&broken_flag) != 0u) {
        if (lid == 0u) {
            let nan = bitcast<f32>(0x7fc00000u);
            if (sharing) {
                kept[t] = nan;
            } else {
                for (var k = 0u; k < 6u; k = k + 1u) {
                    summaries[out + k] = nan;
                }
            }
        }
        return;
    }
    if (sharing) {
        let share = kept_share(lid, t, n, lagged);
        if (lid == 0u) {
            kept[t] = share;
        }
        return;
    }
    let entries = compact_by_ancestor(lid, n);
    let smoothed = summarise(lid, entries, is_angle(d));
    var filtered = vec3<f32>(0.0);
    if (lag_params.filtered == 1u) {
        // The lagged frame's own particles under their own weights.
        for (var m = lid; m < n; m = m + LAG_WG) {
            cloud_weights[m] = weight_of(window_log_weights[particle_at(lagged, t, m)]);
            values[m] = state_at(lagged, t, d, m);
        }
        workgroupBarrier();
        filtered = summarise(lid, n, is_angle(d));
    }
    if (lid == 0u) {
        summaries[out] = smoothed.x;
        summaries[out + 1u] = smoothed.y;
        summaries[out + 2u] = smoothed.z;
        summaries[out + 3u] = filtered.x;
        summaries[out + 4u] = filtered.y;
        summaries[out + 5u] = filtered.z;
    }
}

// The step kept in ring slot `newest`: workgroup (d, t) copies value d of target t's particles,
// workgroup (D, t) the target's normalised log-weights and lineage. Slot `newest` is not one
// the summaries read, so no workgroup waits for another.
fn keep_step(lid: u32, d: u32, t: u32) {
    let n = params.particles;
    let into = lag_params.newest * params.targets + t;
    if (d < params.dims) {
        let from_value = (t * params.dims + d) * n;
        let into_value = (into * params.dims + d) * n;
        for (var m = lid; m < n; m = m + LAG_WG) {
            window_states[into_value + m] = states[from_value + m];
        }
    } else {
        for (var m = lid; m < n; m = m + LAG_WG) {
            let kept_at = particle_at(lag_params.newest, t, m);
            window_log_weights[kept_at] = log_weights[t * n + m];
            window_lineage[kept_at] = lineage[t * n + m];
        }
    }
}

// Workgroup (d, t) for d < D summarises value d of target t; workgroup (D, t) gives target t's
// kept share alone (kept_share), so that no workgroup does both (the kernel takes as long as
// its slowest workgroup). Every workgroup then keeps its part of the step in the ring.
@compute @workgroup_size(256)
fn summarise_lagged(
    @builtin(workgroup_id) group: vec3<u32>,
    @builtin(local_invocation_id) local: vec3<u32>,
) {
    let d = group.x;
    let t = group.y;
    let lid = local.x;
    if (lag_params.summarise == 1u) {
        summarise_target(lid, d, t);
    }
    keep_step(lid, d, t);
}
