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
// CPU twins: pf_core::smooth::ancestry::trace_back, pf_core::smooth::summarise (summary.rs) and
// pf_core::smooth_tracks::AncestryHealth; the ring is the frames pf_core::smooth::lag_window::
// LagWindow keeps.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<uniform> lag_params: LagParams;
// [((slot * T + t) * D + d) * M + m]
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
const LAG_WG: u32 = 256u;
const LOWER_Q: f32 = 0.025;
const UPPER_Q: f32 = 0.975;
// The traced weights' fixed point: weights sum to 1, so 2^30 leaves room for rounding.
const FIXED_ONE: f32 = 1073741824.0;

// The cloud being summarised: each particle's value (then its offset from the mean, sorted)
// and weight; padding at +inf with weight 0.
var<workgroup> values: array<f32, SORT_SIZE>;
var<workgroup> cloud_weights: array<f32, SORT_SIZE>;
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
var<workgroup> partial: array<f32, 256>;
// Several reductions at once (reduce_pair, reduce_ends): one reduction's barriers for two or
// three values.
var<workgroup> partial4: array<vec4<f32>, 256>;
// exclusive_scan's second array.
var<workgroup> scan_other: array<f32, 256>;
var<workgroup> broken: atomic<u32>;
// `broken` read once by one invocation, then by all through workgroupUniformLoad (a value the
// WGSL spec lets the early return below depend on).
var<workgroup> broken_flag: u32;

// Each reduction and scan below takes four-way steps (strides 64, 16, 4, 1 over LAG_WG): one
// target's value is summarised by a workgroup alone on its SM when a frame has few targets, and
// there the summary's time is its chain of dependent steps, each a barrier and a round trip to
// workgroup memory (the engine's normalisation measured the same, BENCHMARKS.md "Four-way
// reductions"). They cover every invocation only when LAG_WG is a power of four.
const_assert ((LAG_WG & (LAG_WG - 1u)) == 0u && (LAG_WG & 0x55555555u) != 0u);

// The sum of `value` over the invocations.
fn reduce_sum(lid: u32, value: f32) -> f32 {
    partial[lid] = value;
    workgroupBarrier();
    for (var stride = LAG_WG / 4u; stride > 0u; stride = stride / 4u) {
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

// The sums of both components of `value` over the invocations (each what reduce_sum gives).
fn reduce_pair(lid: u32, value: vec2<f32>) -> vec2<f32> {
    partial4[lid] = vec4<f32>(value, 0.0, 0.0);
    workgroupBarrier();
    for (var stride = LAG_WG / 4u; stride > 0u; stride = stride / 4u) {
        if (lid < stride) {
            partial4[lid] = (partial4[lid] + partial4[lid + stride])
                + (partial4[lid + 2u * stride] + partial4[lid + 3u * stride]);
        }
        workgroupBarrier();
    }
    let result = partial4[0].xy;
    workgroupBarrier();
    return result;
}

// Two (min, min, max, max) quadruples merged: min of x and y, max of z and w.
fn merge_ends(a: vec4<f32>, b: vec4<f32>) -> vec4<f32> {
    return vec4<f32>(min(a.xy, b.xy), max(a.zw, b.zw));
}

// The min of x and y and the max of z and w over the invocations, in one reduction: an
// interval's two ends, the last weighed entry and whether any entry is weighed.
fn reduce_ends(lid: u32, value: vec4<f32>) -> vec4<f32> {
    partial4[lid] = value;
    workgroupBarrier();
    for (var stride = LAG_WG / 4u; stride > 0u; stride = stride / 4u) {
        if (lid < stride) {
            partial4[lid] = merge_ends(
                merge_ends(partial4[lid], partial4[lid + stride]),
                merge_ends(partial4[lid + 2u * stride], partial4[lid + 3u * stride]),
            );
        }
        workgroupBarrier();
    }
    let result = partial4[0];
    workgroupBarrier();
    return result;
}

// The sum of `value` over the invocations before this one (Hillis-Steele in four-way steps: at
// stride s each invocation adds the three partial sums s, 2s and 3s before it, each step reading
// one array and writing the other, one barrier a step).
fn exclusive_scan(lid: u32, value: f32) -> f32 {
    partial[lid] = value;
    workgroupBarrier();
    var in_partial = true;
    for (var stride = 1u; stride < LAG_WG; stride = stride * 4u) {
        var sum = 0.0;
        if (in_partial) {
            sum = partial[lid];
            for (var k = 1u; k < 4u && k * stride <= lid; k = k + 1u) {
                sum = sum + partial[lid - k * stride];
            }
            scan_other[lid] = sum;
        } else {
            sum = scan_other[lid];
            for (var k = 1u; k < 4u && k * stride <= lid; k = k + 1u) {
                sum = sum + scan_other[lid - k * stride];
            }
            partial[lid] = sum;
        }
        in_partial = !in_partial;
        workgroupBarrier();
    }
    let inclusive = select(scan_other[lid], partial[lid], in_partial);
    workgroupBarrier();
    return inclusive - value;
}

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

// Sorts the first `len` values (with their weights) ascending in workgroup memory (`len` a
// power of two, the same in every invocation).
fn bitonic_sort(lid: u32, len: u32) {
    for (var k = 2u; k <= len; k = k * 2u) {
        for (var j = k / 2u; j > 0u; j = j / 2u) {
            for (var i = lid; i < len; i = i + LAG_WG) {
                let l = i ^ j;
                if (l > i) {
                    let a = values[i];
                    let b = values[l];
                    if ((a > b) == ((i & k) == 0u)) {
                        values[i] = b;
                        values[l] = a;
                        let w = cloud_weights[i];
                        cloud_weights[i] = cloud_weights[l];
                        cloud_weights[l] = w;
                    }
                }
            }
            workgroupBarrier();
        }
    }
}

// The weighted mean of the n `values` under `cloud_weights` (on the circle for an angle).
fn weighted_mean(lid: u32, n: u32, angle: bool) -> f32 {
    var a = 0.0;
    var b = 0.0;
    for (var m = lid; m < n; m = m + LAG_WG) {
        let w = cloud_weights[m];
        let x = values[m];
        if (angle) {
            a = a + w * sin(x);
            b = b + w * cos(x);
        } else {
            a = a + w * x;
        }
    }
    if (angle) {
        let sums = reduce_pair(lid, vec2<f32>(a, b));
        return atan2(sums.x, sums.y);
    }
    return reduce_sum(lid, a);
}

// The mean, lower and upper end of the 95 % interval of the n `values` under `cloud_weights`:
// the quantiles are the smallest offsets from the mean (wrapped for an angle) whose cumulative
// weight in sorted order reaches 2.5 % and 97.5 %, else the largest offset of positive weight.
// Twin of pf_core::smooth::summary. n is the same in every invocation. Up to LAG_WG entries
// (what a trace merged by ancestor leaves) each invocation ranks its own entry against all n
// (ranked_ends: no sort); more are sorted (sorted_ends).
fn summarise(lid: u32, n: u32, angle: bool) -> vec3<f32> {
    let mean = weighted_mean(lid, n, angle);
    let none = bitcast<f32>(0x7f800000u);
    let sort_len = 1u << (32u - countLeadingZeros(max(n, 2u) - 1u));
    let scan_len = select(n, max(sort_len, LAG_WG), n > LAG_WG);
    for (var m = lid; m < scan_len; m = m + LAG_WG) {
        if (m < n) {
            var e = values[m] - mean;
            if (angle) {
                e = wrap_angle(e);
            }
            values[m] = e;
        } else {
            values[m] = none;
            cloud_weights[m] = 0.0;
        }
    }
    workgroupBarrier();
    var ends = vec4<f32>(0.0);
    if (n <= LAG_WG) {
        ends = ranked_ends(lid, n);
    } else {
        ends = sorted_ends(lid, sort_len);
    }
    // Rounding can leave the total just under a quantile: the largest offset then, as on the CPU.
    var lower = select(ends.z, ends.x, ends.x != none);
    var upper = select(ends.z, ends.y, ends.y != none);
    // Every weight zero: no quantile (NaN, as on the CPU).
    if (ends.w <= 0.0) {
        lower = bitcast<f32>(0x7fc00000u);
        upper = lower;
    }
    return vec3<f32>(mean, mean + lower, mean + upper);
}

// The interval's ends for n <= LAG_WG offsets in `values` (weights in `cloud_weights`): each
// invocation's entry's cumulative weight in sorted order is its own weight and the weights of
// the entries before it (a smaller offset, or an equal one at a lower index), summed over all
// n entries in one loop of broadcast reads; the 2.5 % end is the smallest offset of positive
// weight whose cumulative weight reaches 2.5 %, the 97.5 % end likewise. Returns (lower end,
// upper end, +inf where none reaches it; the largest offset of positive weight; 1 where any
// entry is weighed, else 0), as sorted_ends does. One loop and one reduction where a sort
// of 64 entries took 21 barriers and the scan of their weights five more.
fn ranked_ends(lid: u32, n: u32) -> vec4<f32> {
    let none = bitcast<f32>(0x7f800000u);
    var ends = vec4<f32>(none, none, -none, 0.0);
    var own = 0.0;
    var w = 0.0;
    if (lid < n) {
        own = values[lid];
        w = cloud_weights[lid];
    }
    var cumulative = w;
    for (var j = 0u; j < n; j = j + 1u) {
        let other = values[j];
        if (other < own || (other == own && j < lid)) {
            cumulative = cumulative + cloud_weights[j];
        }
    }
    if (lid < n && w > 0.0) {
        ends.z = own;
        ends.w = 1.0;
        if (cumulative >= LOWER_Q) {
            ends.x = own;
        }
        if (cumulative >= UPPER_Q) {
            ends.y = own;
        }
    }
    return reduce_ends(lid, ends);
}

// The interval's ends (as ranked_ends gives them) for offsets sorted in workgroup memory:
// `sort_len` entries, a power of two above LAG_WG, padded at +inf with weight 0. Each invocation
// takes a run of consecutive sorted entries: their cumulative weights from a scan of the runs'
// sums, then the first position reaching each quantile (positions, then the values there).
fn sorted_ends(lid: u32, sort_len: u32) -> vec4<f32> {
    let none = bitcast<f32>(0x7f800000u);
    bitonic_sort(lid, sort_len);
    let run = sort_len / LAG_WG;
    let first = lid * run;
    var own = 0.0;
    for (var c = 0u; c < run; c = c + 1u) {
        own = own + cloud_weights[first + c];
    }
    var cumulative = exclusive_scan(lid, own);
    var at = vec4<f32>(none, none, -1.0, 0.0);
    for (var c = 0u; c < run; c = c + 1u) {
        let w = cloud_weights[first + c];
        cumulative = cumulative + w;
        let position = f32(first + c);
        if (w > 0.0) {
            at.z = position;
            at.w = 1.0;
            if (cumulative >= LOWER_Q) {
                at.x = min(at.x, position);
            }
            if (cumulative >= UPPER_Q) {
                at.y = min(at.y, position);
            }
        }
    }
    at = reduce_ends(lid, at);
    let last = values[u32(max(at.z, 0.0))];
    var ends = vec4<f32>(none, none, last, at.w);
    if (at.x != none) {
        ends.x = values[u32(at.x)];
    }
    if (at.y != none) {
        ends.y = values[u32(at.y)];
    }
    workgroupBarrier();
    return ends;
}

// (sum w)^2 / sum w^2 of the n weights w in cloud_weights.
fn weights_ess(lid: u32, n: u32) -> f32 {
    var s1 = 0.0;
    var s2 = 0.0;
    for (var m = lid; m < n; m = m + LAG_WG) {
        let w = cloud_weights[m];
        s1 = s1 + w;
        s2 = s2 + w * w;
    }
    let sums = reduce_pair(lid, vec2<f32>(s1, s2));
    let sum = sums.x;
    let squares = sums.y;
    if (squares == 0.0) {
        return 0.0;
    }
    return sum * sum / squares;
}

// Target t's newest particle m's ancestor in the lagged frame (n, past the particles, where
// the trace meets a particle without an ancestor).
fn lagged_ancestor(t: u32, m: u32, n: u32) -> u32 {
    var a = lineage[t * params.particles + m];
    for (var k = 1u; k < lag_params.lag && a < n; k = k + 1u) {
        a = window_lineage[particle_at(ring_slot(k), t, a)];
    }
    return min(a, n);
}

// The effective sample size of the lagged frame's traced weights, each lagged particle's the
// sum of its descendants' (in FIXED_ONE units in ancestor_weight, whose ancestors it replaces):
// where the ancestors do not rise, so that one ancestor's descendants may be several runs.
fn traced_ess(lid: u32, t: u32, n: u32) -> f32 {
    for (var m = lid; m < n; m = m + LAG_WG) {
        atomicStore(&ancestor_weight[m], 0u);
    }
    workgroupBarrier();
    for (var m = lid; m < n; m = m + LAG_WG) {
        let w = newest_weight(t, m);
        atomicAdd(&ancestor_weight[lagged_ancestor(t, m, n)], u32(round(w * FIXED_ONE)));
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
    for (var m = lid; m < n; m = m + LAG_WG) {
        var a = lagged_ancestor(t, m, n);
        if (a == n) {
            atomicStore(&broken, 1u);
            a = 0u;
        }
        cloud_weights[m] = newest_weight(t, m);
        var value = 0.0;
        if (!sharing) {
            value = state_at(lagged, t, d, a);
        }
        values[m] = value;
        atomicStore(&ancestor_weight[m], a);
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
            window_log_weights[into * n + m] = log_weights[t * n + m];
            window_lineage[into * n + m] = lineage[t * n + m];
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
