// Point estimates per target from the normalised weights: the weighted mean of every dimension
// (angles as the mean of unit vectors, atan2(sum w sin, sum w cos)), and the posterior's spread
// about it: the weighted standard deviation, or for an angle the circular one, sqrt(-2 ln R) with
// R the length of the weighted mean unit vector. One workgroup per (dimension, target): a target's
// dimensions are independent sums, so they run side by side on as many SMs (the same sums in the
// same order as one workgroup looping over them).
// CPU twins: pf_core::batch::weighted_means and pf_core::batch::weighted_means_and_spreads.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> states: array<f32>;
@group(0) @binding(2) var<storage, read> weights: array<f32>;
@group(0) @binding(3) var<storage, read_write> estimates: array<f32>;
@group(0) @binding(5) var<storage, read_write> spreads: array<f32>;
// The constant-velocity drift and the estimates it is the difference of (NaN: none yet); updated
// only when params.velocity_gain > 0. CPU twin: pf_core::batch::update_velocity.
@group(0) @binding(6) var<storage, read_write> velocity: array<f32>;
@group(0) @binding(7) var<storage, read_write> previous_estimates: array<f32>;

const WG: u32 = 256u;
// The reductions take four-way steps (strides 64, 16, 4, 1), as the normalisation's do: a
// target's estimate runs alone on its SM when a frame has few targets, and there its time is
// its chain of barriers and workgroup-memory round trips.
const_assert ((WG & (WG - 1u)) == 0u && (WG & 0x55555555u) != 0u);
var<workgroup> partial_pair: array<vec2<f32>, 256>;

fn reduce_pair(lid: u32, a: f32, b: f32) -> vec2<f32> {
    partial_pair[lid] = vec2<f32>(a, b);
    workgroupBarrier();
    for (var stride = WG / 4u; stride > 0u; stride = stride / 4u) {
        if (lid < stride) {
            partial_pair[lid] = (partial_pair[lid] + partial_pair[lid + stride])
                + (partial_pair[lid + 2u * stride] + partial_pair[lid + 3u * stride]);
        }
        workgroupBarrier();
    }
    let result = partial_pair[0];
    workgroupBarrier();
    return result;
}

// The two sums one particle adds: (w sin x, w cos x) for an angle, (w x, w) otherwise.
fn mean_terms(angle: bool, w: f32, x: f32) -> vec2<f32> {
    if (angle) {
        return vec2<f32>(w * sin(x), w * cos(x));
    }
    return vec2<f32>(w * x, w);
}

// The mean from the reduced sums: atan2 for an angle, the weighted average otherwise.
fn mean_from_sums(angle: bool, sums: vec2<f32>) -> f32 {
    if (angle) {
        return atan2(sums.x, sums.y);
    }
    if (sums.y > 0.0) {
        return sums.x / sums.y;
    }
    return 0.0;
}

@compute @workgroup_size(256)
fn weighted_mean(@builtin(local_invocation_id) lid3: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    let lid = lid3.x;
    let t = wid.y;
    let n = params.particles;
    let d = wid.x;
    if (d >= params.dims) {
        return;
    }
    {
        let angle = is_angle(d);
        var acc = vec2<f32>(0.0);
        for (var i = lid; i < n; i = i + WG) {
            acc = acc + mean_terms(angle, weights[t * n + i], states[state_index(t, d, i)]);
        }
        let sums = reduce_pair(lid, acc.x, acc.y);
        let mean = mean_from_sums(angle, sums);
        if (lid == 0u) {
            let k = t * params.dims + d;
            estimates[k] = mean;
            if (params.velocity_gain > 0.0) {
                let previous = previous_estimates[k];
                var v = 0.0;
                if (!is_nan(previous)) {
                    var delta = mean - previous;
                    if (angle) {
                        delta = wrap_angle(delta);
                    }
                    v = params.velocity_gain * delta;
                }
                velocity[k] = v;
                previous_estimates[k] = mean;
            }
        }
        if (angle) {
            if (lid == 0u) {
                spreads[t * params.dims + d] = circular_spread(length(sums));
            }
            return;
        }
        var sq = 0.0;
        for (var i = lid; i < n; i = i + WG) {
            let dx = states[state_index(t, d, i)] - mean;
            sq = sq + weights[t * n + i] * dx * dx;
        }
        let spread_sums = reduce_pair(lid, sq, 0.0);
        if (lid == 0u) {
            var spread = 0.0;
            if (sums.y > 0.0) {
                spread = sqrt(spread_sums.x / sums.y);
            }
            spreads[t * params.dims + d] = spread;
        }
    }
}

// The circular standard deviation sqrt(-2 ln R) of a mean resultant length R (the weights sum to
// one): 0 for one direction, growing without bound as the directions spread round the circle.
fn circular_spread(r: f32) -> f32 {
    return sqrt(-2.0 * log(clamp(r, 1e-30, 1.0)));
}

// ---- best-M' weighted mean (eq. 14 of the face paper) ------------------------------------------
// The weighted mean of the M' = params.best heaviest particles of each target, ties broken by the
// lower index. Non-negative f32 weights order like their bit patterns, so a 31-step bisection on
// the bits finds the M'-th largest weight tau with workgroup counts; the particles above tau are
// in, and the first (M' - count above) particles equal to tau in index order. One workgroup per
// (dimension, target), each finding tau for itself (the same tau) and summing its dimension; each
// invocation owns a contiguous chunk so that index order is chunk order.
// A radix select on the bits in its place (three bits a pass, eleven passes of a four-way
// reduction of eight counts, no atomics) took the estimate from 23.6 to 26.7 us of a one-face
// step on an NVIDIA H200: not kept (BENCHMARKS.md, "Four-way reductions"); nor the bisection's
// subtrees counted a pass (as the survival rule's search does, normalise_target.wgsl): 28.3-39.2
// us against 23.2 (BENCHMARKS.md, "The survival rule's search").
// CPU twin: pf_core::batch::best_weighted_means (pf_core::estimate::best_weighted_mean).

@group(0) @binding(4) var<storage, read_write> best_estimates: array<f32>;

var<workgroup> counter: atomic<u32>;
var<workgroup> tie_offsets: array<u32, 256>;

fn count_at_least(lid: u32, base: u32, begin: u32, end: u32, bits: u32) -> u32 {
    if (lid == 0u) {
        atomicStore(&counter, 0u);
    }
    workgroupBarrier();
    var local = 0u;
    for (var i = begin; i < end; i = i + 1u) {
        if (bitcast<u32>(weights[base + i]) >= bits) {
            local = local + 1u;
        }
    }
    atomicAdd(&counter, local);
    workgroupBarrier();
    let total = atomicLoad(&counter);
    workgroupBarrier();
    return total;
}

@compute @workgroup_size(256)
fn best_mean(@builtin(local_invocation_id) lid3: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    let lid = lid3.x;
    let t = wid.y;
    let d = wid.x;
    if (d >= params.dims) {
        return;
    }
    let n = params.particles;
    let base = t * n;
    let best = min(max(params.best, 1u), n);
    let chunk = (n + WG - 1u) / WG;
    let begin = min(lid * chunk, n);
    let end = min(begin + chunk, n);

    // Largest bit pattern tau with count(w >= tau) >= best.
    var lo = 0u;
    var hi = 0x7f800000u;
    while (lo < hi) {
        let mid = lo + (hi - lo + 1u) / 2u;
        if (count_at_least(lid, base, begin, end, mid) >= best) {
            lo = mid;
        } else {
            hi = mid - 1u;
        }
    }
    let tau = lo;
    let above = count_at_least(lid, base, begin, end, tau + 1u);
    let ties_needed = best - above;

    // Rank of each tie in index order: exclusive scan of the chunks' tie counts.
    var my_ties = 0u;
    for (var i = begin; i < end; i = i + 1u) {
        if (bitcast<u32>(weights[base + i]) == tau) {
            my_ties = my_ties + 1u;
        }
    }
    tie_offsets[lid] = my_ties;
    workgroupBarrier();
    for (var offset = 1u; offset < WG; offset = offset * 2u) {
        var add = 0u;
        if (lid >= offset) {
            add = tie_offsets[lid - offset];
        }
        workgroupBarrier();
        tie_offsets[lid] = tie_offsets[lid] + add;
        workgroupBarrier();
    }
    let first_tie_rank = tie_offsets[lid] - my_ties;

    {
        let angle = is_angle(d);
        var acc = vec2<f32>(0.0);
        var rank = first_tie_rank;
        for (var i = begin; i < end; i = i + 1u) {
            let bits = bitcast<u32>(weights[base + i]);
            var take = bits > tau;
            if (bits == tau) {
                take = rank < ties_needed;
                rank = rank + 1u;
            }
            if (take) {
                acc = acc + mean_terms(angle, weights[base + i], states[state_index(t, d, i)]);
            }
        }
        let sums = reduce_pair(lid, acc.x, acc.y);
        if (lid == 0u) {
            best_estimates[t * params.dims + d] = mean_from_sums(angle, sums);
        }
    }
}
