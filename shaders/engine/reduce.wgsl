// Reductions and a scan over a workgroup of REDUCE_WG invocations, in workgroup memory with
// barriers: the engine's one-workgroup-a-target kernels (normalise_target.wgsl,
// resample_target.wgsl) call these. A library with a twin of the same functions,
// reduce_subgroup.wgsl, which pf_gpu::kernels puts in its place where the device has subgroup
// operations (GpuContext::has_subgroups). Both take the invocation's place from the entry point:
// it declares a `lanes: Lanes` parameter and calls begin_lanes(lanes) first.
// Every function is called by every invocation of the workgroup, in uniform control flow.
//
// Each reduction is a tree of four-way steps (strides 64, 16, 4, 1: four barriers and a closing
// one, where halving steps take nine): one target's workgroup runs alone on its SM when a frame
// has few targets, and there a reduction's time is its chain of dependent steps, each a barrier
// and a round trip to workgroup memory; a four-way step's four loads are in flight together.
// (Folding 16 values a step in a loop measured twice as slow.)

const REDUCE_WG: u32 = 256u;
// The four-way steps cover every invocation only when REDUCE_WG is a power of four.
const_assert ((REDUCE_WG & (REDUCE_WG - 1u)) == 0u && (REDUCE_WG & 0x55555555u) != 0u);

// What this library needs of the invocation: nothing beyond its local index (a builtin no
// kernel of the engine declares otherwise, to keep the entry points' signatures one).
struct Lanes {
    @builtin(num_workgroups) unused: vec3<u32>,
}

fn begin_lanes(lanes: Lanes) {}

var<workgroup> reduce_partial: array<f32, 256>;
var<workgroup> reduce_partial_ess: array<vec3<f32>, 256>;
// The scan's two halves, one read while the other is written: one barrier a step.
var<workgroup> reduce_scan: array<array<f32, 256>, 2>;

fn workgroup_max(lid: u32, value: f32) -> f32 {
    reduce_partial[lid] = value;
    workgroupBarrier();
    for (var stride = REDUCE_WG / 4u; stride > 0u; stride = stride / 4u) {
        if (lid < stride) {
            reduce_partial[lid] = max(
                max(reduce_partial[lid], reduce_partial[lid + stride]),
                max(reduce_partial[lid + 2u * stride], reduce_partial[lid + 3u * stride]),
            );
        }
        workgroupBarrier();
    }
    let result = reduce_partial[0];
    workgroupBarrier();
    return result;
}

fn workgroup_sum(lid: u32, value: f32) -> f32 {
    reduce_partial[lid] = value;
    workgroupBarrier();
    for (var stride = REDUCE_WG / 4u; stride > 0u; stride = stride / 4u) {
        if (lid < stride) {
            reduce_partial[lid] = (reduce_partial[lid] + reduce_partial[lid + stride])
                + (reduce_partial[lid + 2u * stride] + reduce_partial[lid + 3u * stride]);
        }
        workgroupBarrier();
    }
    let result = reduce_partial[0];
    workgroupBarrier();
    return result;
}

// Four (max, s1, s2) triples merged into one at their largest max: the max first, then the four
// exponentials independent of each other (merging pairwise would chain them).
fn merge_four(a: vec3<f32>, b: vec3<f32>, c: vec3<f32>, d: vec3<f32>) -> vec3<f32> {
    let m = max(max(a.x, b.x), max(c.x, d.x));
    if (is_neg_inf(m)) {
        return vec3<f32>(m, 0.0, 0.0);
    }
    let sums = (shifted_to(a, m) + shifted_to(b, m)) + (shifted_to(c, m) + shifted_to(d, m));
    return vec3<f32>(m, sums);
}

// The invocations' (max, sum exp(x - max), sum exp(2 (x - max))) triples merged into the
// workgroup's: its max and both sums shifted to it.
fn workgroup_shifted_sums(lid: u32, triple: vec3<f32>) -> vec3<f32> {
    reduce_partial_ess[lid] = triple;
    workgroupBarrier();
    for (var stride = REDUCE_WG / 4u; stride > 0u; stride = stride / 4u) {
        if (lid < stride) {
            reduce_partial_ess[lid] = merge_four(
                reduce_partial_ess[lid],
                reduce_partial_ess[lid + stride],
                reduce_partial_ess[lid + 2u * stride],
                reduce_partial_ess[lid + 3u * stride],
            );
        }
        workgroupBarrier();
    }
    let total = reduce_partial_ess[0];
    workgroupBarrier();
    return total;
}

// The invocation's place in workgroup_scan's order (each place owned by one invocation).
fn scan_place(lid: u32) -> u32 {
    return lid;
}

// (the sum of `value` over the places before this invocation's, the sum over all): Hillis-Steele,
// each step reading one half of reduce_scan and writing the other.
fn workgroup_scan(lid: u32, value: f32) -> vec2<f32> {
    reduce_scan[0][lid] = value;
    workgroupBarrier();
    var source = 0u;
    for (var offset = 1u; offset < REDUCE_WG; offset = offset * 2u) {
        var scanned = reduce_scan[source][lid];
        if (lid >= offset) {
            scanned = scanned + reduce_scan[source][lid - offset];
        }
        reduce_scan[1u - source][lid] = scanned;
        workgroupBarrier();
        source = 1u - source;
    }
    var before = 0.0;
    if (lid > 0u) {
        before = reduce_scan[source][lid - 1u];
    }
    let result = vec2<f32>(before, reduce_scan[source][REDUCE_WG - 1u]);
    workgroupBarrier();
    return result;
}
