//! Counter-based random numbers that the CPU and the GPU draw identically.
//!
//! Every random number in training (sample jitter, inverse-CDF offsets, density noise, ray batch
//! indices) is a pure function of `(seed, step, stream, index)`, so a run is reproducible bit for
//! bit whatever the thread count, and the WGSL kernels (`shaders/rng.wgsl`, with the stream ids and [`RAY_LEVEL_STRIDE`]
//! passed to them from here) reproduce the same
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

/// Streams per ray: a ray's draws at level `l` use stream index `ray * RAY_LEVEL_STRIDE + l`, so
/// that up to 8 levels never share one.
pub const RAY_LEVEL_STRIDE: u32 = 8;

/// The stream index of `ray`'s draws at `level` (wrapping, as the WGSL's `u32` arithmetic does).
#[must_use]
#[inline]
pub const fn ray_level_index(ray: u32, level: u32) -> u32 {
    ray.wrapping_mul(RAY_LEVEL_STRIDE).wrapping_add(level)
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
    /// The random point of each cell at which an occupancy-grid update evaluates the density.
    OccupancyUpdate = 6,
    /// The random background colour of each training pixel (`ModelConfig::random_bkgd`).
    Background = 7,
}

/// The background colour of pixel `pixel` of the batch of training step `step` when training on
/// random backgrounds (`ModelConfig::random_bkgd`): uniforms 0, 1 and 2 of the pixel's
/// [`Stream::Background`] stream, each in `[0, 1)`. The model renders the pixel on this colour and
/// `Dataset::sample_batch` composites its target on it; `shaders/rng.wgsl`'s `random_background`
/// draws the same.
#[must_use]
#[inline]
pub fn random_background(seed: u32, step: u32, pixel: u32) -> [f32; 3] {
    let rng = RayRng::new(seed, step, Stream::Background, pixel);
    [rng.uniform(0), rng.uniform(1), rng.uniform(2)]
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

    /// The stream's key: [`bits`](Self::bits)`(i)` is `pcg_hash(key ^ pcg_hash(i))`. The GPU
    /// kernels take it as a parameter and draw the same bits.
    #[must_use]
    #[inline]
    pub const fn key(&self) -> u32 {
        self.key
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn uniforms_are_in_range_deterministic_and_well_spread() {
        let rng = RayRng::new(1, 2, Stream::SampleJitter, 3);
        let xs: Vec<f32> = (0..100_000).map(|i| rng.uniform(i)).collect();
        assert!(xs.iter().all(|&x| (0.0..1.0).contains(&x)));
        assert_eq!(xs[17], RayRng::new(1, 2, Stream::SampleJitter, 3).uniform(17));
        let mean = xs.iter().map(|&x| f64::from(x)).sum::<f64>() / xs.len() as f64;
        // Standard error of the mean of U[0,1) over 1e5 draws is 0.0009.
        assert!((mean - 0.5).abs() < 0.005, "mean {mean}");
        let mut buckets = [0u32; 10];
        for &x in &xs {
            buckets[(x * 10.0) as usize] += 1;
        }
        assert!(buckets.iter().all(|&b| (9_500..10_500).contains(&b)), "{buckets:?}");
        // Different streams, steps and rays give different numbers.
        let other = [
            RayRng::new(1, 2, Stream::ResampleOffsets, 3),
            RayRng::new(1, 3, Stream::SampleJitter, 3),
            RayRng::new(1, 2, Stream::SampleJitter, 4),
        ];
        for o in other {
            assert_ne!(o.bits(0), rng.bits(0));
        }
    }

    #[test]
    fn normals_have_unit_variance() {
        let rng = RayRng::new(9, 0, Stream::DensityNoise, 0);
        let xs: Vec<f64> = (0..100_000).map(|i| f64::from(rng.normal(i))).collect();
        let mean = xs.iter().sum::<f64>() / xs.len() as f64;
        let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / xs.len() as f64;
        assert!(mean.abs() < 0.02 && (var - 1.0).abs() < 0.02, "mean {mean} var {var}");
    }
}
