// Log-weight normalisation per target, one workgroup per target: the stage of the staged step
// (the fused step settles its last layer with layer.wgsl's settle_last_layer). The work is
// normalise_target (normalise_target.wgsl).
// CPU twin: pf_core::batch::normalise_target.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read_write> log_weights: array<f32>;
@group(0) @binding(2) var<storage, read> log_likelihood: array<f32>;
@group(0) @binding(3) var<storage, read_write> weights: array<f32>;
@group(0) @binding(4) var<storage, read_write> stats: array<TargetStats>;

// Where normalise_target reads and keeps its values: this stage's storage buffers (any M; the
// fused layer's kernel keeps copies in workgroup memory).
fn prior_at(base: u32, i: u32) -> f32 {
    return log_weights[base + i];
}

fn likelihood_at(base: u32, i: u32) -> f32 {
    return log_likelihood[base + i];
}

// The tempered log-weights in place of the log-weights (pass 3 overwrites them normalised).
fn set_tempered(base: u32, i: u32, value: f32) {
    log_weights[base + i] = value;
}

fn tempered_at(base: u32, i: u32) -> f32 {
    return log_weights[base + i];
}

// The weights are in `weights` already.
fn keep_weight(base: u32, i: u32, w: f32) {}

@compute @workgroup_size(256)
fn normalise(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    normalise_target(lid.x, wid.y, params);
}
