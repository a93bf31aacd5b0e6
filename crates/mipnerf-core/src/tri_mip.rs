//! The Tri-Mip encoding (Hu et al., "Tri-MipRF", ICCV 2023): a sample's conical frustum read
//! from three orthogonal feature planes, each pre-filtered as a mipmap, at the level its
//! footprint covers. Mip-NeRF's idea (encode the whole frustum, not a point) at a grid's cost:
//! one trilinear read a plane instead of an MLP over the integrated positional encoding.
//!
//! # The planes
//! Three planes, `xy`, `xz` and `yz` ([`PLANES`]), each of `resolution x resolution` texels of
//! `features` values; level 0 is the parameters ([`TriMipConfig::num_params`], laid out
//! `[plane][v][u][feature]`), initialised uniform in `[-INIT_RANGE, INIT_RANGE]` as the authors'
//! code does. Level `l > 0` is the 2x2 box filter of level `l - 1` ([`Pyramid::build`]), down to
//! `levels - 1`; its gradient is pushed back to level 0 through the same filter
//! ([`Pyramid::push_down`], the filter's adjoint), so only level 0 is trained.
//!
//! # The level of a sample
//! Positions are in the planes' box, `[0, 1]^3` (the caller maps its box there, dividing
//! lengths by the box's side). A sample's footprint is the radius of its cone's cross-section
//! at the frustum, from the frustum's moments: a disk of radius `ρ` has variance `ρ²/4` along
//! each of its axes, so `ρ = 2·sqrt(r_var)` ([`footprint_radius`]). For a pixel's cone this is
//! the sphere Tri-MipRF's code inscribes in the cone (`d · tan`, to second order in the cone's
//! angle; `tests/tri_mip.rs` checks it within a hundredth of a level). The Gaussian's isotropic
//! spread (its trace) was the other candidate and is not used: along a pixel's cone the frustum's
//! length, set by the spacing of the samples, dominates it (at 128 samples over `[2, 6]` and 400
//! pixels, `t_var` is 4 to 40 times `r_var`, and the isotropic ball reads 0.7 to 1.6 levels too
//! coarse), so it would measure the samples' spacing, not the cone's width. The level is `log2` of the footprint's diameter in level-0 texels,
//! `log2(2 ρ · resolution)` ([`level_of`]), clamped to the pyramid (a point reads level 0). It
//! is not differentiated (as in the authors' code): the gradient reaches the features, never
//! the footprint.
//!
//! # Reading a plane
//! As a mipmapped texture with clamped edges: bilinear in `(u, v)` at the two levels around the
//! sample's (texel centres at `(i + 0.5) / size`), blended linearly by the level's fraction
//! ([`Taps`]: 3 planes x 2 levels x 4 texels). The three planes' features are concatenated, in
//! [`PLANES`] order, into the sample's `3 · features` encoding ([`encode`]); [`encode_backward`]
//! is its adjoint.

use glam::Vec3;
use rand::{Rng, SeedableRng, rngs::SmallRng};

use crate::mip::FrustumMoments;
use crate::wide::wide;

/// The planes, each named by the two coordinates of the box it is indexed by (`u`, `v`).
pub const PLANES: [(usize, usize); 3] = [(0, 1), (0, 2), (1, 2)];

/// The half width of the uniform initialisation of the planes (the authors' 0.01).
pub const INIT_RANGE: f32 = 0.01;

/// The texels one sample reads: 3 planes x 2 levels x 4 bilinear corners.
pub const TAPS_PER_SAMPLE: usize = 24;

/// The planes' shape.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct TriMipConfig {
    /// Texels along each side of level 0 (Tri-MipRF: 512).
    pub resolution: usize,
    /// Features a texel (Tri-MipRF: 16).
    pub features: usize,
    /// Pyramid levels, level 0 included (Tri-MipRF: 8); `resolution` halves `levels - 1` times.
    pub levels: usize,
}

impl Default for TriMipConfig {
    fn default() -> Self {
        Self { resolution: 512, features: 16, levels: 8 }
    }
}

/// A [`TriMipConfig`] that cannot be built.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("invalid Tri-Mip planes: {0}")]
pub struct TriMipConfigError(pub String);

impl TriMipConfig {
    /// Checks the shape: every size at least 1, at most 8,192 texels a side, 256 features and 14
    /// levels, and a resolution that halves evenly down to the last level.
    ///
    /// # Errors
    /// The size that is wrong, in words.
    pub fn validate(&self) -> Result<(), TriMipConfigError> {
        let Self { resolution, features, levels } = *self;
        if resolution == 0 || features == 0 || levels == 0 {
            return Err(TriMipConfigError(format!(
                "resolution {resolution}, features {features} and levels {levels} must each be at least 1"
            )));
        }
        if resolution > 8192 || features > 256 || levels > 14 {
            return Err(TriMipConfigError(format!(
                "resolution {resolution} (at most 8192), features {features} (at most 256), levels {levels} (at most 14)"
            )));
        }
        if !resolution.is_multiple_of(1 << (levels - 1)) {
            return Err(TriMipConfigError(format!(
                "resolution {resolution} does not halve evenly {} times (levels {levels})",
                levels - 1
            )));
        }
        Ok(())
    }

    /// Texels along a side of `level`.
    #[must_use]
    pub const fn size(&self, level: usize) -> usize {
        self.resolution >> level
    }

    /// Values of one level, its three planes together.
    #[must_use]
    pub const fn level_len(&self, level: usize) -> usize {
        3 * self.size(level) * self.size(level) * self.features
    }

    /// The trained parameters: level 0 of the three planes.
    #[must_use]
    pub const fn num_params(&self) -> usize {
        self.level_len(0)
    }

    /// Width of a sample's encoding: the three planes' features.
    #[must_use]
    pub const fn encoding_dim(&self) -> usize {
        3 * self.features
    }

    /// Fills level 0 (`params`, [`Self::num_params`] values) uniform in `[-INIT_RANGE, INIT_RANGE]`.
    ///
    /// # Panics
    /// If `params` is not [`Self::num_params`] long.
    pub fn init(&self, params: &mut [f32], seed: u64) {
        assert_eq!(params.len(), self.num_params(), "tri-mip init: level 0");
        let mut rng = SmallRng::seed_from_u64(seed);
        params.iter_mut().for_each(|p| *p = rng.random_range(-INIT_RANGE..=INIT_RANGE));
    }
}

/// The levels above 0 of the planes' mipmaps (level 0 is the parameters themselves), or, in the
/// backward pass, their gradients.
#[derive(Clone, Debug, PartialEq)]
pub struct Pyramid {
    config: TriMipConfig,
    /// `coarse[l - 1]` is level `l`, laid out as level 0.
    coarse: Vec<Vec<f32>>,
}

impl Pyramid {
    /// Zeros for the levels above 0 of `config`.
    #[must_use]
    pub fn zeros(config: TriMipConfig) -> Self {
        Self { config, coarse: (1..config.levels).map(|l| vec![0.0; config.level_len(l)]).collect() }
    }

    /// The planes' shape.
    #[must_use]
    pub fn config(&self) -> TriMipConfig {
        self.config
    }

    /// Level `level >= 1`.
    #[must_use]
    pub fn level(&self, level: usize) -> &[f32] {
        &self.coarse[level - 1]
    }

    /// Level `level >= 1`, to write.
    pub fn level_mut(&mut self, level: usize) -> &mut [f32] {
        &mut self.coarse[level - 1]
    }

    /// Sets every level to zero (a gradient pyramid, between steps).
    pub fn clear(&mut self) {
        self.coarse.iter_mut().for_each(|l| l.fill(0.0));
    }

    /// Builds the levels above 0 from `level0` (the parameters): each texel of level `l` the mean
    /// of the 2x2 texels of level `l - 1` it covers.
    ///
    /// # Panics
    /// If `level0` is not [`TriMipConfig::num_params`] long.
    pub fn build(&mut self, level0: &[f32]) {
        assert_eq!(level0.len(), self.config.num_params(), "tri-mip pyramid: level 0");
        let c = self.config;
        for l in 1..c.levels {
            let (finer, coarser) = self.coarse.split_at_mut(l - 1);
            let src: &[f32] = if l == 1 { level0 } else { &finer[l - 2] };
            box_filter(src, &mut coarser[0], c.size(l - 1), c.features);
        }
    }

    /// The adjoint of [`Self::build`]: adds to `grad_level0` what this pyramid of gradients
    /// (of levels above 0) gives level 0 through the box filters, each coarse texel's gradient
    /// spread a quarter to each of the four finer texels it averages. Leaves `self` changed
    /// (each level then holds its own gradient plus what the coarser ones pushed into it).
    ///
    /// # Panics
    /// If `grad_level0` is not [`TriMipConfig::num_params`] long.
    pub fn push_down(&mut self, grad_level0: &mut [f32]) {
        assert_eq!(grad_level0.len(), self.config.num_params(), "tri-mip push down: level 0");
        let c = self.config;
        for l in (1..c.levels).rev() {
            let (finer, coarser) = self.coarse.split_at_mut(l - 1);
            let dst: &mut [f32] = if l == 1 { grad_level0 } else { &mut finer[l - 2] };
            box_filter_adjoint(&coarser[0], dst, c.size(l - 1), c.features);
        }
    }
}

/// `dst` (of side `fine / 2`) = the 2x2 box filter of `src` (side `fine`), three planes, row by
/// row over every thread. The planes lie one after the other, so row `r` of `dst` (of any
/// plane) averages rows `2r` and `2r + 1` of `src`.
fn box_filter(src: &[f32], dst: &mut [f32], fine: usize, features: usize) {
    use rayon::prelude::*;
    let (coarse, src_row) = (fine / 2, fine * features);
    dst.par_chunks_mut(coarse * features).enumerate().for_each(|(r, out)| {
        let (a, b) = (&src[2 * r * src_row..(2 * r + 1) * src_row], &src[(2 * r + 1) * src_row..(2 * r + 2) * src_row]);
        wide(
            #[inline(always)]
            || {
                for (u, texel) in out.chunks_exact_mut(features).enumerate() {
                    let (a, b) =
                        (&a[2 * u * features..(2 * u + 2) * features], &b[2 * u * features..(2 * u + 2) * features]);
                    let (a0, a1) = a.split_at(features);
                    let (b0, b1) = b.split_at(features);
                    for (f, o) in texel.iter_mut().enumerate() {
                        *o = 0.25 * (a0[f] + a1[f] + b0[f] + b1[f]);
                    }
                }
            },
        );
    });
}

/// Adds the adjoint of [`box_filter`] of `grad_coarse` to `grad_fine` (side `fine`), row by row
/// over every thread: row `r` of `grad_fine` takes a quarter of row `r / 2` of `grad_coarse`.
fn box_filter_adjoint(grad_coarse: &[f32], grad_fine: &mut [f32], fine: usize, features: usize) {
    use rayon::prelude::*;
    let coarse_row = fine / 2 * features;
    grad_fine.par_chunks_mut(fine * features).enumerate().for_each(|(r, to)| {
        let from = &grad_coarse[(r / 2) * coarse_row..(r / 2 + 1) * coarse_row];
        wide(
            #[inline(always)]
            || {
                for (u, texel) in to.chunks_exact_mut(features).enumerate() {
                    let f = &from[(u / 2) * features..(u / 2 + 1) * features];
                    texel.iter_mut().zip(f).for_each(|(t, g)| *t += 0.25 * g);
                }
            },
        );
    });
}

/// The radius of a conical frustum's cross-section at its mean distance, from its moments (in
/// the units of `r_var`): `2·sqrt(r_var)` (a disk of radius `ρ` has variance `ρ²/4` per axis).
#[must_use]
pub fn footprint_radius(m: &FrustumMoments) -> f32 {
    2.0 * m.r_var.max(0.0).sqrt()
}

/// The mipmap level a footprint of radius `radius` (in the box's units, its side 1) reads:
/// `log2` of its diameter in level-0 texels, clamped to `[0, levels - 1]` (a point, or a
/// footprint smaller than a texel, reads level 0; a NaN one too).
#[must_use]
pub fn level_of(radius: f32, config: &TriMipConfig) -> f32 {
    let level = (2.0 * radius * config.resolution as f32).log2();
    if level.is_nan() { 0.0 } else { level.clamp(0.0, (config.levels - 1) as f32) }
}

/// The texels one sample reads and their weights: for each plane, the 4 bilinear corners at the
/// two levels around the sample's ([`TAPS_PER_SAMPLE`] in all), each as (level, offset of its
/// first feature in that level's buffer, weight). Made once and used by the forward and the
/// backward pass.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Taps {
    /// `(level, offset, weight)` per texel, plane by plane (8 a plane).
    pub texels: [(u8, u32, f32); TAPS_PER_SAMPLE],
}

/// The taps of the point `x` (in the box; clamped to its edge) at `level` (clamped to
/// `[0, levels - 1]`).
#[must_use]
pub fn taps(config: &TriMipConfig, x: Vec3, level: f32) -> Taps {
    wide(
        #[inline(always)]
        || taps_inline(config, x, level),
    )
}

#[inline(always)]
fn taps_inline(config: &TriMipConfig, x: Vec3, level: f32) -> Taps {
    let top = config.levels - 1;
    let level = if level.is_nan() { 0.0 } else { level.clamp(0.0, top as f32) };
    let l0 = (level.floor() as usize).min(top);
    let l1 = (l0 + 1).min(top);
    let blend = level - l0 as f32;
    let mut texels = [(0u8, 0u32, 0.0f32); TAPS_PER_SAMPLE];
    let coords = [x.x, x.y, x.z];
    let mut k = 0;
    for (p, &(a, b)) in PLANES.iter().enumerate() {
        for (l, level_weight) in [(l0, 1.0 - blend), (l1, blend)] {
            let size = config.size(l);
            // The two texels around `t` along one side (clamped to the edge) and the weight of
            // the second.
            let corner = |t: f32| {
                let f = t.clamp(0.0, 1.0) * size as f32 - 0.5;
                let i = f.floor();
                let clamp = |j: f32| (j.max(0.0) as usize).min(size - 1);
                (clamp(i), clamp(i + 1.0), f - i)
            };
            let (u0, u1, wu) = corner(coords[a]);
            let (v0, v1, wv) = corner(coords[b]);
            let plane = p * size * size;
            for (u, v, w) in [
                (u0, v0, (1.0 - wu) * (1.0 - wv)),
                (u1, v0, wu * (1.0 - wv)),
                (u0, v1, (1.0 - wu) * wv),
                (u1, v1, wu * wv),
            ] {
                let offset = (plane + v * size + u) * config.features;
                texels[k] = (l as u8, offset as u32, level_weight * w);
                k += 1;
            }
        }
    }
    Taps { texels }
}

/// The sample's encoding: writes the three planes' features read at `taps` (from `level0`, the
/// parameters, and `pyramid`, the levels above) into `out`, [`TriMipConfig::encoding_dim`] values.
///
/// # Panics
/// If `out` is not [`TriMipConfig::encoding_dim`] long.
pub fn encode(config: &TriMipConfig, level0: &[f32], pyramid: &Pyramid, taps: &Taps, out: &mut [f32]) {
    wide(
        #[inline(always)]
        || encode_inline(config, level0, pyramid, taps, out),
    );
}

#[inline(always)]
fn encode_inline(config: &TriMipConfig, level0: &[f32], pyramid: &Pyramid, taps: &Taps, out: &mut [f32]) {
    let c = config.features;
    assert_eq!(out.len(), 3 * c, "tri-mip encode: output");
    out.fill(0.0);
    for (k, &(l, offset, w)) in taps.texels.iter().enumerate() {
        let src = if l == 0 { level0 } else { pyramid.level(usize::from(l)) };
        let texel = &src[offset as usize..offset as usize + c];
        let dst = &mut out[(k / 8) * c..(k / 8 + 1) * c];
        dst.iter_mut().zip(texel).for_each(|(o, t)| *o += w * t);
    }
}

/// The adjoint of [`encode`]: adds `d_out` (the gradient of the sample's encoding) times each
/// tap's weight to its texel's gradient, in `grad_level0` (level 0) or `grad_pyramid` (the levels
/// above; [`Pyramid::push_down`] then carries them to level 0).
///
/// # Panics
/// If `d_out` is not [`TriMipConfig::encoding_dim`] long.
pub fn encode_backward(
    config: &TriMipConfig,
    taps: &Taps,
    d_out: &[f32],
    grad_level0: &mut [f32],
    grad_pyramid: &mut Pyramid,
) {
    wide(
        #[inline(always)]
        || encode_backward_inline(config, taps, d_out, grad_level0, grad_pyramid),
    );
}

#[inline(always)]
fn encode_backward_inline(
    config: &TriMipConfig,
    taps: &Taps,
    d_out: &[f32],
    grad_level0: &mut [f32],
    grad_pyramid: &mut Pyramid,
) {
    let c = config.features;
    assert_eq!(d_out.len(), 3 * c, "tri-mip encode backward: d_out");
    for (k, &(l, offset, w)) in taps.texels.iter().enumerate() {
        if w == 0.0 {
            continue;
        }
        let dst = if l == 0 { &mut *grad_level0 } else { grad_pyramid.level_mut(usize::from(l)) };
        let texel = &mut dst[offset as usize..offset as usize + c];
        let src = &d_out[(k / 8) * c..(k / 8 + 1) * c];
        texel.iter_mut().zip(src).for_each(|(t, g)| *t += w * g);
    }
}

/// [`taps`] and [`encode`] over a batch of samples in parallel: sample `k` at `points[k]` and
/// `levels[k]` writes its taps to `taps_out[k]` (kept for the backward pass) and its encoding to
/// `out[k · encoding_dim ..]`.
///
/// # Panics
/// If the slices' lengths do not match.
pub fn encode_batch(
    config: &TriMipConfig,
    level0: &[f32],
    pyramid: &Pyramid,
    points: &[Vec3],
    levels: &[f32],
    taps_out: &mut [Taps],
    out: &mut [f32],
) {
    use rayon::prelude::*;
    let dim = config.encoding_dim();
    assert!(points.len() == levels.len() && taps_out.len() == points.len(), "tri-mip encode batch: samples");
    assert_eq!(out.len(), points.len() * dim, "tri-mip encode batch: output");
    const SAMPLES_A_TASK: usize = 1024;
    out.par_chunks_mut(SAMPLES_A_TASK * dim).zip(taps_out.par_chunks_mut(SAMPLES_A_TASK)).enumerate().for_each(
        |(task, (out, taps_out))| {
            let first = task * SAMPLES_A_TASK;
            wide(
                #[inline(always)]
                || {
                    for (j, t) in taps_out.iter_mut().enumerate() {
                        *t = taps_inline(config, points[first + j], levels[first + j]);
                        encode_inline(config, level0, pyramid, t, &mut out[j * dim..(j + 1) * dim]);
                    }
                },
            );
        },
    );
}

/// [`encode_backward`] over batches of samples (each its taps and the gradient of its
/// encodings, `taps.len() x encoding_dim`), the three planes in parallel: each plane's texels take
/// their contributions in batch order and sample order, so every texel sums them in one order
/// whatever the thread count (the sequential loop's result, bit for bit).
///
/// Measured on 2 cores (`benches/tri_mip.rs`, `docs/results/tri-mip/per-sample-cost.md`), the
/// scatter is bound by memory: one thread made 75 ns a sample, where bands of texels that each
/// scanned every tap made 139 and bands fed by a parallel sort 156. A plane's task reads only its
/// own 8 of a sample's 24 taps, so the split by plane costs no extra scanning.
///
/// # Panics
/// If a batch's `d_x` is not `taps.len() x encoding_dim`.
pub fn encode_backward_batch(
    config: &TriMipConfig,
    batches: &[(&[Taps], &[f32])],
    grad_level0: &mut [f32],
    grad_pyramid: &mut Pyramid,
) {
    use rayon::prelude::*;
    let (c, dim) = (config.features, config.encoding_dim());
    for (taps, d_x) in batches {
        assert_eq!(d_x.len(), taps.len() * dim, "tri-mip encode backward batch: d_x");
    }
    let plane_len = |level: usize| config.size(level) * config.size(level) * c;
    assert_eq!(grad_level0.len(), 3 * plane_len(0), "tri-mip encode backward batch: level 0");
    // Each plane's slice of level 0 and of every level above.
    let mut planes: Vec<(usize, Vec<&mut [f32]>)> =
        grad_level0.chunks_mut(plane_len(0)).map(|p| vec![p]).enumerate().collect();
    for (l, level) in grad_pyramid.coarse.iter_mut().enumerate() {
        for (p, slice) in level.chunks_mut(plane_len(l + 1)).enumerate() {
            planes[p].1.push(slice);
        }
    }
    planes.par_iter_mut().for_each(|(p, levels)| {
        let p = *p;
        wide(
            #[inline(always)]
            || {
                for (taps, d_x) in batches {
                    for (k, t) in taps.iter().enumerate() {
                        let src = &d_x[k * dim + p * c..k * dim + (p + 1) * c];
                        for &(l, offset, w) in &t.texels[8 * p..8 * (p + 1)] {
                            if w == 0.0 {
                                continue;
                            }
                            let at = offset as usize - p * plane_len(usize::from(l));
                            let texel = &mut levels[usize::from(l)][at..at + c];
                            texel.iter_mut().zip(src).for_each(|(t, g)| *t += w * g);
                        }
                    }
                }
            },
        );
    });
}

/// `weight` times the total variation of the planes' level 0, the mean over every pair of
/// neighbouring texels (along `u` and along `v`, in each plane) and every feature of their
/// squared difference, as TensoRF regularises its planes; adds its gradient to `grad`. Row by
/// row over every thread (each row's loss summed in row order: the same result whatever the
/// thread count).
///
/// # Panics
/// If `level0` or `grad` is not [`TriMipConfig::num_params`] long.
pub fn total_variation(config: &TriMipConfig, level0: &[f32], weight: f32, grad: &mut [f32]) -> f64 {
    use rayon::prelude::*;
    assert!(level0.len() == config.num_params() && grad.len() == level0.len(), "tri-mip total variation: lengths");
    let (size, c) = (config.resolution, config.features);
    if size < 2 {
        return 0.0;
    }
    let scale = total_variation_scale(config, weight);
    let row = size * c;
    let rows: Vec<f64> = grad
        .par_chunks_mut(row)
        .enumerate()
        .map(|(r, g)| {
            let (v, plane) = (r % size, r / size);
            let at = |v: usize| &level0[(plane * size + v) * row..(plane * size + v + 1) * row];
            let here = at(v);
            let mut loss = 0.0f64;
            wide(
                #[inline(always)]
                || {
                    let mut acc = 0.0f32;
                    for i in 0..row {
                        let mut d = 0.0f32;
                        if i >= c {
                            d += here[i] - here[i - c];
                        }
                        if i + c < row {
                            let e = here[i] - here[i + c];
                            d += e;
                            acc += e * e;
                        }
                        if v > 0 {
                            d += here[i] - at(v - 1)[i];
                        }
                        if v + 1 < size {
                            let e = here[i] - at(v + 1)[i];
                            d += e;
                            acc += e * e;
                        }
                        g[i] += 2.0 * scale * d;
                    }
                    loss = f64::from(acc);
                },
            );
            loss
        })
        .collect();
    rows.iter().sum::<f64>() * f64::from(scale)
}

/// The factor [`total_variation`] scales each squared difference by: `weight` over the number of
/// neighbouring pairs (along `u` and `v` in each plane, times the features); 0 for planes of
/// one texel, which have none.
#[must_use]
pub fn total_variation_scale(config: &TriMipConfig, weight: f32) -> f32 {
    let (size, c) = (config.resolution, config.features);
    if size < 2 {
        return 0.0;
    }
    weight / (3 * 2 * size * (size - 1) * c) as f32
}

/// Values of [`spherical_harmonics`]: the real spherical harmonics of degrees 0 to 3 (Tri-MipRF's
/// and Instant-NGP's "degree 4" view encoding).
pub const SH_VALUES: usize = 16;

/// The view direction `d` (normalised here) as the 16 real spherical harmonics of degrees 0 to 3,
/// orthonormal over the sphere (`tests/tri_mip.rs` integrates them), in the order and signs of
/// tiny-cuda-nn's encoding that Tri-MipRF's colour network reads.
#[must_use]
pub fn spherical_harmonics(d: Vec3) -> [f32; SH_VALUES] {
    let d = d.normalize_or_zero();
    let (x, y, z) = (d.x, d.y, d.z);
    let (xx, yy, zz) = (x * x, y * y, z * z);
    [
        0.282_094_8,
        -0.488_602_5 * y,
        0.488_602_5 * z,
        -0.488_602_5 * x,
        1.092_548_4 * x * y,
        -1.092_548_4 * y * z,
        0.946_174_7 * zz - 0.315_391_57,
        -1.092_548_4 * x * z,
        0.546_274_2 * (xx - yy),
        0.590_043_6 * y * (3.0 * xx - yy),
        2.890_611_4 * x * y * z,
        0.457_045_8 * y * (5.0 * zz - 1.0),
        0.373_176_33 * z * (5.0 * zz - 3.0),
        0.457_045_8 * x * (5.0 * zz - 1.0),
        1.445_305_7 * z * (xx - yy),
        0.590_043_6 * x * (xx - 3.0 * yy),
    ]
}
