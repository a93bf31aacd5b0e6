//! Zip-NeRF's anti-aliased hash grid (Barron et al., "Zip-NeRF", ICCV 2023): Instant-NGP's
//! multiresolution hash encoding, each level's features down-weighted by how much of that level
//! the sample's footprint averages away. The Tri-Mip planes' alternative for scenes the planes'
//! projections confuse: one 3D grid a level, no plane shared by every depth.
//!
//! # The grid
//! `levels` grids of `n_l + 1` vertices a side over the box `[0, 1]^3`, `n_l` growing
//! geometrically from `coarsest` to `finest` ([`HashGridConfig::resolution`]). A level whose
//! vertices fit in the table (`(n_l + 1)^3 <= 2^log2_table`) indexes them densely; a finer one
//! hashes them into `2^log2_table` entries (Instant-NGP's spatial hash, `i ⊕ j·π₂ ⊕ k·π₃`). Each
//! entry holds `features` values, initialised uniform in `[-INIT_RANGE, INIT_RANGE]` (Instant-NGP's
//! 1e-4); the parameters are the levels' tables back to back ([`HashGridConfig::offset`]).
//!
//! # A sample's features
//! Trilinear in the 8 vertices of the cell around the sample's point, at every level, times the
//! level's weight `erf(1 / sqrt(8 σ² n_l²))` ([`downweight`]), concatenated level after level:
//! `levels · features` values. `σ` is the sample's footprint as a standard deviation in the box's
//! units ([`GridSample::scale`]): the per-axis spread of the cone's cross-section at the frustum,
//! `sqrt(r_var)`, the same cross-section the Tri-Mip field's level reads (along a pixel's cone
//! the frustum's length measures the samples' spacing, not the cone's width). A point (σ = 0)
//! reads every level at weight 1; a cone wider than a level's cells reads that level near 0,
//! which is Zip-NeRF's stand-in for the mean of a cell's features under the Gaussian (zero, for
//! features spread about zero). Zip-NeRF also averages 6 points spread over the frustum
//! (multisampling); this field reads the frustum's mean alone, 6 times cheaper on a CPU, and
//! keeps the down-weighting that carries the cone's scale. The weight is not differentiated: the
//! gradient reaches the features, never the footprint.
//!
//! [`Levels::encode`] is the forward pass; [`Levels::encode_backward_batch`] its adjoint, by level
//! in parallel.

use glam::Vec3;
use rand::{Rng, SeedableRng, rngs::SmallRng};

use crate::wide::wide;

/// The half width of the uniform initialisation of the tables (Instant-NGP's 1e-4).
pub const INIT_RANGE: f32 = 1e-4;

/// The most levels a grid may have.
pub const MAX_LEVELS: usize = 24;

/// The spatial hash's primes for `y` and `z` (Instant-NGP's; `x`'s is 1).
const PRIMES: [u32; 2] = [2_654_435_761, 805_459_861];

/// The grid's shape.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HashGridConfig {
    /// Resolution levels (Instant-NGP and Zip-NeRF: 16).
    pub levels: usize,
    /// Features an entry (Instant-NGP: 2; Zip-NeRF: 4).
    pub features: usize,
    /// `log2` of the entries of a hashed level's table (Instant-NGP: 19; Zip-NeRF: 21).
    pub log2_table: u32,
    /// Cells along a side of the coarsest level (Instant-NGP: 16).
    pub coarsest: usize,
    /// Cells along a side of the finest level.
    pub finest: usize,
}

impl Default for HashGridConfig {
    fn default() -> Self {
        Self { levels: 16, features: 2, log2_table: 17, coarsest: 16, finest: 512 }
    }
}

/// A [`HashGridConfig`] that cannot be built.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("invalid hash grid: {0}")]
pub struct HashGridConfigError(pub String);

impl HashGridConfig {
    /// Checks the shape: 1 to [`MAX_LEVELS`] levels, 1 to 16 features, tables of `2^4` to `2^24`
    /// entries, and `1 <= coarsest <= finest <= 65,536` cells a side.
    ///
    /// # Errors
    /// The size that is wrong, in words.
    pub fn validate(&self) -> Result<(), HashGridConfigError> {
        let Self { levels, features, log2_table, coarsest, finest } = *self;
        if !(1..=MAX_LEVELS).contains(&levels) || !(1..=16).contains(&features) || !(4..=24).contains(&log2_table) {
            return Err(HashGridConfigError(format!(
                "levels {levels} (1 to {MAX_LEVELS}), features {features} (1 to 16), log2_table {log2_table} (4 to 24)"
            )));
        }
        if coarsest == 0 || coarsest > finest || finest > 65_536 {
            return Err(HashGridConfigError(format!(
                "cells a side from coarsest {coarsest} to finest {finest} must satisfy 1 <= coarsest <= finest <= 65536"
            )));
        }
        Ok(())
    }

    /// Cells along a side of `level`: `coarsest · b^level`, rounded down, with `b` the growth that
    /// takes the last level to `finest`.
    #[must_use]
    pub fn resolution(&self, level: usize) -> usize {
        if self.levels == 1 {
            return self.coarsest;
        }
        let growth = (self.finest as f64 / self.coarsest as f64).ln() / (self.levels - 1) as f64;
        ((self.coarsest as f64 * (growth * level as f64).exp()) + 1e-6).floor() as usize
    }

    /// Entries of `level`'s table: its vertices where they fit in `2^log2_table`, else that.
    #[must_use]
    pub fn entries(&self, level: usize) -> usize {
        let side = self.resolution(level) as u64 + 1;
        side.saturating_pow(3).min(1 << self.log2_table) as usize
    }

    /// Whether `level` indexes its vertices densely (they fit in its table).
    #[must_use]
    pub fn is_dense(&self, level: usize) -> bool {
        let side = self.resolution(level) as u64 + 1;
        side.saturating_pow(3) <= 1 << self.log2_table
    }

    /// Where `level`'s table starts in the parameters.
    #[must_use]
    pub fn offset(&self, level: usize) -> usize {
        (0..level).map(|l| self.entries(l) * self.features).sum()
    }

    /// The trained parameters: every level's table.
    #[must_use]
    pub fn num_params(&self) -> usize {
        self.offset(self.levels)
    }

    /// Width of a sample's encoding: every level's features.
    #[must_use]
    pub const fn encoding_dim(&self) -> usize {
        self.levels * self.features
    }

    /// Fills the tables (`params`, [`Self::num_params`] values) uniform in
    /// `[-INIT_RANGE, INIT_RANGE]`.
    ///
    /// # Panics
    /// If `params` is not [`Self::num_params`] long.
    pub fn init(&self, params: &mut [f32], seed: u64) {
        assert_eq!(params.len(), self.num_params(), "hash grid init: tables");
        let mut rng = SmallRng::seed_from_u64(seed);
        params.iter_mut().for_each(|p| *p = rng.random_range(-INIT_RANGE..=INIT_RANGE));
    }

    /// Zip-NeRF's normalised weight decay of the tables: `weight · Σ_l mean(V_l²)`, the mean over
    /// each level's values, so that a coarse dense level of a few thousand entries weighs as much
    /// as a hashed one of millions. Returns it (in f64) and adds its gradient `2 weight V / |V_l|`
    /// to `grad`. Nothing else bounds the features: without it, entries that few training rays
    /// reach grow where a scene has nothing (floaters; `docs/results/hash-grid/fern-diverged/`).
    ///
    /// # Panics
    /// If `tables` or `grad` is not [`Self::num_params`] long.
    pub fn weight_decay(&self, tables: &[f32], weight: f32, grad: &mut [f32]) -> f64 {
        use rayon::prelude::*;
        assert_eq!(tables.len(), self.num_params(), "hash grid weight decay: tables");
        assert_eq!(grad.len(), self.num_params(), "hash grid weight decay: gradient");
        const BLOCK: usize = 1 << 14;
        let mut total = 0.0f64;
        for level in 0..self.levels {
            let range = self.offset(level)..self.offset(level + 1);
            let count = range.len() as f32;
            let scale = 2.0 * weight / count;
            // Each block's sum, then the blocks' in order: the same bits whatever the threads.
            let sums: Vec<f64> = (grad[range.clone()].par_chunks_mut(BLOCK), tables[range].par_chunks(BLOCK))
                .into_par_iter()
                .map(|(g, v)| {
                    g.iter_mut()
                        .zip(v)
                        .map(|(g, &v)| {
                            *g += scale * v;
                            f64::from(v) * f64::from(v)
                        })
                        .sum::<f64>()
                })
                .collect();
            total += f64::from(weight) * sums.iter().sum::<f64>() / f64::from(count);
        }
        total
    }

    /// Each level's constants, for the inner loops.
    fn level_shapes(&self) -> Vec<LevelShape> {
        (0..self.levels)
            .map(|l| LevelShape {
                cells: self.resolution(l),
                offset: self.offset(l),
                dense: self.is_dense(l),
                mask: (1u32 << self.log2_table) - 1,
            })
            .collect()
    }
}

/// Samples a level reads at once ([`LevelShape::block_corners`]): one AVX-512 vector of `f32`.
const BLOCK: usize = 16;

/// A block's corners: for each of the cell's 8 vertices, each sample's entry in the level's table
/// and its weight, the level's [`downweight`] included.
struct BlockCorners {
    entry: [[u32; BLOCK]; 8],
    weight: [[f32; BLOCK]; 8],
}

/// One level's constants: cells a side, its table's offset, dense or hashed.
#[derive(Clone, Copy, Debug, PartialEq)]
struct LevelShape {
    cells: usize,
    offset: usize,
    dense: bool,
    mask: u32,
}

impl LevelShape {
    /// This level's features at `sample` into `out` (`features` values): the trilinear mix of its
    /// cell's 8 vertices in `params`, times the level's [`downweight`].
    #[inline(always)]
    fn read(&self, params: &[f32], sample: &GridSample, out: &mut [f32]) {
        let f = out.len();
        out.fill(0.0);
        let weight = downweight(sample.scale, self.cells);
        for (at, w) in self.corners(sample.at, f) {
            let w = w * weight;
            out.iter_mut().zip(&params[at..at + f]).for_each(|(o, p)| *o += w * p);
        }
    }

    /// The 8 vertices of the cell around `x` (in the box; clamped to its edge), each as its
    /// entry's first parameter and its trilinear weight.
    #[inline(always)]
    fn corners(&self, x: Vec3, features: usize) -> [(usize, f32); 8] {
        let (entries, weights) = self.cell(x);
        std::array::from_fn(|c| (self.offset + entries[c] as usize * features, weights[c]))
    }

    /// The 8 vertices of the cell around `x`: each one's entry in the level's table and its
    /// trilinear weight, vertex `c` at `(c & 1, c >> 1 & 1, c >> 2)` from the cell's lowest.
    #[inline(always)]
    fn cell(&self, x: Vec3) -> ([u32; 8], [f32; 8]) {
        let n = self.cells as f32;
        let axis = |t: f32| {
            let p = t.clamp(0.0, 1.0) * n;
            let i = p.floor().min(n - 1.0).max(0.0);
            (i as u32, p - i)
        };
        let ((i, fx), (j, fy), (k, fz)) = (axis(x.x), axis(x.y), axis(x.z));
        let side = self.cells as u32 + 1;
        let (mut entries, mut weights) = ([0u32; 8], [0.0f32; 8]);
        for c in 0..8 {
            let (dx, dy, dz) = ((c & 1) as u32, ((c >> 1) & 1) as u32, ((c >> 2) & 1) as u32);
            let (a, b, d) = (i + dx, j + dy, k + dz);
            entries[c] = if self.dense {
                a + side * (b + side * d)
            } else {
                (a ^ b.wrapping_mul(PRIMES[0]) ^ d.wrapping_mul(PRIMES[1])) & self.mask
            };
            weights[c] = (if dx == 1 { fx } else { 1.0 - fx })
                * (if dy == 1 { fy } else { 1.0 - fy })
                * (if dz == 1 { fz } else { 1.0 - fz });
        }
        (entries, weights)
    }

    /// [`Self::corners`] of up to [`BLOCK`] samples (each vertex's entry, not yet its offset in
    /// the parameters), times the level's [`downweight`], the same values: sample after sample
    /// in each vertex's row, so that the loop runs across samples in vectors. Lanes past
    /// `samples.len()` are left at entry 0 with weight 0.
    #[inline(always)]
    fn block_corners(&self, samples: &[GridSample]) -> BlockCorners {
        debug_assert!(samples.len() <= BLOCK);
        let mut out = BlockCorners { entry: [[0; BLOCK]; 8], weight: [[0.0; BLOCK]; 8] };
        for (lane, sample) in samples.iter().enumerate() {
            let (entries, weights) = self.cell(sample.at);
            let level_weight = downweight(sample.scale, self.cells);
            for c in 0..8 {
                out.entry[c][lane] = entries[c];
                out.weight[c][lane] = weights[c] * level_weight;
            }
        }
        out
    }
}

/// A block's features at one level into `column` of each sample's row of `rows` (`dim` values
/// a sample): each the sum over the cell's vertices, in their order, of the vertex's weight times
/// its entry (`features` values from `offset + entry · features` in `params`). `F` is the number
/// of features where a loop of that many is to be unrolled, else 0 (then `column`'s length).
#[inline(always)]
fn gather<const F: usize>(
    params: &[f32],
    offset: usize,
    corners: &BlockCorners,
    rows: &mut [f32],
    dim: usize,
    column: std::ops::Range<usize>,
) {
    let f = if F == 0 { column.len() } else { F };
    for (lane, row) in rows.chunks_exact_mut(dim).enumerate() {
        let mut sum = [0.0f32; 16];
        for c in 0..8 {
            let at = offset + corners.entry[c][lane] as usize * f;
            let w = corners.weight[c][lane];
            sum[..f].iter_mut().zip(&params[at..at + f]).for_each(|(s, p)| *s += w * p);
        }
        row[column.clone()].copy_from_slice(&sum[..f]);
    }
}

/// The adjoint of [`gather`]: each sample's gradient in `column` of its row of `rows`, times
/// each vertex's weight, added to the vertex's entry of `table` (a level's gradient, its
/// entries from 0), sample after sample and vertex after vertex.
#[inline(always)]
fn scatter<const F: usize>(
    table: &mut [f32],
    corners: &BlockCorners,
    rows: &[f32],
    dim: usize,
    column: std::ops::Range<usize>,
) {
    let f = if F == 0 { column.len() } else { F };
    for (lane, row) in rows.chunks_exact(dim).enumerate() {
        let d = &row[column.clone()];
        for c in 0..8 {
            let at = corners.entry[c][lane] as usize * f;
            let w = corners.weight[c][lane];
            table[at..at + f].iter_mut().zip(&d[..f]).for_each(|(g, d)| *g += w * d);
        }
    }
}

/// Where a sample reads the grid: its point in the box (`[0, 1]^3`) and its footprint's standard
/// deviation in the box's units (0: a point). Kept from the forward pass for the backward.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GridSample {
    /// The frustum's mean, in the box.
    pub at: Vec3,
    /// The footprint's per-axis standard deviation `σ`, in the box's units.
    pub scale: f32,
}

/// Zip-NeRF's weight of a level of `cells` cells a side (over the box) for a footprint of
/// standard deviation `scale` (box units): `erf(1 / sqrt(8 σ² n²))`, 1 for a point, near 0
/// once the footprint spans several cells.
#[must_use]
#[inline(always)]
pub fn downweight(scale: f32, cells: usize) -> f32 {
    let s = scale * cells as f32 * std::f32::consts::SQRT_2 * 2.0;
    if s.is_nan() || s <= 0.0 { 1.0 } else { erf(1.0 / s) }
}

/// The error function for `x >= 0`, within 1.5e-7 (Abramowitz and Stegun 7.1.26).
#[must_use]
#[inline(always)]
pub fn erf(x: f32) -> f32 {
    if x.is_infinite() {
        return 1.0;
    }
    let t = 1.0 / (1.0 + 0.327_591_1 * x);
    let poly = t * (0.254_829_6 + t * (-0.284_496_74 + t * (1.421_413_7 + t * (-1.453_152_1 + t * 1.061_405_4))));
    // `f32::exp`'s bits (crate::expf), in a form that a loop over samples turns into vectors.
    1.0 - poly * crate::expf::expf(-x * x)
}

/// A grid's shape with each level's constants worked out once (cells a side, where its table
/// starts, dense or hashed), for the inner loops of [`Levels::encode`] and
/// [`Levels::encode_backward_batch`].
#[derive(Clone, Debug, PartialEq)]
pub struct Levels {
    config: HashGridConfig,
    shapes: Vec<LevelShape>,
}

impl Levels {
    /// The levels of `config`.
    #[must_use]
    pub fn new(config: HashGridConfig) -> Self {
        Self { config, shapes: config.level_shapes() }
    }

    /// The grid's shape.
    #[must_use]
    pub fn config(&self) -> &HashGridConfig {
        &self.config
    }

    /// The sample's encoding: every level's trilinear features at `sample.at` times the level's
    /// [`downweight`], into `out` ([`HashGridConfig::encoding_dim`] values), from `params` (the
    /// tables).
    ///
    /// # Panics
    /// If `params` is not [`HashGridConfig::num_params`] or `out` not
    /// [`HashGridConfig::encoding_dim`] long.
    pub fn encode(&self, params: &[f32], sample: &GridSample, out: &mut [f32]) {
        wide(
            #[inline(always)]
            || self.encode_inline(params, sample, out),
        );
    }

    /// [`Self::encode`] for many samples: sample `k` into `out[k · encoding_dim ..]`, the same
    /// values. Level after level over every sample, so that one level's table (a megabyte at
    /// the recipe's `2^17` entries) stays in the core's cache while its samples read it, where
    /// sample after sample would walk every level's table for each.
    ///
    /// # Panics
    /// As [`Self::encode`], for `out` of `samples.len() · encoding_dim` values.
    pub fn encode_many(&self, params: &[f32], samples: &[GridSample], out: &mut [f32]) {
        let (f, dim) = (self.config.features, self.config.encoding_dim());
        assert_eq!(params.len(), self.config.num_params(), "hash grid encode: tables");
        assert_eq!(out.len(), samples.len() * dim, "hash grid encode: output");
        wide(
            #[inline(always)]
            || {
                for (l, shape) in self.shapes.iter().enumerate() {
                    for (block, rows) in samples.chunks(BLOCK).zip(out.chunks_mut(BLOCK * dim)) {
                        let corners = shape.block_corners(block);
                        let column = l * f..(l + 1) * f;
                        match f {
                            2 => gather::<2>(params, shape.offset, &corners, rows, dim, column),
                            4 => gather::<4>(params, shape.offset, &corners, rows, dim, column),
                            _ => gather::<0>(params, shape.offset, &corners, rows, dim, column),
                        }
                    }
                }
            },
        );
    }

    #[inline(always)]
    fn encode_inline(&self, params: &[f32], sample: &GridSample, out: &mut [f32]) {
        let f = self.config.features;
        assert_eq!(params.len(), self.config.num_params(), "hash grid encode: tables");
        assert_eq!(out.len(), self.config.encoding_dim(), "hash grid encode: output");
        for (shape, o) in self.shapes.iter().zip(out.chunks_exact_mut(f)) {
            shape.read(params, sample, o);
        }
    }

    /// The adjoint of [`Self::encode`] over batches of samples (each its samples and the
    /// gradient of their encodings, `samples.len() x encoding_dim`), added to `grad`
    /// ([`HashGridConfig::num_params`] values), the levels in parallel: each level's entries
    /// take their contributions in batch order and sample order, so every entry sums them in
    /// one order whatever the thread count.
    ///
    /// # Panics
    /// If a batch's gradient is not `samples.len() x encoding_dim` or `grad` not the tables'
    /// length.
    pub fn encode_backward_batch(&self, batches: &[(&[GridSample], &[f32])], grad: &mut [f32]) {
        use rayon::prelude::*;
        let (config, f) = (&self.config, self.config.features);
        let dim = config.encoding_dim();
        assert_eq!(grad.len(), config.num_params(), "hash grid encode backward: tables");
        for (samples, d_x) in batches {
            assert_eq!(d_x.len(), samples.len() * dim, "hash grid encode backward: d_x");
        }
        let mut levels = Vec::with_capacity(config.levels);
        let mut rest = grad;
        for (l, shape) in self.shapes.iter().enumerate() {
            let (here, after) = rest.split_at_mut(config.entries(l) * f);
            levels.push((l, LevelShape { offset: 0, ..*shape }, here));
            rest = after;
        }
        levels.par_iter_mut().for_each(|(l, shape, table)| {
            wide(
                #[inline(always)]
                || {
                    for (samples, d_x) in batches {
                        for (block, rows) in samples.chunks(BLOCK).zip(d_x.chunks(BLOCK * dim)) {
                            let corners = shape.block_corners(block);
                            let column = *l * f..(*l + 1) * f;
                            match f {
                                2 => scatter::<2>(table, &corners, rows, dim, column),
                                4 => scatter::<4>(table, &corners, rows, dim, column),
                                _ => scatter::<0>(table, &corners, rows, dim, column),
                            }
                        }
                    }
                },
            );
        });
    }
}
