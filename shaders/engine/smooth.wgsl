// The marginal backward smoother (Doucet, Godsill & Andrieu 2000) on the GPU, one value at a time
// (the blocked smoother the trackers run, a block per value): for each entry of a backward step
// (a track's frame t, its frame t+1 and one value d),
//   w_{t|T}^i = w_t^i * sum_j s_j * f(x_{t+1}^j | x_t^i) / sum_k w_t^k * f(x_{t+1}^j | x_t^k)
// with f the value's Gaussian random walk after the frame's drift (the difference taken the short
// way round for an angle) and s the smoothed weights of frame t+1 for the same value.
// Two kernels a step: `predictive` (log sum_k w_t^k f(x_{t+1}^j | x_t^k), one invocation per j)
// then `reweigh` (one invocation per i). The smoothed weights are left unnormalised: the step
// keeps their sum (sum_i w_t^i f_ij / predictive_j = 1 for every j), and the host normalises.
// CPU twin: pf_core::smooth::backward_step with GaussianTransition::block(&[d]).
// Launcher: pf_gpu::smooth::GpuSmoother.

// Layouts: frames of every track one after another; states[(f * D + d) * M + m],
// log_weights[f * M + m], drift[f * D + d]; smoothed[slot * M + m], slot = f * D + d.
struct SmoothParams {
    particles: u32,
    dims: u32,
    _pad0: u32,
    _pad1: u32,
}

// One backward step of one value of one track.
struct SmoothEntry {
    current: u32,
    next: u32,
    dim: u32,
    angular: u32,
    // 1 / sigma of the value.
    inv_sigma: f32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> sp: SmoothParams;
@group(0) @binding(1) var<storage, read> entries: array<SmoothEntry>;
@group(0) @binding(2) var<storage, read> states: array<f32>;
@group(0) @binding(3) var<storage, read> log_weights: array<f32>;
@group(0) @binding(4) var<storage, read> drift: array<f32>;
@group(0) @binding(5) var<storage, read_write> smoothed: array<f32>;
@group(0) @binding(6) var<storage, read_write> log_predictive: array<f32>;

const SMOOTH_PI: f32 = 3.14159265358979;
const SMOOTH_TAU: f32 = 6.28318530717959;

// log f(y | x) up to a constant, x with its drift.
fn log_transition(e: SmoothEntry, x: f32, y: f32) -> f32 {
    var diff = y - x;
    if (e.angular == 1u) {
        diff = diff - SMOOTH_TAU * floor((diff + SMOOTH_PI) / SMOOTH_TAU);
    }
    let z = diff * e.inv_sigma;
    return -0.5 * z * z;
}

fn value_of(frame: u32, d: u32, m: u32) -> f32 {
    return states[(frame * sp.dims + d) * sp.particles + m];
}

fn is_minus_infinity(x: f32) -> bool {
    return bitcast<u32>(x) == 0xff800000u;
}

@compute @workgroup_size(64)
fn predictive(@builtin(global_invocation_id) gid: vec3<u32>) {
    let j = gid.x;
    let index = gid.y;
    let n = sp.particles;
    if (j >= n || index >= arrayLength(&entries)) {
        return;
    }
    let e = entries[index];
    let y = value_of(e.next, e.dim, j);
    let shift = drift[e.current * sp.dims + e.dim];
    // A streaming log-sum-exp over the current frame's particles.
    var top = bitcast<f32>(0xff800000u);
    var sum = 0.0;
    for (var k = 0u; k < n; k = k + 1u) {
        let lw = log_weights[e.current * n + k];
        if (is_minus_infinity(lw)) {
            continue;
        }
        let v = lw + log_transition(e, value_of(e.current, e.dim, k) + shift, y);
        if (v <= top) {
            sum = sum + exp(v - top);
        } else {
            sum = sum * exp(top - v) + 1.0;
            top = v;
        }
    }
    var result = top;
    if (!is_minus_infinity(top)) {
        result = top + log(sum);
    }
    log_predictive[index * n + j] = result;
}

@compute @workgroup_size(64)
fn reweigh(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    let index = gid.y;
    let n = sp.particles;
    if (i >= n || index >= arrayLength(&entries)) {
        return;
    }
    let e = entries[index];
    let out = (e.current * sp.dims + e.dim) * n + i;
    let lw = log_weights[e.current * n + i];
    if (is_minus_infinity(lw)) {
        smoothed[out] = 0.0;
        return;
    }
    let x = value_of(e.current, e.dim, i) + drift[e.current * sp.dims + e.dim];
    let next_slot = (e.next * sp.dims + e.dim) * n;
    var share = 0.0;
    for (var j = 0u; j < n; j = j + 1u) {
        let s = smoothed[next_slot + j];
        let p = log_predictive[index * n + j];
        if (s > 0.0 && !is_minus_infinity(p)) {
            share = share + s * exp(log_transition(e, x, value_of(e.next, e.dim, j)) - p);
        }
    }
    smoothed[out] = exp(lw) * share;
}
