// The toy likelihood of the tests and benchmarks: a Gaussian around each target's observed state,
// log p = -1/2 sum_d ((x_d - z_d) / sigma_d)^2, angle differences taken the short way round.
// One invocation per (particle, target). CPU twin: pf_core::GaussianObservation.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> states: array<f32>;
@group(0) @binding(2) var<storage, read_write> log_likelihood: array<f32>;
@group(0) @binding(3) var<storage, read> observed: array<f32>;
@group(0) @binding(4) var<storage, read> inv_sigma: array<f32>;

@compute @workgroup_size(64)
fn gaussian_log_likelihood(@builtin(global_invocation_id) gid: vec3<u32>) {
    let m = gid.x;
    let t = gid.y;
    if (m >= params.particles || t >= params.targets) {
        return;
    }
    var sum = 0.0;
    for (var d = 0u; d < params.dims; d = d + 1u) {
        var diff = states[state_index(t, d, m)] - observed[t * params.dims + d];
        if (is_angle(d)) {
            diff = wrap_angle(diff);
        }
        let z = diff * inv_sigma[d];
        sum = sum + z * z;
    }
    log_likelihood[t * params.particles + m] = -0.5 * sum;
}
