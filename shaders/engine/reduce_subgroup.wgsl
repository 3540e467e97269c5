// The twin of reduce.wgsl through subgroup operations (the same functions, for the same
// callers), which pf_gpu::kernels::adapted_source puts in reduce.wgsl's place where the device
// has them (GpuContext::has_subgroups: the adapter's subgroups hold 4 to 256 invocations, so a
// workgroup of REDUCE_WG is whole subgroups, at most 64 of them).
// A reduction combines each subgroup's values in its registers (subgroupMax, subgroupAdd), its
// first lane writes the subgroup's result, and after one barrier every invocation
// combines the (8 on a GPU of 32-wide subgroups) results itself: one barrier a reduction where
// reduce.wgsl's tree takes five. Two arrays of results are used in turn, so that a reduction's
// writes never meet the reads of the one before it (every invocation has passed this reduction's
// barrier, so finished the one before, when the next writes again).
// The sums are taken in another order than reduce.wgsl's: the same values within rounding.

const REDUCE_WG: u32 = 256u;
const MAX_SUBGROUPS: u32 = 64u;

// The invocation's subgroup, its place in it, and the subgroups' count and size.
struct Lanes {
    @builtin(subgroup_id) subgroup: u32,
    @builtin(subgroup_invocation_id) lane: u32,
    @builtin(num_subgroups) subgroups: u32,
    @builtin(subgroup_size) size: u32,
}

var<private> lanes_here: Lanes;
// Which of the two arrays of results the next reduction writes.
var<private> reduce_turn: u32;

fn begin_lanes(lanes: Lanes) {
    lanes_here = lanes;
    reduce_turn = 0u;
}

var<workgroup> reduce_results: array<array<vec4<f32>, MAX_SUBGROUPS>, 2>;

// The array of results this reduction writes (the other one next time).
fn next_results() -> u32 {
    let turn = reduce_turn;
    reduce_turn = 1u - turn;
    return turn;
}

fn workgroup_max(lid: u32, value: f32) -> f32 {
    let turn = next_results();
    let here = subgroupMax(value);
    if (lanes_here.lane == 0u) {
        reduce_results[turn][lanes_here.subgroup].x = here;
    }
    workgroupBarrier();
    var result = reduce_results[turn][0].x;
    for (var s = 1u; s < lanes_here.subgroups; s = s + 1u) {
        result = max(result, reduce_results[turn][s].x);
    }
    return result;
}

fn workgroup_sum(lid: u32, value: f32) -> f32 {
    let turn = next_results();
    let here = subgroupAdd(value);
    if (lanes_here.lane == 0u) {
        reduce_results[turn][lanes_here.subgroup].x = here;
    }
    workgroupBarrier();
    var result = reduce_results[turn][0].x;
    for (var s = 1u; s < lanes_here.subgroups; s = s + 1u) {
        result = result + reduce_results[turn][s].x;
    }
    return result;
}

// The invocations' (max, sum exp(x - max), sum exp(2 (x - max))) triples merged into the
// workgroup's: its max and both sums shifted to it (each subgroup's at the subgroup's max, then
// the subgroups' at theirs).
fn workgroup_shifted_sums(lid: u32, triple: vec3<f32>) -> vec3<f32> {
    let turn = next_results();
    let subgroup_max = subgroupMax(triple.x);
    var shifted = vec2<f32>(0.0, 0.0);
    if (!is_neg_inf(subgroup_max)) {
        shifted = shifted_to(triple, subgroup_max);
    }
    let sums = subgroupAdd(shifted);
    if (lanes_here.lane == 0u) {
        reduce_results[turn][lanes_here.subgroup] = vec4<f32>(subgroup_max, sums, 0.0);
    }
    workgroupBarrier();
    var m = reduce_results[turn][0].x;
    for (var s = 1u; s < lanes_here.subgroups; s = s + 1u) {
        m = max(m, reduce_results[turn][s].x);
    }
    if (is_neg_inf(m)) {
        return vec3<f32>(m, 0.0, 0.0);
    }
    var total = vec2<f32>(0.0, 0.0);
    for (var s = 0u; s < lanes_here.subgroups; s = s + 1u) {
        total = total + shifted_to(reduce_results[turn][s].xyz, m);
    }
    return vec3<f32>(m, total);
}

// The invocation's place in workgroup_scan's order: its subgroup's block, its lane within it
// (whatever order the device gives the subgroups their local indices in).
fn scan_place(lid: u32) -> u32 {
    return lanes_here.subgroup * lanes_here.size + lanes_here.lane;
}

// (the sum of `value` over the places before this invocation's, the sum over all): each
// subgroup's exclusive scan, and the subgroups before it from their totals.
fn workgroup_scan(lid: u32, value: f32) -> vec2<f32> {
    let turn = next_results();
    let within = subgroupExclusiveAdd(value);
    let subgroup_total = subgroupAdd(value);
    if (lanes_here.lane == 0u) {
        reduce_results[turn][lanes_here.subgroup].x = subgroup_total;
    }
    workgroupBarrier();
    var before = 0.0;
    var total = 0.0;
    for (var s = 0u; s < lanes_here.subgroups; s = s + 1u) {
        let sum = reduce_results[turn][s].x;
        if (s < lanes_here.subgroup) {
            before = before + sum;
        }
        total = total + sum;
    }
    return vec2<f32>(before + within, total);
}
