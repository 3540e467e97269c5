//! Seeded random streams.
//!
//! Two kinds of generator, both reproducible from one `u64` seed:
//!
//! - [`RandomStream`]: a sequential xoshiro256++ stream, one per (target, stage). It drives the
//!   initial particle cloud, the diffusion noise and the recovery re-initialisation.
//! - [`CounterUniforms`]: Philox4x32-10, a counter-based generator. A uniform is a pure function of
//!   (key, particle, draw), so a resampler can read any draw of any particle in any order, from
//!   any thread, and a GPU kernel can compute the very same bits. The resamplers take their
//!   uniforms through the [`UniformSource`] trait, which this implements.
//!
//! Streams of different targets and stages are derived by hashing (seed, target, stage) with
//! SplitMix64, the seeding function xoshiro's authors recommend; distinct inputs give
//! statistically independent streams.

use rand_core::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

/// The stage of a filter step a random stream belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Stage {
    /// Drawing the initial particle cloud.
    Init,
    /// Diffusion noise of the dynamics.
    Diffusion,
    /// Resampling uniforms.
    Resampling,
    /// Re-initialisation after a failed step.
    Recovery,
    /// Free for models that need their own stream (the number tells two such streams apart).
    Model(u32),
}

impl Stage {
    fn code(self) -> u64 {
        match self {
            Stage::Init => 1,
            Stage::Diffusion => 2,
            Stage::Resampling => 3,
            Stage::Recovery => 4,
            Stage::Model(k) => 0x1_0000_0000 | u64::from(k),
        }
    }
}

/// SplitMix64's output function: a bijective 64-bit mixer.
pub fn splitmix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The seed of part `part` of a run split over several engines (islands, shards): part 0 keeps
/// `seed`, so that a run of one part draws what an unsplit run draws; the others get seeds
/// mixed from it.
pub fn part_seed(seed: u64, part: usize) -> u64 {
    if part == 0 {
        seed
    } else {
        splitmix64(seed ^ (part as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15))
    }
}

/// The root of every random stream of a run: one seed, any number of (target, stage) streams.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RandomStreams {
    seed: u64,
}

impl RandomStreams {
    /// Streams derived from `seed`.
    pub fn new(seed: u64) -> Self {
        Self { seed }
    }

    /// The seed.
    pub fn seed(&self) -> u64 {
        self.seed
    }

    /// A 64-bit key unique to (seed, target, stage).
    pub fn key(&self, target: u32, stage: Stage) -> u64 {
        let a = splitmix64(self.seed);
        let b = splitmix64(a ^ (u64::from(target) << 20) ^ 0x5851_F42D_4C95_7F2D);
        splitmix64(b ^ stage.code())
    }

    /// The sequential stream of one target and stage.
    pub fn stream(&self, target: u32, stage: Stage) -> RandomStream {
        RandomStream::from_key(self.key(target, stage))
    }

    /// The counter-based uniforms of one target and stage at one filter step.
    pub fn counter_uniforms(&self, target: u32, stage: Stage, step: u64) -> CounterUniforms {
        CounterUniforms::new(key_words(self.key(target, stage)), step)
    }
}

/// A sequential xoshiro256++ stream with uniform and Gaussian draws.
#[derive(Debug, Clone)]
pub struct RandomStream {
    rng: Xoshiro256PlusPlus,
}

impl RandomStream {
    /// A stream from a 64-bit key (seeded through SplitMix64).
    pub fn from_key(key: u64) -> Self {
        Self {
            rng: Xoshiro256PlusPlus::seed_from_u64(key),
        }
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.rng.next_u64()
    }

    /// A uniform in [0, 1) with 53 random bits.
    pub fn uniform(&mut self) -> f64 {
        (self.rng.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// A standard normal draw (Box–Muller; one pair of uniforms per draw, so the stream position
    /// after k draws does not depend on how the draws were used).
    pub fn gaussian(&mut self) -> f64 {
        let u1 = 1.0 - self.uniform(); // (0, 1]: ln never sees 0
        let u2 = self.uniform();
        box_muller(u1, u2)
    }

    /// A standard Gaussian draw as f32.
    pub fn gaussian_f32(&mut self) -> f32 {
        self.gaussian() as f32
    }
}

/// Box–Muller's cosine branch: `u1` in (0, 1], `u2` in [0, 1).
pub fn box_muller(u1: f64, u2: f64) -> f64 {
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// Where a resampler gets its uniform numbers: a pure function of (particle, draw) with values in
/// [0, 1). Counter-based so that the parallel resamplers (Metropolis, rejection) stay
/// deterministic and so that a GPU kernel can be fed the same numbers.
pub trait UniformSource: Sync {
    /// The `draw`-th uniform of `particle`, in [0, 1).
    fn uniform(&self, particle: u32, draw: u32) -> f64;

    /// Draws `4·block … 4·block + 3` of `particle` at once (one Philox call for
    /// [`CounterUniforms`]); the same numbers as four calls of [`Self::uniform`].
    fn uniform4(&self, particle: u32, block: u32) -> [f64; 4] {
        let first = block.wrapping_mul(4);
        [0, 1, 2, 3].map(|lane| self.uniform(particle, first.wrapping_add(lane)))
    }
}

/// Any `Fn(particle, draw) -> u` is a uniform source; handy for fixed uniforms in tests.
impl<F: Fn(u32, u32) -> f64 + Sync> UniformSource for F {
    fn uniform(&self, particle: u32, draw: u32) -> f64 {
        self(particle, draw)
    }
}

const PHILOX_M0: u32 = 0xD251_1F53;
const PHILOX_M1: u32 = 0xCD9E_8D57;
const PHILOX_W0: u32 = 0x9E37_79B9;
const PHILOX_W1: u32 = 0xBB67_AE85;

/// Philox4x32-10 (Salmon et al., SC'11): 4 output words from a 4-word counter and a 2-word key.
pub fn philox4x32_10(counter: [u32; 4], key: [u32; 2]) -> [u32; 4] {
    let mut c = counter;
    let mut k = key;
    for round in 0..10 {
        if round > 0 {
            k[0] = k[0].wrapping_add(PHILOX_W0);
            k[1] = k[1].wrapping_add(PHILOX_W1);
        }
        let p0 = u64::from(PHILOX_M0) * u64::from(c[0]);
        let p1 = u64::from(PHILOX_M1) * u64::from(c[2]);
        let (hi0, lo0) = ((p0 >> 32) as u32, p0 as u32);
        let (hi1, lo1) = ((p1 >> 32) as u32, p1 as u32);
        c = [hi1 ^ c[1] ^ k[0], lo1, hi0 ^ c[3] ^ k[1], lo0];
    }
    c
}

/// `-2 ln(u)` for `u = ((word >> 8) + 1) / 2^24` in (0, 1]; near u = 1 the same series as the
/// WGSL twin (`shaders/engine/philox.wgsl`), so that both round alike.
pub fn minus_two_log_unit(word: u32) -> f64 {
    let u = f64::from((word >> 8) + 1) * (1.0 / 16_777_216.0);
    let v = 1.0 - u;
    if v < 0.015625 {
        2.0 * v * (1.0 + v * (0.5 + v * (1.0 / 3.0 + v * 0.25)))
    } else {
        -2.0 * u.ln()
    }
}

/// The counter-based standard normal draw of dimension `dim` of `particle` at `step`: Box–Muller
/// on lanes 2(dim % 2), 2(dim % 2) + 1 of Philox block `[particle, dim / 2, step]`. The CPU twin of
/// `counter_gaussian` in `shaders/engine/philox.wgsl` (24-bit uniforms, which f32 holds exactly).
pub fn counter_gaussian(key: [u32; 2], particle: u32, dim: u32, step: u64) -> f64 {
    let block = philox4x32_10([particle, dim / 2, step as u32, (step >> 32) as u32], key);
    if dim.is_multiple_of(2) {
        box_muller_words(block[0], block[1])
    } else {
        box_muller_words(block[2], block[3])
    }
}

/// The draws of dimensions `2·pair` and `2·pair + 1` at once, from their one Philox block:
/// `(counter_gaussian(.., 2·pair, ..), counter_gaussian(.., 2·pair + 1, ..))` for half the work.
pub fn counter_gaussian_pair(key: [u32; 2], particle: u32, pair: u32, step: u64) -> (f64, f64) {
    let block = philox4x32_10([particle, pair, step as u32, (step >> 32) as u32], key);
    (
        box_muller_words(block[0], block[1]),
        box_muller_words(block[2], block[3]),
    )
}

/// One Box–Muller draw (the cosine branch) from two 32-bit words, 24 bits of each used.
fn box_muller_words(w0: u32, w1: u32) -> f64 {
    let radius = minus_two_log_unit(w0).sqrt();
    let angle = std::f64::consts::TAU * (f64::from(w1 >> 8) * (1.0 / 16_777_216.0));
    radius * angle.cos()
}

/// Splits a 64-bit key into the two Philox key words (low, high).
pub fn key_words(key: u64) -> [u32; 2] {
    [key as u32, (key >> 32) as u32]
}

/// Counter-based uniforms: draw `d` of particle `i` at step `s` is lane `d % 4` of
/// Philox4x32-10(counter = [i, d / 4, s_lo, s_hi], key), scaled by 2^-32.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CounterUniforms {
    key: [u32; 2],
    step: u64,
}

impl CounterUniforms {
    /// Uniforms for `key` at filter step `step`.
    pub fn new(key: [u32; 2], step: u64) -> Self {
        Self { key, step }
    }

    /// The Philox key.
    pub fn key(&self) -> [u32; 2] {
        self.key
    }

    /// The filter step the uniforms belong to.
    pub fn step(&self) -> u64 {
        self.step
    }

    /// The raw 32-bit word behind [`UniformSource::uniform`].
    pub fn word(&self, particle: u32, draw: u32) -> u32 {
        let block = philox4x32_10(
            [
                particle,
                draw / 4,
                self.step as u32,
                (self.step >> 32) as u32,
            ],
            self.key,
        );
        block[(draw % 4) as usize]
    }
}

impl UniformSource for CounterUniforms {
    fn uniform(&self, particle: u32, draw: u32) -> f64 {
        f64::from(self.word(particle, draw)) * (1.0 / 4_294_967_296.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pair_of_draws_is_the_two_single_draws() {
        let mut rng = RandomStreams::new(5).stream(0, Stage::Model(0));
        for _ in 0..1000 {
            let key = [rng.next_u64() as u32, rng.next_u64() as u32];
            let (particle, pair, step) = (
                rng.next_u64() as u32,
                rng.next_u64() as u32 >> 1,
                rng.next_u64(),
            );
            let (a, b) = counter_gaussian_pair(key, particle, pair, step);
            assert_eq!(
                a.to_bits(),
                counter_gaussian(key, particle, 2 * pair, step).to_bits()
            );
            assert_eq!(
                b.to_bits(),
                counter_gaussian(key, particle, 2 * pair + 1, step).to_bits()
            );
        }
    }

    // Known-answer vectors of Random123 (tests/kat_vectors): counter, key, output.
    #[test]
    fn philox_matches_random123_known_answers() {
        assert_eq!(
            philox4x32_10([0; 4], [0; 2]),
            [0x6627e8d5, 0xe169c58d, 0xbc57ac4c, 0x9b00dbd8]
        );
        assert_eq!(
            philox4x32_10([u32::MAX; 4], [u32::MAX; 2]),
            [0x408f276d, 0x41c83b0e, 0xa20bc7c6, 0x6d5451fd]
        );
        assert_eq!(
            philox4x32_10(
                [0x243f6a88, 0x85a308d3, 0x13198a2e, 0x03707344],
                [0xa4093822, 0x299f31d0]
            ),
            [0xd16cfe09, 0x94fdcceb, 0x5001e420, 0x24126ea1]
        );
    }

    #[test]
    fn uniform4_gives_the_same_numbers_as_four_single_draws() {
        let u = RandomStreams::new(5).counter_uniforms(2, Stage::Resampling, 1 << 40);
        for block in [0u32, 1, 7, u32::MAX / 4] {
            let four = u.uniform4(9, block);
            for lane in 0..4 {
                assert_eq!(four[lane as usize], u.uniform(9, 4 * block + lane));
            }
        }
        let closure = |p: u32, d: u32| f64::from(p * 100 + d) / 1e6;
        assert_eq!(closure.uniform4(3, 2), [308e-6, 309e-6, 310e-6, 311e-6]);
    }

    #[test]
    fn counter_gaussian_has_unit_moments_and_a_smooth_log_near_one() {
        let key = [17, 4];
        let n = 100_000u32;
        let draws: Vec<f64> = (0..n).map(|i| counter_gaussian(key, i, i % 7, 3)).collect();
        let mean = draws.iter().sum::<f64>() / f64::from(n);
        let var = draws.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / f64::from(n);
        assert!(
            mean.abs() < 0.016 && (var - 1.0).abs() < 0.023,
            "mean {mean} var {var}"
        );
        // The series branch meets the log branch continuously.
        let edge = (((1.0 - 0.015625) * 16_777_216.0) as u32 - 1) << 8;
        let below = minus_two_log_unit(edge - 256);
        let above = minus_two_log_unit(edge + 256);
        let exact = -2.0 * (f64::from((edge >> 8) + 1) / 16_777_216.0).ln();
        assert!((minus_two_log_unit(edge) - exact).abs() < 1e-9);
        assert!(below > above);
        assert_eq!(minus_two_log_unit(u32::MAX), 0.0);
    }

    #[test]
    fn streams_of_different_targets_and_stages_differ() {
        let streams = RandomStreams::new(7);
        let first = |t, s| streams.stream(t, s).next_u64();
        assert_ne!(first(0, Stage::Diffusion), first(1, Stage::Diffusion));
        assert_ne!(first(0, Stage::Diffusion), first(0, Stage::Resampling));
        assert_eq!(first(3, Stage::Init), first(3, Stage::Init));
        assert_ne!(
            RandomStreams::new(8).stream(0, Stage::Init).next_u64(),
            first(0, Stage::Init)
        );
    }

    #[test]
    fn gaussian_draws_have_unit_moments() {
        let mut s = RandomStreams::new(11).stream(0, Stage::Diffusion);
        let n = 200_000;
        let draws: Vec<f64> = (0..n).map(|_| s.gaussian()).collect();
        let mean = draws.iter().sum::<f64>() / n as f64;
        let var = draws.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n as f64;
        // Standard errors: 1/sqrt(n) = 0.0022 for the mean, sqrt(2/n) = 0.0032 for the variance.
        assert!(mean.abs() < 0.011, "mean {mean}");
        assert!((var - 1.0).abs() < 0.016, "variance {var}");
    }

    #[test]
    fn counter_uniforms_are_in_range_and_roughly_uniform() {
        let u = RandomStreams::new(3).counter_uniforms(0, Stage::Resampling, 5);
        let mut bins = [0u32; 10];
        for i in 0..10_000u32 {
            for d in 0..4 {
                let x = u.uniform(i, d);
                assert!((0.0..1.0).contains(&x));
                bins[(x * 10.0) as usize] += 1;
            }
        }
        // 40 000 draws, 4 000 expected per bin, sd ≈ 60.
        for b in bins {
            assert!((3700..4300).contains(&b), "bins {bins:?}");
        }
    }
}
