// Point estimates per target from the normalised weights: the weighted mean of every dimension
// (angles as the mean of unit vectors, atan2(sum w sin, sum w cos)). One workgroup per target.
// CPU twin: pf_core::estimate::weighted_mean.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> states: array<f32>;
@group(0) @binding(2) var<storage, read> weights: array<f32>;
@group(0) @binding(3) var<storage, read_write> estimates: array<f32>;

const WG: u32 = 256u;
var<workgroup> partial_a: array<f32, 256>;
var<workgroup> partial_b: array<f32, 256>;

fn reduce_pair(lid: u32, a: f32, b: f32) -> vec2<f32> {
    partial_a[lid] = a;
    partial_b[lid] = b;
    workgroupBarrier();
    for (var stride = WG / 2u; stride > 0u; stride = stride / 2u) {
        if (lid < stride) {
            partial_a[lid] = partial_a[lid] + partial_a[lid + stride];
            partial_b[lid] = partial_b[lid] + partial_b[lid + stride];
        }
        workgroupBarrier();
    }
    let result = vec2<f32>(partial_a[0], partial_b[0]);
    workgroupBarrier();
    return result;
}

@compute @workgroup_size(256)
fn weighted_mean(@builtin(local_invocation_id) lid3: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    let lid = lid3.x;
    let t = wid.y;
    let n = params.particles;
    for (var d = 0u; d < params.dims; d = d + 1u) {
        let angle = is_angle(d);
        var a = 0.0;
        var b = 0.0;
        for (var i = lid; i < n; i = i + WG) {
            let w = weights[t * n + i];
            let x = states[state_index(t, d, i)];
            if (angle) {
                a = a + w * sin(x);
                b = b + w * cos(x);
            } else {
                a = a + w * x;
                b = b + w;
            }
        }
        let sums = reduce_pair(lid, a, b);
        if (lid == 0u) {
            var value = 0.0;
            if (angle) {
                value = atan2(sums.x, sums.y);
            } else if (sums.y > 0.0) {
                value = sums.x / sums.y;
            }
            estimates[t * params.dims + d] = value;
        }
    }
}
