// The lag window's ring (pf_gpu::filter::lag_window): a whole step's particles, normalised
// log-weights and lineage copied into ring slot `newest`, as a dispatch in the compute pass that
// ends the step (the fused step's own, or the lag window's after a staged step), where three
// buffer copies took transfers of their own between the step's pass and the summary's (the
// summary started 25 µs after the four-face step's estimate ended on an NVIDIA H200, copies back
// included). One invocation a value of a particle (x) of target t (y); the first M of each
// target also copy its particles' log-weights and ancestors. Layouts: states
// [(t * D + d) * M + m], the ring's [((slot * T + t) * D + d) * M + m]; log-weights and
// lineage [t * M + m], the ring's [(slot * T + t) * M + m] (as lag_summary.wgsl reads them).

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<uniform> lag_params: LagParams;
@group(0) @binding(2) var<storage, read> states: array<f32>;
@group(0) @binding(3) var<storage, read> log_weights: array<f32>;
@group(0) @binding(4) var<storage, read> lineage: array<u32>;
@group(0) @binding(5) var<storage, read_write> window_states: array<f32>;
@group(0) @binding(6) var<storage, read_write> window_log_weights: array<f32>;
@group(0) @binding(7) var<storage, read_write> window_lineage: array<u32>;

@compute @workgroup_size(256)
fn keep_newest(@builtin(global_invocation_id) gid: vec3<u32>) {
    let block = params.dims * params.particles;
    let t = gid.y;
    let x = gid.x;
    if (x >= block || t >= params.targets) {
        return;
    }
    let into = lag_params.newest * params.targets + t;
    window_states[into * block + x] = states[t * block + x];
    if (x < params.particles) {
        window_log_weights[into * params.particles + x] = log_weights[t * params.particles + x];
        window_lineage[into * params.particles + x] = lineage[t * params.particles + x];
    }
}
