//! Counter-based random numbers that the CPU and the GPU draw identically.
//!
//! Every random number in training (sample jitter, inverse-CDF offsets, density noise, ray batch
//! indices) is a pure function of `(seed, step, stream, index)`, so a run is reproducible bit for
//! bit whatever the thread count, and the WGSL kernels (`shaders/rng.wgsl`) reproduce the same
//! numbers. The hash is PCG's output permutation (O'Neill 2014) applied in a chain, which passes
//! the usual avalanche tests for this use.

/// One round of the PCG-RXS-M-XS 32-bit permutation.
#[must_use]
#[inline]
pub const fn pcg_hash(x: u32) -> u32 {
    let state = x.wrapping_mul(747_796_405).wrapping_add(2_891_336_453);
    let word = ((state >> ((state >> 28) + 4)) ^ state).wrapping_mul(277_803_737);
    (word >> 22) ^ word
}

/// Which use a random stream serves; keeps the streams of one step independent.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u32)]
pub enum Stream {
    /// Stratified jitter of the coarse interval edges.
    SampleJitter = 1,
    /// Offsets of the fine level's inverse-CDF samples.
    ResampleOffsets = 2,
    /// Gaussian noise added to the raw density in training.
    DensityNoise = 3,
    /// Which training pixels make up a batch.
    RayBatch = 4,
    /// Anything else (tests, initialisation).
    Other = 5,
}

/// A random stream for one ray (or one draw site) of one training step.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RayRng {
    key: u32,
}

impl RayRng {
    /// The stream for `(seed, step, stream, ray)`.
    #[must_use]
    #[inline]
    pub const fn new(seed: u32, step: u32, stream: Stream, ray: u32) -> Self {
        let k = pcg_hash(seed ^ pcg_hash(step ^ pcg_hash(stream as u32 ^ pcg_hash(ray))));
        Self { key: k }
    }

    /// The `i`-th 32 random bits of this stream.
    #[must_use]
    #[inline]
    pub const fn bits(&self, i: u32) -> u32 {
        pcg_hash(self.key ^ pcg_hash(i))
    }

    /// The `i`-th uniform number in `[0, 1)`, a multiple of `2^-24`.
    #[must_use]
    #[inline]
    pub fn uniform(&self, i: u32) -> f32 {
        (self.bits(i) >> 8) as f32 * (1.0 / 16_777_216.0)
    }

    /// The `i`-th standard normal number (Box-Muller on uniforms `2i` and `2i + 1`).
    #[must_use]
    #[inline]
    pub fn normal(&self, i: u32) -> f32 {
        let u1 = 1.0 - self.uniform(2 * i); // in (0, 1]
        let u2 = self.uniform(2 * i + 1);
        (-2.0 * u1.ln()).sqrt() * (std::f32::consts::TAU * u2).cos()
    }
}
