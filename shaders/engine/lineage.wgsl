// The particles' lineage through a frame: for each particle at the end of the frame, the index
// of its ancestor among the previous frame's particles (every annealing layer's resampling
// composed), what smoothing from the ancestry traces back (pf_core::smooth::ancestry). Recorded
// after each layer's resampling when the filter keeps a lineage. One invocation per (particle,
// target). CPU twin: pf_core::smooth::ancestry::compose (the CPU engine composes the same way in
// pf_core::batch::BatchFilter). The fused step composes it in its select instead where the adapter
// binds enough storage buffers (layer.wgsl, select_*_keeping_lineage): the same values.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> ancestors: array<u32>;
// The lineage so far (layers after the first) or each target's restart flag (the first layer).
@group(0) @binding(2) var<storage, read> before: array<u32>;
@group(0) @binding(3) var<storage, read_write> lineage: array<u32>;
// Each target's restart flag, cleared once the first layer has read it (its own dispatch, so no
// invocation of the first layer can see it cleared).
@group(0) @binding(4) var<storage, read_write> restarts: array<u32>;

// Layer 0: the ancestors themselves, or none for a target restarted since the last frame (its
// particles are new: they descend from no particle of the frame before).
@compute @workgroup_size(64)
fn first_layer(@builtin(global_invocation_id) gid: vec3<u32>) {
    let k = gid.x;
    let t = gid.y;
    let n = params.particles;
    if (k >= n || t >= params.targets) {
        return;
    }
    if (before[t] != 0u) {
        lineage[t * n + k] = NO_ANCESTOR;
    } else {
        lineage[t * n + k] = ancestors[t * n + k];
    }
}

// A later layer: each particle's ancestor's lineage.
@compute @workgroup_size(64)
fn later_layer(@builtin(global_invocation_id) gid: vec3<u32>) {
    let k = gid.x;
    let t = gid.y;
    let n = params.particles;
    if (k >= n || t >= params.targets) {
        return;
    }
    lineage[t * n + k] = before[t * n + ancestors[t * n + k]];
}

// After the first layer: the restarts have been taken into the lineage.
@compute @workgroup_size(64)
fn clear_restarts(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.x < params.targets) {
        restarts[gid.x] = 0u;
    }
}
