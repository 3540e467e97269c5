// Counter-based random numbers: Philox4x32-10 (Salmon et al., SC'11) and the draws built on it.
// A library, prepended to the kernels that draw random numbers. Its CPU twin is
// pf_core::random (philox4x32_10, counter_gaussian), which gives the same bits.

// The high and low 32 bits of a 32x32-bit product, from 16-bit halves (WGSL has no u64).
fn mulhilo(a: u32, b: u32) -> vec2<u32> {
    let a_lo = a & 0xffffu;
    let a_hi = a >> 16u;
    let b_lo = b & 0xffffu;
    let b_hi = b >> 16u;
    let ll = a_lo * b_lo;
    let lh = a_lo * b_hi;
    let hl = a_hi * b_lo;
    let hh = a_hi * b_hi;
    let mid = (ll >> 16u) + (lh & 0xffffu) + (hl & 0xffffu);
    let lo = (ll & 0xffffu) | (mid << 16u);
    let hi = hh + (lh >> 16u) + (hl >> 16u) + (mid >> 16u);
    return vec2<u32>(hi, lo);
}

fn philox4x32_10(counter: vec4<u32>, key: vec2<u32>) -> vec4<u32> {
    var c = counter;
    var k = key;
    for (var round = 0u; round < 10u; round = round + 1u) {
        if (round > 0u) {
            k = k + vec2<u32>(0x9E3779B9u, 0xBB67AE85u);
        }
        let p0 = mulhilo(0xD2511F53u, c.x);
        let p1 = mulhilo(0xCD9E8D57u, c.z);
        c = vec4<u32>(p1.x ^ c.y ^ k.x, p1.y, p0.x ^ c.w ^ k.y, p0.y);
    }
    return c;
}

// A uniform index in 0..n: floor(word * n / 2^32), exact in integers.
fn uniform_index(word: u32, n: u32) -> u32 {
    return mulhilo(word, n).x;
}

// A word as a uniform in [0, 1) (rounded to f32).
fn unit_from_word(word: u32) -> f32 {
    return f32(word) * 2.3283064365386963e-10;
}

// -2 ln(u) for u = ((word >> 8) + 1) / 2^24 in (0, 1]. Near u = 1 the series of -ln(1 - v) keeps
// the result accurate where a hardware log's absolute error would dominate.
fn minus_two_log_unit(word: u32) -> f32 {
    let u = f32((word >> 8u) + 1u) * 5.9604644775390625e-8;
    let v = 1.0 - u;
    if (v < 0.015625) {
        return 2.0 * v * (1.0 + v * (0.5 + v * (0.33333334 + v * 0.25)));
    }
    return -2.0 * log(u);
}

// The standard normal draw of dimension `dim` of `particle` at `step` (Box-Muller on lanes
// 2(dim % 2) and 2(dim % 2) + 1 of block dim / 2).
fn counter_gaussian(key: vec2<u32>, particle: u32, dim: u32, step: vec2<u32>) -> f32 {
    return gaussian_of_block(gaussian_block(key, particle, dim, step), dim);
}

// The Philox block that dimensions 2j and 2j + 1 (j = dim / 2) of `particle` draw from at `step`:
// a kernel moving both dimensions of a pair computes it once.
fn gaussian_block(key: vec2<u32>, particle: u32, dim: u32, step: vec2<u32>) -> vec4<u32> {
    return philox4x32_10(vec4<u32>(particle, dim / 2u, step.x, step.y), key);
}

// Dimension `dim`'s standard normal draw from its pair's block (counter_gaussian's second half).
fn gaussian_of_block(block: vec4<u32>, dim: u32) -> f32 {
    var w0 = block.x;
    var w1 = block.y;
    if ((dim & 1u) == 1u) {
        w0 = block.z;
        w1 = block.w;
    }
    let radius = sqrt(minus_two_log_unit(w0));
    let angle = 6.283185307179586 * (f32(w1 >> 8u) * 5.9604644775390625e-8);
    return radius * cos(angle);
}
