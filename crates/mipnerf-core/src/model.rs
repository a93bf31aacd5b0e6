//! The Mip-NeRF model (coarse and fine levels around one MLP), its loss and gradient, on the CPU.
//!
//! One call of [`Model::loss_and_grad`] is the official `train_step` minus the optimiser: for a
//! batch of rays, each level samples intervals (stratified for the coarse level, inverse-CDF from
//! the previous level's weights for the next), casts them to Gaussians, encodes them (IPE), runs
//! the MLP, volume renders, and compares the colour with the target; the gradient of
//! `coarse_loss_mult * coarse + fine` flows back through rendering, the activations and the MLP.
//! The fine level's intervals carry no gradient (the official `stop_level_grad`).
//!
//! The batch is cut into chunks of whole rays that run in parallel (rayon); each chunk's gradient
//! is summed in chunk order, so results are bit-for-bit the same whatever the thread count.

use rayon::prelude::*;

use crate::bf16::{Bf16Support, Precision};
use crate::cone::{Ray, RayShape};
use crate::hash_grid::GridSample;
use crate::mip::Gaussian;
use crate::mlp::{MlpCache, MlpConfigError, MlpShape};
use crate::occupancy::{DensityField, OccupancyGrid};
use crate::render;
use crate::stages::{self, LevelRays, RawGradients, RawOutputs};
use crate::tri_mip::{Pyramid, Taps};
use crate::wide::wide;

pub use crate::config::{
    FAST_SAMPLES, FastRecipe, Field, GridFit, HashGridRecipe, Mode, ModelConfig, PointEncoding, Preset, TriMipRecipe,
};
use field::FieldGrads;
pub use field::FieldState;
pub use rendering::{LevelOutput, Levels};

mod field;
mod rendering;

/// Errors in a model configuration.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ModelError {
    /// The MLP's shape is invalid.
    #[error(transparent)]
    Mlp(#[from] MlpConfigError),
    /// Another setting is out of range.
    #[error("invalid model configuration: {0}")]
    Config(String),
}

/// A model: its configuration and the layout of its parameters (one MLP, or one per level).
#[derive(Clone, Debug)]
pub struct Model {
    config: ModelConfig,
    mlps: Vec<MlpShape>,
    num_params: usize,
    /// The parameters before the MLPs': the Tri-Mip planes' level 0 (none for the Mip-NeRF field).
    field_params: usize,
}

/// Losses of one batch.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct LossStats {
    /// Per level: `sum(lossmult (rgb - gt)²) / (3 sum(lossmult))`, the lossmult-weighted
    /// per-channel mean squared error. (The official code omits the 3, so its losses are 3x these.)
    pub losses: Vec<f32>,
    /// `coarse_loss_mult * sum(losses[..last]) + losses[last]`, plus `distortion`.
    pub loss: f32,
    /// Per level, the plain per-channel MSE (no lossmult), what PSNR is computed from.
    pub mse: Vec<f32>,
    /// The distortion loss's term in `loss`: `distortion_loss_mult` times its mean over the
    /// batch's rays (0 when off).
    pub distortion: f32,
    /// The field's regulariser's term in `loss`, weighted (0 when off): the Tri-Mip planes' total
    /// variation or the hash grid's weight decay.
    pub regulariser: f32,
}

impl LossStats {
    /// PSNR of the last level's plain MSE (`-10 log10(mse)`).
    #[must_use]
    pub fn psnr(&self) -> f32 {
        self.mse.last().map_or(f32::NAN, |&m| crate::metrics::mse_to_psnr(m))
    }
}

/// Rays processed together by one thread.
pub const CHUNK_RAYS: usize = 64;

/// A training batch on the host: `rays` ([`Model::rays_per_pixel`] a pixel) and one target
/// colour a pixel.
#[derive(Clone, Copy, Debug)]
pub struct TrainBatch<'a> {
    /// The rays.
    pub rays: &'a [Ray],
    /// A colour a pixel.
    pub targets: &'a [[f32; 3]],
}

/// What [`Model::loss_and_grad`] may reuse and what guides it; the default reuses nothing and
/// samples as the paper does.
#[derive(Debug, Default)]
pub struct GradWith<'a> {
    /// Per-chunk gradient buffers kept across calls.
    pub scratch: Option<&'a mut GradScratch>,
    /// The occupancy grid guiding the coarse samples.
    pub grid: Option<&'a OccupancyGrid>,
}

/// One chunk of whole pixels for [`Model::run_chunk`]: its rays, their indices in the batch
/// (their random streams), their occupied spans when a grid guides the samples, in training
/// the targets with the loss's norm and the distortion loss's scale, and the mode.
#[derive(Clone, Copy)]
struct Chunk<'a> {
    rays: &'a [Ray],
    ids: RayIds<'a>,
    spans: Option<ChunkSpans<'a>>,
    targets: Option<(&'a [[f32; 3]], f32, f32)>,
    mode: Mode,
}

/// Per-chunk gradient buffers, kept between training steps to avoid reallocating them.
#[derive(Default, Debug, Clone)]
pub struct GradScratch {
    chunk_grads: Vec<Vec<f32>>,
    /// Each chunk's share of the field's gradient (the Tri-Mip planes'), scattered into the
    /// planes after every chunk has run, in chunk order ([`Model::field_backward_chunks`]).
    chunk_field: Vec<FieldGrads>,
    grad_pyramid: Option<Pyramid>,
}

thread_local! {
    /// Each rayon worker keeps its buffers between chunks and between steps.
    static WORKSPACE: std::cell::RefCell<Workspace> = std::cell::RefCell::new(Workspace::default());
}

/// Per-thread buffers of one chunk.
#[derive(Default)]
struct Workspace {
    t: Vec<f32>,
    t_next: Vec<f32>,
    ids: Vec<u32>,
    backgrounds: Vec<[f32; 3]>,
    x: Vec<f32>,
    view: Vec<f32>,
    cache: MlpCache,
    samples: stages::RenderedSamples,
    per_ray: Vec<render::RenderedRay>,
    d_ray_rgb: Vec<[f32; 3]>,
    d_raw_rgb: Vec<f32>,
    d_raw_density: Vec<f32>,
    pixel_rgb: Vec<[f32; 3]>,
    /// The Tri-Mip field's taps of the level's samples (copied to the chunk's [`FieldGrads`]
    /// in training).
    taps: Vec<Taps>,
    /// The hash grid's points and footprints of the level's samples (as `taps`).
    grid_samples: Vec<GridSample>,
}

impl Model {
    /// The model of `config`.
    ///
    /// # Errors
    /// If the configuration is invalid.
    pub fn new(config: ModelConfig) -> Result<Self, ModelError> {
        if config.num_samples < 1 || config.num_levels < 1 {
            return Err(ModelError::Config("num_samples and num_levels must be at least 1".into()));
        }
        if config.max_deg_point <= config.min_deg_point || config.max_deg_point > 24 {
            return Err(ModelError::Config(format!(
                "point encoding degrees {}..{} must be a non-empty range below 24",
                config.min_deg_point, config.max_deg_point
            )));
        }
        if config.supersample < 1 {
            return Err(ModelError::Config("supersample must be at least 1".into()));
        }
        if config.unbounded && config.ray_shape != RayShape::Cone {
            return Err(ModelError::Config(
                "an unbounded scene casts cones: a cylinder keeps its pixel's width out to infinity, where the \
                 contraction squeezes it to nothing but along the ray (cylinders are for forward-facing scenes in NDC)"
                    .into(),
            ));
        }
        Self::check_regulariser_weights(&config)?;
        if !(config.distortion_loss_mult.is_finite() && (0.0..=1.0).contains(&config.distortion_loss_mult)) {
            return Err(ModelError::Config(format!(
                "the distortion loss's weight must be between 0 and 1 (the successor's: 0.01), got {}",
                config.distortion_loss_mult
            )));
        }
        let field_params = match config.field {
            Field::MipNerf => 0,
            Field::TriMip { planes, half_side, .. } => {
                planes.validate().map_err(|e| ModelError::Config(e.to_string()))?;
                if !(half_side.is_finite() && half_side > 0.0) {
                    return Err(ModelError::Config(format!(
                        "the Tri-Mip planes' cube needs a positive half side, got {half_side}"
                    )));
                }
                planes.num_params()
            }
            Field::HashGrid { grid, half_side } => {
                grid.validate().map_err(|e| ModelError::Config(e.to_string()))?;
                if !(half_side.is_finite() && half_side > 0.0) {
                    return Err(ModelError::Config(format!(
                        "the hash grid's cube needs a positive half side, got {half_side}"
                    )));
                }
                grid.num_params()
            }
        };
        let n_mlps = if config.separate_mlps { config.num_levels } else { 1 };
        let mut mlps = Vec::with_capacity(n_mlps);
        let mut off = field_params;
        for _ in 0..n_mlps {
            let s = MlpShape::new(config.mlp_config(), off)?;
            off += s.num_params;
            mlps.push(s);
        }
        Ok(Self { config, mlps, num_params: off, field_params })
    }

    /// The configuration (fixed when the model is made: the parameter layout depends on it).
    #[must_use]
    pub fn config(&self) -> &ModelConfig {
        &self.config
    }

    /// Sets the precision of the MLP's matrix products (on the CPU; a device backend runs f32).
    ///
    /// # Errors
    /// [`ModelError::Config`] for [`Precision::Bf16`] on a CPU with neither AMX-BF16 nor AVX-512
    /// BF16, naming the missing features ([`Bf16Support::detect`]); the precision is then unchanged.
    pub fn set_precision(&mut self, precision: Precision) -> Result<(), ModelError> {
        if let (Precision::Bf16, Bf16Support::Unavailable(why)) = (precision, Bf16Support::detect()) {
            return Err(ModelError::Config(format!("bf16 precision is not available: {why}")));
        }
        for m in &mut self.mlps {
            m.precision = precision;
        }
        Ok(())
    }

    /// The precision of the MLP's matrix products.
    #[must_use]
    pub fn precision(&self) -> Precision {
        self.mlps[0].precision
    }

    /// The MLPs, back to back in the flat parameter buffer (one, or one per level).
    #[must_use]
    pub fn mlps(&self) -> &[MlpShape] {
        &self.mlps
    }

    /// Total parameters of all MLPs.
    #[must_use]
    pub fn num_params(&self) -> usize {
        self.num_params
    }

    /// Host memory of a training step over `batch_pixels` pixels, in bytes: each chunk of
    /// [`CHUNK_RAYS`] rays keeps a whole gradient (`f32` per parameter) so that the chunks can be
    /// summed in a fixed order, plus the rays and targets. Measured peaks (`/usr/bin/time`, CPU,
    /// 4096 and 32768 rays) grow by 1.52 KB a ray for the tiny preset and 6.38 KB for the small
    /// one; this gives 1.59 and 6.44.
    #[must_use]
    pub fn training_bytes(&self, batch_pixels: usize) -> u64 {
        /// A ray, its target, its outputs and index lists, rounded up.
        const BYTES_PER_RAY: u64 = 128;
        let rpp = self.config.supersample * self.config.supersample;
        let chunks = batch_pixels.div_ceil(CHUNK_RAYS.div_ceil(rpp).max(1)) as u64;
        let rays = (batch_pixels as u64).saturating_mul(rpp as u64);
        chunks.saturating_mul(self.num_params as u64 * 4).saturating_add(rays.saturating_mul(BYTES_PER_RAY))
    }

    /// Fresh parameters: Glorot-uniform kernels and zero biases, from `seed`.
    #[must_use]
    pub fn init_params(&self, seed: u64) -> Vec<f32> {
        let mut p = vec![0.0; self.num_params];
        match self.config.field {
            Field::MipNerf => {}
            Field::TriMip { planes, .. } => planes.init(&mut p[..self.field_params], seed.wrapping_add(0x7431_4D49)),
            Field::HashGrid { grid, .. } => grid.init(&mut p[..self.field_params], seed.wrapping_add(0x4841_5348)),
        }
        for (i, m) in self.mlps.iter().enumerate() {
            m.init_glorot(&mut p, seed.wrapping_add(i as u64 * 0x9E37_79B9));
        }
        p
    }

    fn mlp_for_level(&self, level: usize) -> &MlpShape {
        &self.mlps[if self.config.separate_mlps { level } else { 0 }]
    }

    /// Rays per pixel (`supersample²`).
    #[must_use]
    pub fn rays_per_pixel(&self) -> usize {
        self.config.supersample * self.config.supersample
    }

    /// The background colour behind the ray with batch index `ray` in `mode`: in training with
    /// `random_bkgd`, the random colour of its pixel; otherwise white or black (`white_bkgd`).
    fn ray_background(&self, mode: Mode, ray: u32) -> [f32; 3] {
        match mode {
            Mode::Train { seed, step } if self.config.random_bkgd => {
                crate::rng::random_background(seed, step, ray / self.rays_per_pixel() as u32)
            }
            _ => render::background(self.config.white_bkgd),
        }
    }

    /// The occupied spans of each ray under `grid`, or `None` when the grid changes nothing (no
    /// grid, a full one, or supersampled pixels, which it does not guide).
    fn guide(&self, grid: Option<&OccupancyGrid>, rays: &[Ray]) -> Option<Guide> {
        let grid = grid.filter(|g| !g.is_full() && self.rays_per_pixel() == 1)?;
        let per_ray: Vec<Vec<[f32; 2]>> = rays
            .par_iter()
            .map(|r| {
                let mut spans = Vec::new();
                grid.ray_segments(r, &mut spans);
                spans
            })
            .collect();
        let mut guide = Guide { active: Vec::new(), starts: vec![0], spans: Vec::new() };
        for (i, spans) in per_ray.into_iter().enumerate() {
            if !spans.is_empty() {
                guide.active.push(i as u32);
                guide.spans.extend(spans);
                guide.starts.push(guide.spans.len() as u32);
            }
        }
        Some(guide)
    }

    /// The loss of a batch and, added to `grads` (zeroed by the caller), its gradient with
    /// respect to every parameter. `batch.targets` has one colour per pixel; `batch.rays` has
    /// [`rays_per_pixel`](Self::rays_per_pixel) rays per pixel. `with` says what the pass may
    /// reuse (`scratch`: per-chunk gradient buffers kept across calls, so that no call after
    /// the first of a batch size allocates) and what guides it: with a `grid` (see
    /// [`render_guided`](Self::render_guided)) the rays that meet no occupied cell add their
    /// background's error to the loss and nothing to the gradient; a full grid, or none, gives
    /// exactly the paper's result.
    ///
    /// # Panics
    /// If the lengths disagree.
    pub fn loss_and_grad(
        &self,
        params: &[f32],
        batch: TrainBatch<'_>,
        mode: Mode,
        grads: &mut [f32],
        with: GradWith<'_>,
    ) -> LossStats {
        let TrainBatch { rays, targets } = batch;
        let mut own = GradScratch::default();
        let (scratch, grid) = (with.scratch.unwrap_or(&mut own), with.grid);
        let rpp = self.rays_per_pixel();
        assert_eq!(rays.len(), targets.len() * rpp, "loss_and_grad: rays per pixel");
        assert_eq!(params.len(), self.num_params, "loss_and_grad: parameter count");
        assert_eq!(grads.len(), self.num_params, "loss_and_grad: gradient length");
        let lm_sum: f64 = rays.chunks(rpp).map(|r| f64::from(self.lossmult(&r[0]))).sum();
        let norm = (3.0 * lm_sum) as f32;
        let n_pix = targets.len() as f32;
        let guide = self.guide(grid, rays);
        let field = self.field_state(params).with_footprint_floor(self.config.footprint_floor_at(mode));
        // With a guide, only the rays that meet occupied cells run, compacted; the others add
        // their background's error to the sums below.
        let compacted = guide.as_ref().map(|g| {
            let r: Vec<Ray> = g.active.iter().map(|&i| rays[i as usize]).collect();
            let t: Vec<[f32; 3]> = g.active.iter().map(|&i| targets[i as usize]).collect();
            (r, t)
        });
        let (run_rays, run_targets) = compacted.as_ref().map_or((rays, targets), |(r, t)| (r.as_slice(), t.as_slice()));
        // The distortion loss is a mean over every ray of the batch (those that meet no
        // occupied cell have no weights, and add nothing).
        let dist_scale = self.config.distortion_loss_mult / rays.len().max(1) as f32;
        let chunk_pix = CHUNK_RAYS.div_ceil(rpp);
        let n_chunks = run_targets.len().div_ceil(chunk_pix);
        scratch.chunk_grads.resize_with(n_chunks, Vec::new);
        scratch.chunk_field.resize_with(n_chunks, FieldGrads::default);
        // The field's parameters (the planes) come first and take their gradient after the
        // chunks (below), so a chunk's buffer is cleared and summed from `field_params` on only
        // (its first part is allocated zero and never touched).
        let fp = self.field_params;
        let mut sums: Vec<Vec<[f64; 2]>> = scratch.chunk_grads[..n_chunks]
            .par_iter_mut()
            .zip(&mut scratch.chunk_field[..n_chunks])
            .zip(run_rays.par_chunks(chunk_pix * rpp).zip(run_targets.par_chunks(chunk_pix)))
            .enumerate()
            .map(|(ci, ((g, fg), (rays, tg)))| {
                if g.len() == self.num_params {
                    g[fp..].fill(0.0);
                } else {
                    *g = vec![0.0; self.num_params];
                }
                fg.clear();
                let first = ci * chunk_pix * rpp;
                let (ids, spans) = match &guide {
                    Some(guide) => {
                        (RayIds::List(&guide.active[first..first + rays.len()]), Some(guide.spans(first, rays.len())))
                    }
                    None => (RayIds::From(first), None),
                };
                WORKSPACE.with(|ws| {
                    let ws = &mut ws.borrow_mut();
                    let targets = Some((tg, norm, dist_scale));
                    let chunk = Chunk { rays, ids, spans, targets, mode };
                    self.run_chunk(params, &field, chunk, ws, Some((g, fg)), None)
                })
            })
            .collect();
        if let Some(guide) = &guide {
            let mut empty = vec![[0.0f64; 2]; self.config.num_levels];
            let mut next_active = guide.active.iter().peekable();
            for (i, (ray, tg)) in rays.iter().zip(targets).enumerate() {
                if next_active.next_if(|&&a| a as usize == i).is_some() {
                    continue;
                }
                let (bg, lm) = (self.ray_background(mode, i as u32), f64::from(self.lossmult(ray)));
                for level in &mut empty {
                    for k in 0..3 {
                        let e = f64::from(bg[k] - tg[k]);
                        level[0] += lm * e * e;
                        level[1] += e * e;
                    }
                }
            }
            sums.push(empty);
        }
        // Sum the chunks' gradients in chunk order, element by element: the same result whatever
        // the number of threads.
        let chunk_grads = &scratch.chunk_grads[..n_chunks];
        const BLOCK: usize = 8192;
        let (field_grads, mlp_grads) = grads.split_at_mut(fp);
        mlp_grads.par_chunks_mut(BLOCK).enumerate().for_each(|(bi, out)| {
            let (lo, len) = (fp + bi * BLOCK, out.len());
            for g in chunk_grads {
                for (o, &x) in out.iter_mut().zip(&g[lo..lo + len]) {
                    *o += x;
                }
            }
        });
        self.field_backward_chunks(&scratch.chunk_field[..n_chunks], &mut scratch.grad_pyramid, field_grads);
        let regulariser = self.field_regulariser(params, field_grads);
        let levels = self.config.num_levels;
        let mut total = vec![[0.0f64; 2]; levels];
        for s in &sums {
            for l in 0..levels {
                total[l][0] += s[l][0];
                total[l][1] += s[l][1];
            }
        }
        let losses: Vec<f32> = total.iter().map(|s| (s[0] / f64::from(norm)) as f32).collect();
        let mse: Vec<f32> = total.iter().map(|s| (s[1] / (3.0 * f64::from(n_pix))) as f32).collect();
        // run_chunk's entry after the levels': the chunk's distortion loss, scaled.
        let distortion = sums.iter().filter_map(|s| s.get(levels)).map(|d| d[0]).sum::<f64>() as f32;
        let loss = self.level_weights().iter().zip(&losses).map(|(w, l)| w * l).sum::<f32>() + distortion + regulariser;
        LossStats { losses, loss, mse, distortion, regulariser }
    }

    /// The loss weight of each level: `coarse_loss_mult` for all but the last, 1 for the last.
    #[must_use]
    pub fn level_weights(&self) -> Vec<f32> {
        let n = self.config.num_levels;
        (0..n).map(|l| if l + 1 == n { 1.0 } else { self.config.coarse_loss_mult }).collect()
    }

    /// A ray's weight in the loss: its pixel's footprint area relative to a full-resolution pixel
    /// (`lossmult`, the paper's area loss) when the area loss is on, else 1.
    fn lossmult(&self, ray: &Ray) -> f32 {
        if self.config.area_loss { ray.lossmult } else { 1.0 }
    }

    /// Runs all levels over one chunk of whole pixels: the stages of [`crate::stages`] in the
    /// paper's order (see ARCHITECTURE.md), each the reference of one GPU kernel. With `targets`
    /// (`(colours, norm, distortion scale)`), accumulates the gradient into `grads` and returns
    /// per level `[sum lossmult·sq, sum sq]`, then `[distortion loss × scale, 0]`; with `out`,
    /// writes the rendered pixels of the levels it names (with [`Levels::Last`] and no
    /// `targets`, the earlier levels run the MLP's density alone).
    fn run_chunk(
        &self,
        params: &[f32],
        field: &FieldState,
        chunk: Chunk<'_>,
        ws: &mut Workspace,
        mut grads: Option<(&mut [f32], &mut FieldGrads)>,
        mut out: Option<(&mut [LevelOutput], Levels)>,
    ) -> Vec<[f64; 2]> {
        let Chunk { rays, ids, spans, targets, mode } = chunk;
        let c = &self.config;
        let (s, n) = (c.num_samples, rays.len() * c.num_samples);
        self.size_workspace(rays.len(), ws);
        let mut sums = vec![[0.0f64; 2]; c.num_levels + 1];
        ws.ids.clear();
        ws.ids.extend((0..rays.len()).map(|r| ids.get(r)));
        ws.backgrounds.clear();
        ws.backgrounds.extend(ws.ids.iter().map(|&id| self.ray_background(mode, id)));
        stages::encode_view_directions(rays, c.deg_view, &mut ws.view);
        ws.cache.set_training(grads.is_some());
        for level in 0..c.num_levels {
            let coarse = stages::Sample { n_samples: s, spacing: c.spacing(), mode };
            match (level, spans) {
                (0, Some(sp)) => {
                    stages::sample_occupied_intervals(rays, (sp.starts, sp.spans), coarse, &ws.ids, &mut ws.t);
                }
                (0, None) => stages::sample_intervals(rays, coarse, &ws.ids, &mut ws.t),
                _ => {
                    let (t, w) = (&ws.t, &ws.samples.weights);
                    let how = stages::Resample {
                        n_samples: s,
                        spacing: c.spacing(),
                        padding: c.resample_padding,
                        level,
                        mode,
                    };
                    stages::resample_intervals(t, w, how, &ws.ids, &mut ws.t_next);
                    std::mem::swap(&mut ws.t, &mut ws.t_next);
                }
            }
            let mlp = self.mlp_for_level(level);
            self.encode_samples(params, field, rays, mlp.precision, ws);
            let last = level + 1 == c.num_levels;
            let colour_shown = match out {
                Some((_, Levels::Last)) => last,
                _ => true,
            };
            if colour_shown || targets.is_some() {
                mlp.forward(params, &ws.x, &ws.view, rays.len(), s, &mut ws.cache);
            } else {
                // Only this level's weights are used (by the next level's resampling), and they
                // depend on the densities alone: the colours are left at a constant.
                mlp.density(params, &ws.x, n, &mut ws.cache);
                ws.cache.raw_rgb.clear();
                ws.cache.raw_rgb.resize(3 * n, 0.0);
            }
            let noise = stages::DensityNoise::of(c, level, mode);
            stages::add_density_noise(noise, &ws.ids, s, &mut ws.cache.raw_density[..n]);
            let raw = RawOutputs { rgb: &ws.cache.raw_rgb[..3 * n], density: &ws.cache.raw_density[..n] };
            let level_rays = LevelRays { t: &ws.t, rays, backgrounds: &ws.backgrounds };
            stages::render_rays(c, raw, level_rays, &mut ws.samples, &mut ws.per_ray);
            self.average_pixels(ws);
            match out.as_mut() {
                Some((out, Levels::All)) => self.write_level_output(level, c.num_levels, ws, out),
                Some((out, Levels::Last)) if last => self.write_level_output(0, 1, ws, out),
                _ => {}
            }
            let (Some((tg, norm, dist_scale)), Some((grads, field_grads))) = (targets, grads.as_mut()) else {
                continue;
            };
            self.loss_gradient(level, rays, tg, norm, &mut sums[level], ws);
            let raw = RawOutputs { rgb: &ws.cache.raw_rgb[..3 * n], density: &ws.cache.raw_density[..n] };
            let level_rays = LevelRays { t: &ws.t, rays, backgrounds: &ws.backgrounds };
            let d_raw = RawGradients { rgb: &mut ws.d_raw_rgb[..], density: &mut ws.d_raw_density[..] };
            stages::render_rays_backward(c, raw, level_rays, &ws.samples, &ws.d_ray_rgb, d_raw);
            if dist_scale > 0.0 && level + 1 == c.num_levels {
                sums[c.num_levels][0] += f64::from(self.distortion_backward(rays, dist_scale, ws));
            }
            let (x, view, cache) = (&ws.x, &ws.view, &mut ws.cache);
            mlp.backward(
                params,
                crate::mlp::MlpInputs { x, view, samples_per_ray: s },
                cache,
                crate::mlp::OutputGradients { rgb: &ws.d_raw_rgb, density: &ws.d_raw_density },
                grads,
            );
            self.field_backward(params, mlp, n, ws, field_grads);
        }
        sums
    }

    /// The distortion loss ([`stages::distortion_loss`]) of the level just rendered, times
    /// `scale`, summed over the chunk's rays; its gradient added to `ws.d_raw_density` through
    /// the weights ([`render::weights_backward`]) and the density activation.
    fn distortion_backward(&self, rays: &[Ray], scale: f32, ws: &mut Workspace) -> f32 {
        let c = &self.config;
        let s = c.num_samples;
        let (mut edges, mut d_w, mut d_density) = (vec![0.0f32; s + 1], vec![0.0f32; s], vec![0.0f32; s]);
        let mut total = 0.0f32;
        for (r, ray) in rays.iter().enumerate() {
            let (sl, t) = (r * s..(r + 1) * s, &ws.t[r * (s + 1)..(r + 1) * (s + 1)]);
            for (e, &tv) in edges.iter_mut().zip(t) {
                *e = stages::normalised_distance(tv, ray.near, ray.far, c.spacing());
            }
            d_w.fill(0.0);
            d_density.fill(0.0);
            total += scale * stages::distortion_loss(&edges, &ws.samples.weights[sl.clone()], scale, &mut d_w);
            let density = &ws.samples.density[sl.clone()];
            render::weights_backward(density, t, ray.direction, &ws.samples.weights[sl.clone()], &d_w, &mut d_density);
            for (j, i) in sl.enumerate() {
                ws.d_raw_density[i] +=
                    d_density[j] * c.density_activation.derivative(ws.cache.raw_density[i], c.density_bias);
            }
        }
        total
    }

    /// Sizes the workspace for `nr` rays.
    fn size_workspace(&self, nr: usize, ws: &mut Workspace) {
        let c = &self.config;
        let (s, n) = (c.num_samples, nr * c.num_samples);
        ws.t.resize(nr * (s + 1), 0.0);
        ws.t_next.resize(nr * (s + 1), 0.0);
        ws.x.resize(n * c.x_dim(), 0.0);
        ws.view.resize(nr * c.view_dim(), 0.0);
        ws.samples.resize(n);
        ws.per_ray.resize(nr, render::RenderedRay::default());
        ws.d_ray_rgb.resize(nr, [0.0; 3]);
        ws.d_raw_rgb.resize(n * 3, 0.0);
        ws.d_raw_density.resize(n, 0.0);
        ws.pixel_rgb.resize(nr / self.rays_per_pixel(), [0.0; 3]);
    }

    /// This model's density with `params`, as the occupancy grid probes it
    /// ([`OccupancyGrid::update`]).
    #[must_use]
    pub fn density_field<'a>(&'a self, params: &'a [f32]) -> ModelDensity<'a> {
        ModelDensity { model: self, params, field: self.field_state(params) }
    }

    /// One Gaussian (world space) encoded by the configured point encoding into `dst` (`x_dim`
    /// values): IPE, PE of the mean ("w/o IPE"), or NeRF's PE ([`stages::encode_gaussian`]); in an
    /// unbounded scene, after the scene contraction ([`crate::contract::contract_gaussian`]).
    /// Inlined, so that in a [`wide`] loop its IPE runs in 512-bit vectors.
    #[inline(always)]
    pub fn encode_point(&self, g: &Gaussian, dst: &mut [f32]) {
        let c = &self.config;
        let g = if c.unbounded { crate::contract::contract_gaussian(g) } else { *g };
        stages::encode_gaussian(&g, (c.point_encoding, Precision::F32), c.min_deg_point, c.max_deg_point, dst);
    }

    /// Each pixel's colour: the mean of its rays' rendered colours.
    fn average_pixels(&self, ws: &mut Workspace) {
        let rpp = self.rays_per_pixel();
        let inv_rpp = 1.0 / rpp as f32;
        ws.pixel_rgb.iter_mut().for_each(|p| *p = [0.0; 3]);
        for (r, ray) in ws.per_ray.iter().enumerate() {
            for k in 0..3 {
                ws.pixel_rgb[r / rpp][k] += ray.rgb[k] * inv_rpp;
            }
        }
    }

    /// Each pixel's colour, distance and opacity of the level just rendered, into `out` as entry
    /// `slot` of `levels` per pixel.
    fn write_level_output(&self, slot: usize, levels: usize, ws: &Workspace, out: &mut [LevelOutput]) {
        let rpp = self.rays_per_pixel();
        let inv_rpp = 1.0 / rpp as f32;
        for (p, group) in ws.per_ray.chunks(rpp).enumerate() {
            out[p * levels + slot] = LevelOutput {
                rgb: ws.pixel_rgb[p],
                distance: group.iter().map(|g| g.distance).sum::<f32>() * inv_rpp,
                acc: group.iter().map(|g| g.acc).sum::<f32>() * inv_rpp,
            };
        }
    }

    /// The level's loss and each ray's loss gradient with respect to its rendered colour: per
    /// pixel, [`pixel_loss_gradient`] of the area-weighted squared error (adding the pixel's
    /// `lossmult · |e|²` and `|e|²` to `sums`), shared equally by its rays (`ws.d_ray_rgb`).
    fn loss_gradient(
        &self,
        level: usize,
        rays: &[Ray],
        tg: &[[f32; 3]],
        norm: f32,
        sums: &mut [f64; 2],
        ws: &mut Workspace,
    ) {
        let rpp = self.rays_per_pixel();
        let inv_rpp = 1.0 / rpp as f32;
        let level_w = self.level_weights()[level];
        for (r, ray) in rays.iter().enumerate() {
            let p = r / rpp;
            let lm = self.lossmult(ray);
            if r % rpp == 0 {
                for k in 0..3 {
                    let e = ws.pixel_rgb[p][k] - tg[p][k];
                    sums[0] += f64::from(lm) * f64::from(e * e);
                    sums[1] += f64::from(e * e);
                }
            }
            let d_pixel = pixel_loss_gradient(ws.pixel_rgb[p], tg[p], lm, level_w, norm);
            ws.d_ray_rgb[r] = d_pixel.map(|d| d * inv_rpp);
        }
    }
}

/// Where a chunk's rays stand in the batch: the index each draws its random numbers with.
#[derive(Clone, Copy)]
enum RayIds<'a> {
    /// Consecutive rays from this index.
    From(usize),
    /// The listed indices (the rays an occupancy grid let through).
    List(&'a [u32]),
}

impl RayIds<'_> {
    fn get(self, r: usize) -> u32 {
        match self {
            Self::From(first) => (first + r) as u32,
            Self::List(ids) => ids[r],
        }
    }
}

/// The rays of a batch that meet occupied cells (indices into the batch, ascending) and each
/// one's occupied spans (`spans[starts[k]..starts[k + 1]]` for the `k`-th).
struct Guide {
    active: Vec<u32>,
    starts: Vec<u32>,
    spans: Vec<[f32; 2]>,
}

impl Guide {
    /// The spans of the `len` active rays from the `first`-th.
    fn spans(&self, first: usize, len: usize) -> ChunkSpans<'_> {
        ChunkSpans { starts: &self.starts[first..=first + len], spans: &self.spans }
    }
}

/// The occupied spans of one chunk's rays.
#[derive(Clone, Copy)]
struct ChunkSpans<'a> {
    starts: &'a [u32],
    spans: &'a [[f32; 2]],
}

/// The gradient of one level's loss with respect to a pixel's rendered colour: the loss is
/// `level_weight · Σ_pixels lossmult · |rendered - target|² / norm` with `norm = 3 Σ lossmult`
/// over the batch (the official `mse` of each level, weighted by pixel area: the paper's area
/// loss), so this is `level_weight · 2 · lossmult · (rendered - target) / norm`. The one
/// statement of the formula: the GPU's `render.wgsl` (`backward_ray`, `pixel_backward`) and
/// `batch.wgsl` (`norm`) compute the same.
#[must_use]
#[inline]
pub fn pixel_loss_gradient(
    rendered: [f32; 3],
    target: [f32; 3],
    lossmult: f32,
    level_weight: f32,
    norm: f32,
) -> [f32; 3] {
    debug_assert!(norm > 0.0, "pixel_loss_gradient: norm {norm}");
    std::array::from_fn(|k| level_weight * 2.0 * lossmult * (rendered[k] - target[k]) / norm)
}

/// A model's density with its parameters, as the occupancy grid probes it ([`DensityField`]):
/// the first MLP's density after its activation, the probes encoded as the model encodes a sample
/// ([`Model::encode_point`]; in a contracted grid, as they are).
#[derive(Clone)]
pub struct ModelDensity<'a> {
    model: &'a Model,
    params: &'a [f32],
    field: FieldState,
}

impl DensityField for ModelDensity<'_> {
    fn densities(&self, probes: &[Gaussian], contracted: bool) -> Vec<f32> {
        let c = self.model.config();
        let (x_dim, n) = (c.x_dim(), probes.len());
        PROBE_WORKSPACE.with(|ws| {
            let ProbeWorkspace { x, cache } = &mut *ws.borrow_mut();
            x.resize(n * x_dim, 0.0);
            // Through `wide`'s 512-bit vectors (the encodings are inlined into it): the same bits.
            wide(
                #[inline(always)]
                || {
                    for (g, dst) in probes.iter().zip(x.chunks_exact_mut(x_dim)) {
                        self.model.encode_probe(self.params, &self.field, g, contracted, dst);
                    }
                },
            );
            self.model.mlps()[0].density(self.params, x, n, cache);
            cache.raw_density.iter().map(|&raw| c.density_activation.forward(raw, c.density_bias)).collect()
        })
    }
}

thread_local! {
    /// Each thread's buffers for the occupancy grid's density probes, kept between updates
    /// (fresh buffers on every update cost a page fault per 4 KiB page).
    static PROBE_WORKSPACE: std::cell::RefCell<ProbeWorkspace> = std::cell::RefCell::new(ProbeWorkspace::default());
}

/// One thread's buffers for [`ModelDensity`]: the probes' encodings and the MLP's activations.
#[derive(Default)]
struct ProbeWorkspace {
    x: Vec<f32>,
    cache: MlpCache,
}
