// Moving one particle's value in one dimension by the layer's dynamics: layer 0's
// constant-velocity drift (when the gain is set), then x_d += (sigma_ld * s) * n (sigma_ld: the
// layer's sigma of dimension d, 0 where a partitioned layer keeps d still; s: the annealing layer's
// scale, 1 without), n ~ N(0, 1) from counter_gaussian(key_t, m, d, step); optional clamping to
// [lower, upper]; angle dimensions wrapped.
// A library: the including kernel declares params, sigma, lower, upper, diffusion_keys and
// velocity (diffuse.wgsl for the stage, layer.wgsl for the fused layer).
// CPU twins: pf_core::batch::diffuse (with pf_core::anneal::Annealing::layer_sigma) and
// pf_core::batch::add_drift.

fn moved_value(t: u32, d: u32, m: u32, value: f32, step: vec2<u32>) -> f32 {
    return moved_by(t, d, value, counter_gaussian(diffusion_keys[t], m, d, step));
}

// moved_value with the standard normal draw n given (the fused layer draws a pair of
// dimensions' from one Philox block).
fn moved_by(t: u32, d: u32, value: f32, n: f32) -> f32 {
    var x = value;
    if (params.velocity_gain > 0.0 && params.layer == 0u) {
        x = x + velocity[t * params.dims + d];
    }
    let sigma_d = sigma[params.layer * params.dims + d];
    x = x + (sigma_d * params.sigma_scale) * n;
    // A NaN state stays NaN (clamp would turn it into a bound), so the failure policy sees it.
    if (params.has_bounds == 1u && !is_nan(x)) {
        x = clamp(x, lower[d], upper[d]);
    }
    if (is_angle(d)) {
        x = wrap_angle(x);
    }
    return x;
}
