// Selection: the states of each target's ancestors into a second buffer (copied back by the
// driver), and equal log-weights -ln M for the targets that resampled. One invocation per
// (offspring, target). CPU twin: pf_core::ParticleSet::select.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> states: array<f32>;
@group(0) @binding(2) var<storage, read_write> selected: array<f32>;
@group(0) @binding(3) var<storage, read> ancestors: array<u32>;
@group(0) @binding(4) var<storage, read> stats: array<TargetStats>;
@group(0) @binding(5) var<storage, read_write> log_weights: array<f32>;

@compute @workgroup_size(64)
fn gather(@builtin(global_invocation_id) gid: vec3<u32>) {
    let k = gid.x;
    let t = gid.y;
    let n = params.particles;
    if (k >= n || t >= params.targets) {
        return;
    }
    let a = ancestors[t * n + k];
    for (var d = 0u; d < params.dims; d = d + 1u) {
        selected[state_index(t, d, k)] = states[state_index(t, d, a)];
    }
    if (stats[t].resampled == 1u) {
        log_weights[t * n + k] = -log(f32(n));
    }
}
