//! `shaders/occupancy.wgsl`: occupancy-guided coarse edges per ray, and the grid on the device.
//!
//! CPU reference: [`mipnerf_core::stages::sample_occupied_intervals`] (the spans from [`mipnerf_core::occupancy::OccupancyGrid::ray_segments`]).

use mipnerf_core::occupancy::OccupancyGrid;
use mipnerf_core::stages::Sample;

use crate::kernels::Recorder;
use crate::{GpuContext, GpuError, kernels};

/// The WGSL source of this kernel.
pub const SOURCE: super::Shader = super::shader!("occupancy.wgsl", [OccupancyParams]);

/// Most spans one ray keeps in the kernel (WGSL: `MAX_SPANS`).
pub const MAX_SPANS: usize = 256;

/// The finest grid the kernel takes: a ray crosses at most `3 r` cells of a grid of `r` cells per
/// axis, so at most `3 r / 2 + 1` spans, which must fit in [`MAX_SPANS`].
pub const MAX_RESOLUTION: usize = 2 * (MAX_SPANS - 1) / 3;

/// The uniform block of `occupancy.wgsl` (`struct Params`), 48 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct OccupancyParams {
    /// Rays.
    pub n_rays: u32,
    /// Samples per ray.
    pub n_samples: u32,
    /// [`mipnerf_core::sampling::Spacing::code`]: 0 linear in depth, 1 in disparity (a ray with
    /// one span), 2 unbounded (the spans shared out in the normalised distance `s`).
    pub spacing: u32,
    /// 1: training (jitter).
    pub randomized: u32,
    /// Run seed.
    pub seed: u32,
    /// Step.
    pub step: u32,
    /// Cells along each axis.
    pub resolution: u32,
    /// Half the side of the grid's cube (world units).
    pub bound: f32,
    /// The side of one cell (world units), `2 bound / resolution`, computed once on the host.
    pub cell_size: f32,
    /// Workgroups along x.
    pub groups_x: u32,
    /// 1: the grid covers an unbounded scene's contracted space (filled from the grid).
    pub contracted: u32,
    /// Padding.
    pub _pad: u32,
}

/// An [`OccupancyGrid`]'s layers on the device ([`OccupancyGrid::packed_layers`]) and its cells'
/// opacities, with its layout: the opacities are uploaded once and then kept by the updates on
/// the device ([`crate::model::GpuModel::update_grid`]); [`update`](Self::update) writes the
/// layers the host finds from them.
#[derive(Debug)]
pub struct DeviceGrid {
    bits: wgpu::Buffer,
    opacity: wgpu::Buffer,
    /// `[the candidates' mean opacity]`, written and read by the refresh of the layers.
    mean: wgpu::Buffer,
    /// The grid's threshold (before its min with the candidates' mean).
    threshold: f32,
    /// The update after which cells are occupied by their opacity, and whether one has run.
    warmup_steps: u64,
    warmed_up: bool,
    /// An update's density probes (one vec4 per cell of a chunk), made by the first update.
    probes: Option<wgpu::Buffer>,
    resolution: u32,
    bound: f32,
    cell_size: f32,
    contracted: bool,
    decay: f32,
    full: bool,
}

impl DeviceGrid {
    /// Uploads `grid`.
    ///
    /// # Errors
    /// [`GpuError::InvalidInput`] for a grid finer than [`MAX_RESOLUTION`].
    pub fn new(ctx: &GpuContext, grid: &OccupancyGrid) -> Result<Self, GpuError> {
        let r = grid.resolution();
        if r > MAX_RESOLUTION {
            return Err(GpuError::InvalidInput(format!(
                "an occupancy grid of {r} cells per axis: the GPU sampler takes at most {MAX_RESOLUTION}"
            )));
        }
        let bits = ctx.storage_buffer("occupancy grid layers", &grid.packed_layers(), true);
        let opacity = ctx.storage_buffer("occupancy grid opacities", &grid.opacity, true);
        Ok(Self {
            bits,
            opacity,
            mean: ctx.storage_buffer("occupancy grid mean opacity", &[0.0f32], false),
            threshold: grid.config.threshold,
            warmup_steps: grid.config.warmup_steps,
            warmed_up: grid.warmed_up,
            probes: None,
            resolution: r as u32,
            bound: grid.config.bound,
            cell_size: grid.cell_size(),
            contracted: grid.config.contracted,
            decay: grid.config.decay,
            full: grid.is_full(),
        })
    }

    /// Writes `grid`'s occupied cells and their dilations (the same layout as the grid this was
    /// made from). Not its opacities: those on the device are the ones the device's update keeps
    /// ([`crate::model::GpuModel::update_grid`]), which the host's were read from.
    ///
    /// # Errors
    /// [`GpuError::InvalidInput`] for a grid of another layout.
    pub fn update(&mut self, ctx: &GpuContext, grid: &OccupancyGrid) -> Result<(), GpuError> {
        if grid.resolution() as u32 != self.resolution
            || grid.config.bound != self.bound
            || grid.config.contracted != self.contracted
        {
            return Err(GpuError::InvalidInput(format!(
                "an occupancy grid of {} cells over ±{} in place of {} cells over ±{}",
                grid.resolution(),
                grid.config.bound,
                self.resolution,
                self.bound
            )));
        }
        ctx.queue().write_buffer(&self.bits, 0, bytemuck::cast_slice(&grid.packed_layers()));
        self.full = grid.is_full();
        self.warmed_up = grid.warmed_up;
        Ok(())
    }

    /// Cells along each axis.
    #[must_use]
    pub fn resolution(&self) -> usize {
        self.resolution as usize
    }

    /// Half the side of the grid's cube.
    #[must_use]
    pub fn bound(&self) -> f32 {
        self.bound
    }

    /// Whether the grid lies over an unbounded scene's contracted space.
    #[must_use]
    pub fn contracted(&self) -> bool {
        self.contracted
    }

    /// The cells' opacities (`resolution³` f32, x fastest; -1 for a carved cell).
    #[must_use]
    pub fn opacity(&self) -> &wgpu::Buffer {
        &self.opacity
    }

    /// The decay of a cell's remembered opacity at each update.
    #[must_use]
    pub fn decay(&self) -> f32 {
        self.decay
    }

    /// The occupied cells' bit layers (`OccupancyGrid::packed_layers`' layout).
    #[must_use]
    pub fn layers(&self) -> &wgpu::Buffer {
        &self.bits
    }

    /// The threshold of an occupied cell's opacity (before its min with the candidates' mean).
    #[must_use]
    pub fn threshold(&self) -> f32 {
        self.threshold
    }

    /// The scratch of the refresh: the candidates' mean opacity.
    pub(crate) fn mean(&self) -> &wgpu::Buffer {
        &self.mean
    }

    /// Ends an update made at `step`, as the CPU's grid does: the warm-up over once
    /// `step >= warmup_steps`. Whether it is. After the warm-up the layers come from the
    /// opacities on the device, which the host does not read: the grid is no longer known to be
    /// full (the sampler walks it).
    pub(crate) fn end_update(&mut self, step: u64) -> bool {
        self.warmed_up |= step >= self.warmup_steps;
        self.full &= !self.warmed_up;
        self.warmed_up
    }

    /// Whether an update has ended the warm-up.
    #[must_use]
    pub fn warmed_up(&self) -> bool {
        self.warmed_up
    }

    /// Makes the probes' buffer hold at least `n` probes (vec4), kept between updates.
    pub(crate) fn reserve_probes(&mut self, ctx: &GpuContext, n: usize) {
        if self.probes.as_ref().is_some_and(|b| b.size() < 16 * n as u64) {
            self.probes = None;
        }
        self.probes
            .get_or_insert_with(|| ctx.storage_buffer("occupancy grid probes", &vec![[0.0f32; 4]; n.max(1)], true));
    }

    /// The probes' buffer ([`reserve_probes`](Self::reserve_probes)).
    pub(crate) fn probes(&self) -> Option<&wgpu::Buffer> {
        self.probes.as_ref()
    }

    /// Whether every cell is occupied: the sampler is then the paper's (`sample.wgsl`'s
    /// `stratified`), as on the CPU.
    #[must_use]
    pub fn is_full(&self) -> bool {
        self.full
    }
}

/// The rays [`OccupancyKernel::sample`] reads: two vec4 per ray ((origin, radius), (direction,
/// anything)), `(near, far)` per ray, and each ray's index in its step's batch (the stream of
/// its jitter).
#[derive(Clone, Copy, Debug)]
pub struct GuidedRays<'a> {
    /// The rays.
    pub rays: &'a wgpu::Buffer,
    /// Their bounds.
    pub bounds: &'a wgpu::Buffer,
    /// Their indices in the batch.
    pub ray_ids: &'a wgpu::Buffer,
}

/// The pipeline of `occupancy.wgsl`.
#[derive(Debug)]
pub struct OccupancyKernel {
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
}

impl OccupancyKernel {
    /// Compiles the kernel.
    ///
    /// # Errors
    /// If the device rejects it.
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        let ([pipeline], layout) =
            kernels::build_entries(ctx, "occupancy", SOURCE, &[true, true, true, false, true], ["sample_occupied"])?;
        Ok(Self { pipeline, layout })
    }

    /// Records the coarse edges of `n_rays` rays (`rays`: two vec4 per ray, `bounds`: (near,
    /// far) per ray, `ray_ids`: its index in the step's batch, for its jitter) inside `grid`'s
    /// occupied spans into `t_out`, drawn as `how` says.
    ///
    /// # Errors
    /// [`GpuError::InvalidInput`] for a sample count out of range.
    pub fn sample(
        &self,
        rec: &mut Recorder<'_>,
        n_rays: usize,
        how: Sample,
        grid: &DeviceGrid,
        rays: GuidedRays<'_>,
        t_out: &wgpu::Buffer,
    ) -> Result<(), GpuError> {
        let GuidedRays { rays, bounds, ray_ids } = rays;
        let (seed, step, train) = kernels::mode_uniforms(how.mode);
        let mut params = OccupancyParams {
            n_rays: n_rays as u32,
            n_samples: how.n_samples as u32,
            spacing: how.spacing.code(),
            randomized: u32::from(train),
            seed,
            step,
            ..OccupancyParams::default()
        };
        if params.n_samples == 0 || params.n_samples as usize > kernels::sample::MAX_SAMPLES {
            return Err(GpuError::InvalidInput(format!(
                "occupancy: {} samples per ray (1..={})",
                params.n_samples,
                kernels::sample::MAX_SAMPLES
            )));
        }
        let (gx, gy) = kernels::dispatch_grid(u64::from(params.n_rays), kernels::WORKGROUP)?;
        params.groups_x = gx;
        params.resolution = grid.resolution;
        params.bound = grid.bound;
        params.cell_size = grid.cell_size;
        params.contracted = u32::from(grid.contracted);
        rec.dispatch(
            "occupancy",
            &self.pipeline,
            &self.layout,
            &params,
            &[rays, bounds, &grid.bits, t_out, ray_ids],
            (gx, gy, 1),
        );
        Ok(())
    }
}

super::wgsl_struct!(
    OccupancyParams,
    "Params",
    [n_rays, n_samples, spacing, randomized, seed, step, resolution, bound, cell_size, groups_x, contracted, _pad]
);
