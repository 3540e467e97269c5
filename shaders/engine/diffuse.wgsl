// Diffusion: every particle moved by the layer's dynamics (moved_value, move_particle.wgsl). One
// invocation per (particle, target).
// CPU twin: pf_core::batch::diffuse (with pf_core::anneal::Annealing::layer_sigma).

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read_write> states: array<f32>;
// [layer * D + d] (pf_core::anneal::Annealing::layer_sigma per layer).
@group(0) @binding(2) var<storage, read> sigma: array<f32>;
@group(0) @binding(3) var<storage, read> lower: array<f32>;
@group(0) @binding(4) var<storage, read> upper: array<f32>;
@group(0) @binding(5) var<storage, read> diffusion_keys: array<vec2<u32>>;
// The constant-velocity drift [t * D + d], added in the first annealing layer when the gain is
// set (pf_core::batch::add_drift).
@group(0) @binding(6) var<storage, read> velocity: array<f32>;

@compute @workgroup_size(64)
fn diffuse(@builtin(global_invocation_id) gid: vec3<u32>) {
    let m = gid.x;
    let t = gid.y;
    if (m >= params.particles || t >= params.targets) {
        return;
    }
    let step = vec2<u32>(params.step_lo, params.step_hi);
    for (var d = 0u; d < params.dims; d = d + 1u) {
        let i = state_index(t, d, m);
        states[i] = moved_value(t, d, m, states[i], step);
    }
}
