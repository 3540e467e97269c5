// Shared declarations of the generic filter stages: the per-frame parameters and the float-bit
// tests. Prepended (after philox.wgsl) to every stage kernel. Layouts, T targets x M particles x D
// dimensions: states[(t * D + d) * M + m], per-particle buffers [t * M + m].

struct Params {
    targets: u32,
    particles: u32,
    dims: u32,
    // Bit d set: dimension d is an angle (wrapped to [-pi, pi), averaged on the circle). Only the
    // first 32 dimensions can be angles.
    angular_mask: u32,
    step_lo: u32,
    step_hi: u32,
    // 1: clamp diffused states to [lower, upper].
    has_bounds: u32,
    // Steps of the Metropolis resampler.
    metropolis_steps: u32,
    // Resample a target when ESS < threshold * M (a huge value: every step).
    ess_threshold: f32,
    // Particles averaged by the best-M' estimate.
    best: u32,
    // This annealing layer's exponent of the likelihood (used when survival_rate is 0).
    beta: f32,
    // > 0: choose beta so that ESS = survival_rate * M, at most max_beta (pf_core::anneal).
    survival_rate: f32,
    max_beta: f32,
    // This layer's diffusion scale: sigma_d * sigma_scale.
    sigma_scale: f32,
    // The constant-velocity gain (0: the random walk alone; pf_core::batch::Motion).
    velocity_gain: f32,
    // The annealing layer; the drift is added in layer 0 only.
    layer: u32,
}

// Per-target results of the normalisation.
struct TargetStats {
    max_log_weight: f32,
    log_sum_shifted: f32,
    ess: f32,
    // 0 ok, 1 every weight zero, 2 NaN log-weight, 3 +inf log-weight.
    status: u32,
    // The first particle with a NaN or +inf log-weight (0xffffffff when none).
    bad_particle: u32,
    // 1 when this target resampled at the start of the step (its last annealing layer).
    resampled: u32,
    // The exponent of the last layer's weighing.
    beta: f32,
    // log sum exp(lw + ll) at beta = 1 in layer 0: the frame's log evidence (pf_core's
    // frame_log_evidence); NaN / +inf / -inf for a NaN, a +inf, or every weight zero.
    log_evidence: f32,
}

const PI: f32 = 3.14159265358979;
const TAU: f32 = 6.28318530717959;

fn is_nan(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7fffffffu) > 0x7f800000u;
}

fn is_pos_inf(x: f32) -> bool {
    return bitcast<u32>(x) == 0x7f800000u;
}

fn is_neg_inf(x: f32) -> bool {
    return bitcast<u32>(x) == 0xff800000u;
}

fn is_angle(d: u32) -> bool {
    return d < 32u && ((params.angular_mask >> d) & 1u) == 1u;
}

fn wrap_angle(x: f32) -> f32 {
    return x - TAU * floor((x + PI) / TAU);
}

fn state_index(t: u32, d: u32, m: u32) -> u32 {
    return (t * params.dims + d) * params.particles + m;
}

// A particle that descends from no particle of the frame before (its target restarted): the
// lineage's mark, pf_core::smooth::ancestry::NO_ANCESTOR (lineage.wgsl, layer.wgsl).
const NO_ANCESTOR: u32 = 0xffffffffu;
