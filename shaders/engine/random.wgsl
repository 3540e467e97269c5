// Counter-based random numbers as a stage of their own: raw Philox4x32-10 blocks for a list of
// counters, and standard normal draws for a (particle, dimension) grid. philox.wgsl is prepended.
// CPU twins: pf_core::random::{philox4x32_10, counter_gaussian}.

struct RandomParams {
    key: vec2<u32>,
    count: u32,
    dims: u32,
    step_lo: u32,
    step_hi: u32,
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<uniform> random_params: RandomParams;
@group(0) @binding(1) var<storage, read> counters: array<vec4<u32>>;
@group(0) @binding(2) var<storage, read_write> words: array<vec4<u32>>;
@group(0) @binding(3) var<storage, read_write> normals: array<f32>;

@compute @workgroup_size(64)
fn philox_blocks(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if (i < random_params.count) {
        words[i] = philox4x32_10(counters[i], random_params.key);
    }
}

// normals[m * dims + d] = counter_gaussian(key, m, d, step), for m < count.
@compute @workgroup_size(64)
fn gaussians(@builtin(global_invocation_id) gid: vec3<u32>) {
    let m = gid.x;
    if (m >= random_params.count) {
        return;
    }
    let step = vec2<u32>(random_params.step_lo, random_params.step_hi);
    for (var d = 0u; d < random_params.dims; d = d + 1u) {
        normals[m * random_params.dims + d] = counter_gaussian(random_params.key, m, d, step);
    }
}
