//! `shaders/render.wgsl`: activations, volume rendering, loss and their backward pass per ray.
//!
//! CPU reference: [`mipnerf_core::stages::add_density_noise`], [`mipnerf_core::stages::render_rays`] and [`mipnerf_core::stages::render_rays_backward`].

use mipnerf_core::model::Mode;
use mipnerf_core::stages::DensityNoise;

use crate::kernels::Recorder;
use crate::{GpuContext, GpuError, kernels};

/// The WGSL source of this kernel.
pub const SOURCE: super::Shader = super::shader!("render.wgsl", [RenderParams]);

/// The uniform block of `render.wgsl` (`struct Params`), 64 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct RenderParams {
    /// Rays.
    pub n_rays: u32,
    /// Samples per ray.
    pub n_samples: u32,
    /// What the rays are composited on: [`BACKGROUND_BLACK`], [`BACKGROUND_WHITE`] or (training,
    /// with `seed`, `step` and the rays' batch indices) [`BACKGROUND_RANDOM`].
    pub background: u32,
    /// 0: softplus, 1: ReLU.
    pub density_activation: u32,
    /// Added to raw density.
    pub density_bias: f32,
    /// Colour padding.
    pub rgb_padding: f32,
    /// Loss weight of the level.
    pub level_weight: f32,
    /// Elements between consecutive samples' raw densities (and their gradients): 1, or the row
    /// length of the fused heads `[density | bottleneck]`.
    pub density_stride: u32,
    /// 1: compute the loss gradient.
    pub train: u32,
    /// 1: weight rays by lossmult.
    pub area_loss: u32,
    /// Workgroups along x.
    pub groups_x: u32,
    /// Standard deviation of the training noise on raw density (0: none), drawn from
    /// mipnerf-core's `Stream::DensityNoise` of the ray's stream at this level
    /// (`rng::ray_level_index`).
    pub density_noise: f32,
    /// Run seed (density noise).
    pub seed: u32,
    /// Step (density noise).
    pub step: u32,
    /// Level (density noise).
    pub level: u32,
    /// Rays per pixel side (supersampled NeRF); 1: one ray per pixel. Above 1, `main` only
    /// renders: the loss is the pixel's (the mean of its `k x k` rays' colours), computed with its
    /// gradient by `pixel_backward`.
    pub supersample: u32,
}

impl RenderParams {
    /// The block for a model configuration.
    #[must_use]
    pub fn new(cfg: &mipnerf_core::model::ModelConfig, n_rays: usize, level_weight: f32, train: bool) -> Self {
        Self {
            n_rays: n_rays as u32,
            n_samples: cfg.num_samples as u32,
            background: background_code(cfg.white_bkgd, false),
            density_activation: cfg.density_activation as u32,
            density_bias: cfg.density_bias,
            rgb_padding: cfg.rgb_padding,
            level_weight,
            density_stride: 1,
            train: u32::from(train),
            area_loss: u32::from(cfg.area_loss),
            groups_x: 0,
            density_noise: 0.0,
            seed: 0,
            step: 0,
            level: 0,
            supersample: cfg.supersample as u32,
        }
    }

    /// Composited on each pixel's random colour of training step `(seed, step)`
    /// (`ModelConfig::random_bkgd`).
    #[must_use]
    pub fn with_random_background(mut self, seed: u32, step: u32) -> Self {
        self.background = BACKGROUND_RANDOM;
        self.seed = seed;
        self.step = step;
        self
    }

    /// With the training noise on raw density `noise` (none in evaluation or at 0), as
    /// [`mipnerf_core::stages::add_density_noise`] adds it.
    #[must_use]
    pub fn with_density_noise(mut self, noise: DensityNoise) -> Self {
        if let (true, Mode::Train { seed, step }) = (noise.is_on(), noise.mode) {
            self.density_noise = noise.std;
            self.seed = seed;
            self.step = step;
            self.level = noise.level as u32;
        }
        self
    }
}

/// `background` code: black (alpha dropped, no colour behind the scene).
pub const BACKGROUND_BLACK: u32 = 0;
/// `background` code: white.
pub const BACKGROUND_WHITE: u32 = 1;
/// `background` code: each pixel on its own random colour (`mipnerf_core::rng::random_background`
/// of its place in the batch), in training only.
pub const BACKGROUND_RANDOM: u32 = 2;

/// The `background` code for a model's `white_bkgd` and, in training, its `random_bkgd`.
#[must_use]
pub const fn background_code(white_bkgd: bool, random: bool) -> u32 {
    if random {
        BACKGROUND_RANDOM
    } else if white_bkgd {
        BACKGROUND_WHITE
    } else {
        BACKGROUND_BLACK
    }
}

/// The buffers `render.wgsl` reads and writes.
#[derive(Clone, Copy, Debug)]
pub struct RenderBuffers<'a> {
    /// `n x 3` raw colours.
    pub raw_rgb: &'a wgpu::Buffer,
    /// `n` raw densities.
    pub raw_density: &'a wgpu::Buffer,
    /// `n_rays x (n_samples + 1)` interval edges.
    pub t_vals: &'a wgpu::Buffer,
    /// Two vec4 per ray: (origin, radius), (direction, lossmult).
    pub rays: &'a wgpu::Buffer,
    /// vec4 per ray: target colour.
    pub targets: &'a wgpu::Buffer,
    /// `n` weights (output).
    pub weights: &'a wgpu::Buffer,
    /// `n x 3` (output).
    pub d_raw_rgb: &'a wgpu::Buffer,
    /// `n` (output).
    pub d_raw_density: &'a wgpu::Buffer,
    /// Two vec4 per ray (output): (rgb, distance), (acc, lossmult * se, se, 0).
    pub ray_out: &'a wgpu::Buffer,
    /// One float: `3 * sum(lossmult)` over the batch, the loss's denominator.
    pub norm: &'a wgpu::Buffer,
    /// `u32` per ray: its index in the step's batch (its random streams).
    pub ray_ids: &'a wgpu::Buffer,
}

/// Which entry point renders the rays. Both compute the same maths; they group the sums over a
/// ray's samples differently (rounding only).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RenderVariant {
    /// `main`: one invocation per ray, for software adapters (lavapipe emulates workgroup memory
    /// and barriers per lane).
    PerRay,
    /// `main_wide`: a workgroup of 32 invocations per ray, each a block of its samples, with the
    /// prefix and suffix sums across blocks in lane order: for hardware GPUs, where a few
    /// thousand rays of one invocation each would leave most of the device idle.
    Wide,
}

impl RenderVariant {
    /// The variant for `ctx`'s adapter.
    #[must_use]
    #[cfg(feature = "test-support")]
    pub fn for_adapter(ctx: &GpuContext) -> Self {
        if ctx.adapter().is_software { Self::PerRay } else { Self::Wide }
    }
}

/// The compiled render pipelines: `main` or `main_wide` (the rays) and `pixel_backward`
/// (supersampling).
#[derive(Debug)]
pub struct RenderKernel {
    pipeline: wgpu::ComputePipeline,
    pixel_backward: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    variant: RenderVariant,
}

impl RenderKernel {
    /// Compiles the kernel.
    ///
    /// # Errors
    /// If the device rejects it.
    #[cfg(feature = "test-support")]
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        Self::with_variant(ctx, RenderVariant::for_adapter(ctx))
    }

    /// Compiles `variant`.
    ///
    /// # Errors
    /// If the device rejects it.
    pub fn with_variant(ctx: &GpuContext, variant: RenderVariant) -> Result<Self, GpuError> {
        let read_only = [true, true, true, true, true, false, false, false, false, true, true];
        let entry = match variant {
            RenderVariant::PerRay => "main",
            RenderVariant::Wide => "main_wide",
        };
        let ([pipeline, pixel_backward], layout) =
            kernels::build_entries(ctx, "render", SOURCE, &read_only, [entry, "pixel_backward"])?;
        Ok(Self { pipeline, pixel_backward, layout, variant })
    }

    /// Records one pass over `params.n_rays` rays; with supersampling, also the per-pixel loss
    /// (and in training its gradient) of `pixel_backward`.
    ///
    /// # Errors
    /// [`GpuError::InvalidInput`] for a grid too large for one dispatch, or rays that are not a
    /// whole number of pixels.
    pub fn encode(
        &self,
        rec: &mut Recorder<'_>,
        mut params: RenderParams,
        b: &RenderBuffers<'_>,
    ) -> Result<(), GpuError> {
        let kk = params.supersample.max(1).pow(2);
        if !params.n_rays.is_multiple_of(kk) {
            return Err(GpuError::InvalidInput(format!("{} rays in pixels of {kk} rays", params.n_rays)));
        }
        let per_group = match self.variant {
            RenderVariant::PerRay => kernels::WORKGROUP,
            RenderVariant::Wide => 1,
        };
        let (gx, gy) = kernels::dispatch_grid(u64::from(params.n_rays), per_group)?;
        params.groups_x = gx;
        let bufs = [
            b.raw_rgb,
            b.raw_density,
            b.t_vals,
            b.rays,
            b.targets,
            b.weights,
            b.d_raw_rgb,
            b.d_raw_density,
            b.ray_out,
            b.norm,
            b.ray_ids,
        ];
        rec.dispatch("render", &self.pipeline, &self.layout, &params, &bufs, (gx, gy, 1));
        if kk > 1 {
            // One invocation per ray.
            let (px, py) = kernels::dispatch_grid(u64::from(params.n_rays), kernels::WORKGROUP)?;
            let pp = RenderParams { groups_x: px, ..params };
            rec.dispatch("render pixels", &self.pixel_backward, &self.layout, &pp, &bufs, (px, py, 1));
        }
        Ok(())
    }
}

/// What `render.wgsl` reads, held on the host: the inputs of [`RenderKernel::run`].
#[derive(Clone, Copy, Debug)]
#[cfg(feature = "test-support")]
pub struct RenderInputs<'a> {
    /// `n x 3` raw colours (`n` = rays x samples).
    pub raw_rgb: &'a [f32],
    /// `n` raw densities.
    pub raw_density: &'a [f32],
    /// `rays x (samples + 1)` interval edges.
    pub t: &'a [f32],
    /// The rays (origin, radius, direction and `lossmult` are read).
    pub rays: &'a [mipnerf_core::Ray],
    /// Each ray's index in the batch (its random streams).
    pub ids: &'a [u32],
    /// Each ray's target colour.
    pub targets: &'a [[f32; 3]],
    /// The loss's denominator, `3 * sum(lossmult)` over the batch.
    pub norm: f32,
}

/// What `render.wgsl` writes, read back by [`RenderKernel::run`].
#[derive(Clone, Debug, PartialEq)]
#[cfg(feature = "test-support")]
pub struct RenderOutputs {
    /// `n` rendering weights.
    pub weights: Vec<f32>,
    /// Eight floats per ray: colour, distance, opacity, `lossmult * se`, `se`, 0.
    pub ray_out: Vec<f32>,
    /// `n x 3` gradients of the raw colours (training).
    pub d_raw_rgb: Vec<f32>,
    /// `n` gradients of the raw densities (training).
    pub d_raw_density: Vec<f32>,
}

impl RenderKernel {
    /// Runs the kernel once on host data (for checks and tests; training records it into a step
    /// with [`encode`](Self::encode)). The outputs are filled with NaN first, so anything the
    /// kernel fails to write reads back as NaN.
    ///
    /// # Errors
    /// [`GpuError::InvalidInput`] for lengths that disagree with `params`, or any error wgpu
    /// reports.
    #[cfg(feature = "test-support")]
    pub fn run(
        &self,
        ctx: &GpuContext,
        params: RenderParams,
        input: &RenderInputs<'_>,
    ) -> Result<RenderOutputs, GpuError> {
        let (nr, s) = (params.n_rays as usize, params.n_samples as usize);
        let n = nr * s;
        let lengths = [input.raw_rgb.len(), input.raw_density.len(), input.t.len(), input.rays.len(), input.ids.len()];
        if lengths != [3 * n, n, nr * (s + 1), nr, nr] || input.targets.len() != nr {
            return Err(GpuError::InvalidInput(format!("render: lengths {lengths:?} for {nr} rays of {s} samples")));
        }
        let packed = super::packed_rays(input.rays);
        let targets: Vec<[f32; 4]> = input.targets.iter().map(|t| [t[0], t[1], t[2], 0.0]).collect();
        let buf = |name: &str, v: &[f32], out: bool| ctx.storage_buffer(name, v, out);
        let poisoned = |name: &str, len: usize| ctx.storage_buffer(name, &vec![f32::NAN; len], true);
        let (raw_rgb, raw_density, t_vals) = (
            buf("raw rgb", input.raw_rgb, false),
            buf("raw density", input.raw_density, false),
            buf("t", input.t, false),
        );
        let (rays, targets) =
            (buf("rays", packed.as_flattened(), false), buf("targets", targets.as_flattened(), false));
        let (weights, d_raw_rgb, d_raw_density, ray_out) = (
            poisoned("weights", n),
            poisoned("d raw rgb", 3 * n),
            poisoned("d raw density", n),
            poisoned("ray out", 8 * nr),
        );
        let (norm, ray_ids) = (buf("norm", &[input.norm], false), ctx.storage_buffer("ray ids", input.ids, false));
        let b = RenderBuffers {
            raw_rgb: &raw_rgb,
            raw_density: &raw_density,
            t_vals: &t_vals,
            rays: &rays,
            targets: &targets,
            weights: &weights,
            d_raw_rgb: &d_raw_rgb,
            d_raw_density: &d_raw_density,
            ray_out: &ray_out,
            norm: &norm,
            ray_ids: &ray_ids,
        };
        let mut rec = Recorder::new(ctx, "render (host data)");
        self.encode(&mut rec, params, &b)?;
        let _ = rec.submit();
        Ok(RenderOutputs {
            weights: ctx.read_f32(&weights, n)?,
            ray_out: ctx.read_f32(&ray_out, 8 * nr)?,
            d_raw_rgb: ctx.read_f32(&d_raw_rgb, 3 * n)?,
            d_raw_density: ctx.read_f32(&d_raw_density, n)?,
        })
    }
}

super::wgsl_struct!(
    RenderParams,
    "Params",
    [
        n_rays,
        n_samples,
        background,
        density_activation,
        density_bias,
        rgb_padding,
        level_weight,
        density_stride,
        train,
        area_loss,
        groups_x,
        density_noise,
        seed,
        step,
        level,
        supersample,
    ]
);
