// The lag summary's statistics of a weighted cloud in workgroup memory (a library between
// lag_params.wgsl and lag_summary.wgsl, which declares SORT_SIZE, sized by the driver): the
// workgroup's reductions and scan, the weighted mean and the 95 % interval (summarise), and the
// effective sample size. One workgroup of LAG_WG invocations a cloud; n, the cloud's entries,
// is the same in every invocation.
// CPU twin: pf_core::smooth::summary (summarise_value), pf_core::weights (the ESS).

const LAG_WG: u32 = 256u;
const LOWER_Q: f32 = 0.025;
const UPPER_Q: f32 = 0.975;

// The cloud being summarised: each particle's value (then its offset from the mean, sorted)
// and weight; padding at +inf with weight 0.
var<workgroup> values: array<f32, SORT_SIZE>;
var<workgroup> cloud_weights: array<f32, SORT_SIZE>;
var<workgroup> partial: array<f32, 256>;
// Several reductions at once (reduce_pair, reduce_ends): one reduction's barriers for two or
// three values.
var<workgroup> partial4: array<vec4<f32>, 256>;
// exclusive_scan's second array.
var<workgroup> scan_other: array<f32, 256>;

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
// entry is weighed, else 0), as sorted_ends does. One loop and one reduction where a
// bitonic sort of 64 entries takes 21 barriers and the scan of their weights six more.
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
