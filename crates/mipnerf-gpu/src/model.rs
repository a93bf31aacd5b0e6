//! The whole Mip-NeRF forward pass, loss and gradient of a batch on the device: the same
//! computation as `mipnerf_core::model::Model::loss_and_grad` and `Model::render`, composed from
//! this crate's kernels, with every intermediate kept on the device.
//!
//! Per level: edges (`sample.wgsl`: stratified, or resampled from the previous level's weights),
//! Gaussians and IPE (`cast_ipe.wgsl`), the MLP forward pass, rendering with the loss gradient
//! (`render.wgsl`), and the MLP backward pass into the gradient buffer. Random numbers are the
//! CPU's, so a training-mode batch gives the CPU's result to rounding.
//!
//! The batch comes in a [`RayBatch`]: made on the device by `batch.wgsl` (training and chunked
//! rendering, see [`crate::trainer`]) or uploaded from the host ([`RayBatch::upload`]).

use mipnerf_core::model::{LevelOutput, LossStats, Mode, Model, TrainBatch};
use mipnerf_core::occupancy::OccupancyGrid;
use mipnerf_core::stages;

use crate::kernels::Recorder;
use crate::kernels::batch::ActiveRays;
pub use crate::kernels::batch::RayBatch;
use crate::kernels::cast_ipe::{CastIpeKernel, CastIpeParams};
use crate::kernels::compact::{Compaction, ExpandKernel, ExpandParams, GatherKernel, kept_rays};
use crate::kernels::occupancy::{DeviceGrid, GuidedRays, OccupancyKernel};
use crate::kernels::occupancy_update::{
    OccupancyProbeKernel, OccupancyRefreshKernel, OccupancyUpdateKernel, OccupancyUpdateParams, ProbeBuffers,
    UpdateBuffers,
};
use crate::kernels::render::{RenderBuffers, RenderKernel, RenderParams, background_code};
use crate::kernels::sample::{CoarseLevel, SampleKernels};
use crate::kernels::tri_mip::{FieldBuffers, PlaneField, Samples, TriMipKernel, total_variation_loss};
use crate::kernels::view_enc::ViewEncKernel;
use crate::mlp::{GpuMlp, MlpBuffers, ParamBuffers};
use crate::{GpuContext, GpuError};

/// The per-level intermediates of a batch of `n_rays` rays: edges, MLP activations, weights,
/// output gradients, and the per-ray outputs of every level.
#[derive(Debug)]
pub struct ModelBuffers {
    /// Rays the next pass uses, of those the buffers were made for.
    active: ActiveRays,
    mlp: MlpBuffers,
    t_vals: Vec<wgpu::Buffer>,
    /// Per level, two vec4 per ray: (rgb, distance), (acc, lossmult * se, se, 0).
    pub ray_out: Vec<wgpu::Buffer>,
    weights: wgpu::Buffer,
    d_rgb: wgpu::Buffer,
    /// The Tri-Mip planes' pyramid and its gradient (none for the Mip-NeRF field).
    field: Option<FieldBuffers>,
}

impl ModelBuffers {
    /// Buffers for `n_rays` rays of `model`, filled with NaN.
    ///
    /// # Errors
    /// [`GpuError::InvalidInput`] when one buffer would exceed what the device binds (the message
    /// names the largest batch that fits).
    pub fn new(ctx: &GpuContext, model: &Model, n_rays: usize) -> Result<Self, GpuError> {
        let c = &model.config();
        if c.distortion_loss_mult != 0.0 {
            return Err(GpuError::InvalidInput(
                "the distortion loss runs on the CPU backend only (--backend cpu), not in WGSL".into(),
            ));
        }
        if c.coarse_to_fine_steps != 0 {
            return Err(GpuError::InvalidInput(
                "coarse_to_fine_steps runs on the CPU backend only (--backend cpu): the WGSL kernels read each \
                 sample at its own footprint"
                    .into(),
            ));
        }
        if matches!(c.field, mipnerf_core::model::Field::HashGrid { .. }) {
            return Err(GpuError::InvalidInput(
                "the hash-grid field runs on the CPU backend only (--backend cpu): its WGSL kernels are not written"
                    .into(),
            ));
        }
        let (s, levels) = (c.num_samples, c.num_levels);
        let n = n_rays * s;
        let limit = ctx.max_binding_bytes();
        let widest = Self::largest_buffer_bytes_per_ray(model);
        if n_rays as u64 * widest > limit {
            return Err(GpuError::InvalidInput(format!(
                "{n_rays} rays of {s} samples need a {:.0} MiB buffer; this adapter binds at most {:.0} MiB: \
                 use at most {} rays per batch",
                (n_rays as u64 * widest) as f64 / 1048576.0,
                limit as f64 / 1048576.0,
                limit / widest
            )));
        }
        let nan = |label: &str, len: usize| ctx.storage_buffer(label, &vec![f32::NAN; len.max(1)], true);
        let shape = &model.mlps()[0];
        let mut mlp = MlpBuffers::new(ctx, shape, n_rays, s);
        let field = PlaneField::of(model);
        if let Some(f) = &field {
            // The planes' gradient needs the encodings' own, which the MLP's backward pass gives
            // where they enter the first layer only.
            if (0..shape.config.net_depth).any(|i| shape.concat_after(i)) {
                return Err(GpuError::InvalidInput(
                    "the Tri-Mip field's MLP on the GPU takes no skip connection (skip_layer)".into(),
                ));
            }
            let limit = ctx.max_binding_bytes();
            if 4 * f.planes.num_params() as u64 > limit {
                return Err(GpuError::InvalidInput(format!(
                    "the Tri-Mip planes take {:.0} MiB; this adapter binds at most {:.0} MiB (lower tri_mip_resolution)",
                    (4 * f.planes.num_params()) as f64 / 1048576.0,
                    limit as f64 / 1048576.0
                )));
            }
            mlp = mlp.with_input_gradient(ctx, shape.config.x_dim);
        }
        Ok(Self {
            active: ActiveRays::all(n_rays),
            mlp,
            t_vals: (0..levels).map(|l| nan(&format!("edges level {l}"), n_rays * (s + 1))).collect(),
            ray_out: (0..levels).map(|l| nan(&format!("ray outputs level {l}"), n_rays * 8)).collect(),
            weights: nan("weights", n),
            d_rgb: nan("d raw rgb", n * 3),
            field: field.map(|f| FieldBuffers::new(ctx, &f)),
        })
    }

    /// Device bytes per ray of the largest single buffer (what the binding size limits).
    #[must_use]
    pub fn largest_buffer_bytes_per_ray(model: &Model) -> u64 {
        Self::widest_row(model) as u64 * 4 * model.config().num_samples as u64
    }

    /// Floats per sample of the widest per-sample buffer: the encodings, or what the MLP's
    /// passes keep ([`MlpBuffers::widest_row`]).
    fn widest_row(model: &Model) -> usize {
        MlpBuffers::widest_row(&model.mlps()[0])
    }

    /// Device bytes per ray of these buffers, for sizing chunks.
    #[must_use]
    pub fn bytes_per_ray(model: &Model) -> u64 {
        let shape = &model.mlps()[0];
        let c = &shape.config;
        let cfg = &model.config();
        let s = cfg.num_samples;
        // The MLP's buffers, the encodings' gradient (for a field with parameters), weights
        // and colour gradients per sample; edges and outputs per level.
        let d_x = if cfg.field.is_mip_nerf() { 0 } else { c.x_dim };
        let per_sample = MlpBuffers::floats_per_sample(shape) + d_x + 1 + 3;
        let per_ray = s * per_sample + MlpBuffers::floats_per_ray(shape, s) + cfg.num_levels * (s + 1 + 8);
        per_ray as u64 * 4
    }

    /// Rays the buffers hold.
    #[must_use]
    pub fn capacity(&self) -> usize {
        self.active.capacity()
    }

    /// Device bytes of these buffers for `n_rays` rays: [`bytes_per_ray`](Self::bytes_per_ray)
    /// each, and the weight gradients' partial products (at most `MAX_SPLITS` of the largest
    /// layer's kernel, whatever the batch).
    #[must_use]
    pub fn bytes_for(model: &Model, n_rays: usize) -> u64 {
        let n = n_rays * model.config().num_samples;
        let field = PlaneField::of(model).map_or(0, |f| 2 * f.pyramid_len() + 3 * f.planes.resolution);
        Self::bytes_per_ray(model) * n_rays as u64 + 4 * (MlpBuffers::fixed_floats(&model.mlps()[0], n) + field) as u64
    }

    /// Rays the next pass runs (set by [`set_active`](Self::set_active)).
    #[must_use]
    pub fn n_rays(&self) -> usize {
        self.active.n()
    }

    /// Runs the next passes on the first `n` rays (a chunk's tail), the MLP's buffers included.
    ///
    /// # Errors
    /// As [`ActiveRays::set`].
    pub fn set_active(&mut self, n: usize) -> Result<(), GpuError> {
        self.active.set(n)?;
        self.mlp.set_active(n);
        Ok(())
    }

    /// Device bytes these buffers take.
    #[must_use]
    pub fn bytes(&self) -> u64 {
        let mut b = self.mlp.bytes();
        for buf in self.t_vals.iter().chain(&self.ray_out).chain([&self.weights, &self.d_rgb]) {
            b += buf.size();
        }
        b + self.field.as_ref().map_or(0, FieldBuffers::bytes)
    }
}

/// What a pass of the model reads besides its rays: the model and its parameters on the
/// device, training (random draws, the loss gradient) or rendering, where the gradient is added
/// (training), and the occupancy grid that guides the coarse samples (none: the paper's).
#[derive(Clone, Copy, Debug)]
pub struct Pass<'a> {
    /// The model.
    pub model: &'a Model,
    /// Its parameters.
    pub params: &'a wgpu::Buffer,
    /// Training (seed and step) or rendering.
    pub mode: Mode,
    /// The gradient every parameter's is **added** to; `None` to render.
    pub grads: Option<&'a wgpu::Buffer>,
    /// The grid guiding the coarse samples.
    pub grid: Option<&'a DeviceGrid>,
}

/// The kernels of a model step.
#[derive(Debug)]
pub struct GpuModel {
    sample: SampleKernels,
    occupancy: OccupancyKernel,
    occupancy_update: OccupancyUpdateKernel,
    occupancy_probe: OccupancyProbeKernel,
    occupancy_refresh: OccupancyRefreshKernel,
    cast: CastIpeKernel,
    tri_mip: TriMipKernel,
    view: ViewEncKernel,
    mlp: GpuMlp,
    render: RenderKernel,
    gather: GatherKernel,
    expand: ExpandKernel,
}

/// The family of kernel variants a [`GpuModel`] runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum KernelSet {
    /// Register-blocked products through workgroup memory, 32 invocations per ray for rendering
    /// and resampling: for hardware GPUs.
    Hardware,
    /// Products straight from storage, one invocation per ray: for software adapters.
    Software,
}

impl GpuModel {
    /// Compiles the kernels of `set` (tests run the hardware set on lavapipe with it).
    ///
    /// # Errors
    /// If the device rejects one.
    pub fn with_kernel_set(ctx: &GpuContext, set: KernelSet) -> Result<Self, GpuError> {
        use crate::kernels::matmul::MatmulVariant;
        use crate::kernels::render::RenderVariant;
        use crate::kernels::sample::ResampleVariant;
        let (m, r, s) = match set {
            KernelSet::Hardware => (MatmulVariant::Tiled, RenderVariant::Wide, ResampleVariant::Wide),
            KernelSet::Software => (MatmulVariant::Blocked, RenderVariant::PerRay, ResampleVariant::PerRay),
        };
        Ok(Self {
            sample: SampleKernels::with_variant(ctx, s)?,
            occupancy: OccupancyKernel::new(ctx)?,
            occupancy_update: OccupancyUpdateKernel::new(ctx)?,
            occupancy_probe: OccupancyProbeKernel::new(ctx)?,
            occupancy_refresh: OccupancyRefreshKernel::new(ctx)?,
            cast: CastIpeKernel::new(ctx)?,
            tri_mip: TriMipKernel::new(ctx)?,
            view: ViewEncKernel::new(ctx)?,
            mlp: GpuMlp::with_variant(ctx, m)?,
            render: RenderKernel::with_variant(ctx, r)?,
            gather: GatherKernel::new(ctx)?,
            expand: ExpandKernel::new(ctx)?,
        })
    }

    /// Compiles every kernel, the variants suited to the adapter.
    ///
    /// # Errors
    /// If the device rejects one.
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        Self::with_kernel_set(ctx, if ctx.adapter().is_software { KernelSet::Software } else { KernelSet::Hardware })
    }

    /// Records the model on `batch`: every level's outputs into `work.ray_out`; in training
    /// (`grads` given) also the loss gradient of every parameter, **added** to `grads`.
    ///
    /// With a `grid` that is not full (and one ray per pixel) the coarse sampling is
    /// occupancy-guided (`occupancy.wgsl`, the CPU's `Model::loss_and_grad` with a grid and
    /// `render_guided`): the coarse edges lie in each ray's occupied spans, and a ray that meets
    /// no occupied cell renders the background (no opacity, distance `near`) and adds its
    /// background's error to the loss and nothing to the gradient. Such a ray still runs the
    /// MLP here (on intervals of zero length); [`encode_compacted`](Self::encode_compacted)
    /// skips it, as the CPU does. A full grid, or none, is the paper's stratified sampling.
    ///
    /// # Errors
    /// [`GpuError::InvalidInput`] for buffers of another size or rays that are not whole pixels.
    pub fn encode(
        &self,
        rec: &mut Recorder<'_>,
        pass: Pass<'_>,
        batch: &RayBatch,
        work: &ModelBuffers,
    ) -> Result<(), GpuError> {
        let Pass { model, params, mode, grads, grid } = pass;
        let grid = grid.filter(|g| !g.is_full() && model.rays_per_pixel() == 1);
        if batch.n_rays() != work.n_rays() || batch.n_rays() == 0 {
            return Err(GpuError::InvalidInput(format!(
                "a batch of {} rays with buffers for {}",
                batch.n_rays(),
                work.n_rays()
            )));
        }
        let c = &model.config();
        let (nr, s) = (batch.n_rays(), c.num_samples);
        let (seed, step, randomized) = crate::kernels::mode_uniforms(mode);
        let level_w = model.level_weights();
        rec.context().count_model_rays(nr);
        let bufs = &work.mlp;
        // The fused MLP encodes the view directions where it reads them.
        if !bufs.runs_fused_passes() {
            self.view.encode(rec, nr, c.deg_view, &batch.viewdirs, &bufs.view)?;
        }
        for level in 0..c.num_levels {
            let t = &work.t_vals;
            if level == 0 {
                let how = stages::Sample { n_samples: s, spacing: c.spacing(), mode };
                match grid {
                    Some(g) => {
                        let rays = GuidedRays { rays: &batch.rays, bounds: &batch.bounds, ray_ids: &batch.ids };
                        self.occupancy.sample(rec, nr, how, g, rays, &t[0])?;
                    }
                    None => self.sample.stratified(rec, nr, how, &batch.bounds, &batch.ids, &t[0])?,
                }
            } else {
                let how =
                    stages::Resample { n_samples: s, spacing: c.spacing(), padding: c.resample_padding, level, mode };
                let coarse = CoarseLevel { t: &t[level - 1], weights: &work.weights };
                self.sample.resample(rec, nr, how, coarse, &batch.ids, &t[level])?;
            }
            let samples = Samples { rays: &batch.rays, t_vals: &t[level], n_rays: nr, n_samples: s, probes: false };
            self.encode_samples(rec, model, params, samples, work)?;
            // One MLP for all levels, or one per level (the same shape at its own offset).
            let shape = &model.mlps()[if c.separate_mlps { level } else { 0 }];
            self.mlp.forward(rec, shape, params, bufs, &batch.viewdirs);
            let rb = RenderBuffers {
                raw_rgb: &bufs.raw_rgb,
                raw_density: bufs.raw_density().0,
                t_vals: &t[level],
                rays: &batch.rays,
                targets: &batch.targets,
                weights: &work.weights,
                d_raw_rgb: &work.d_rgb,
                d_raw_density: bufs.d_raw_density().0,
                ray_out: &work.ray_out[level],
                norm: &batch.norm,
                ray_ids: &batch.ids,
            };
            let mut rp = RenderParams::new(c, nr, level_w[level], grads.is_some());
            rp.density_stride = bufs.raw_density().1 as u32;
            rp = rp.with_density_noise(stages::DensityNoise::of(c, level, mode));
            if randomized && c.random_bkgd {
                rp = rp.with_random_background(seed, step);
            }
            self.render.encode(rec, rp, &rb)?;
            if let Some(g) = grads {
                let pg = ParamBuffers { params, grads: g };
                self.mlp.backward(rec, shape, pg, bufs, &work.d_rgb, &batch.viewdirs)?;
                self.field_backward(rec, model, samples, work, g)?;
            }
        }
        Ok(())
    }

    /// The batch's samples encoded into the MLP's input (`work`'s): the IPE of their Gaussians
    /// (`cast_ipe.wgsl`, the Mip-NeRF field), or the Tri-Mip planes read at each frustum's
    /// footprint (`tri_mip.wgsl`, from the pyramid [`prepare_field`](Self::prepare_field)
    /// built). The device's side of the CPU's `Model::encode_samples`.
    fn encode_samples(
        &self,
        rec: &mut Recorder<'_>,
        model: &Model,
        params: &wgpu::Buffer,
        samples: Samples<'_>,
        work: &ModelBuffers,
    ) -> Result<(), GpuError> {
        let c = model.config();
        let x = &work.mlp.x;
        match (PlaneField::of(model), &work.field) {
            (None, _) => {
                let cp = CastIpeParams {
                    n_rays: samples.n_rays as u32,
                    n_samples: samples.n_samples as u32,
                    min_deg: c.min_deg_point,
                    max_deg: c.max_deg_point,
                    ray_shape: c.ray_shape as u32,
                    groups_x: 0,
                    encoding: c.point_encoding as u32,
                    unbounded: u32::from(c.unbounded),
                    probes: u32::from(samples.probes),
                    ..CastIpeParams::default()
                };
                self.cast.encode(rec, cp, samples.rays, samples.t_vals, x)
            }
            (Some(f), Some(bufs)) => self.tri_mip.encode(rec, &f, samples, params, bufs, x),
            (Some(_), None) => Err(GpuError::InvalidInput("buffers made for another model's field".into())),
        }
    }

    /// After the MLP's backward pass of a level: the gradient of the samples' Tri-Mip encodings
    /// scattered into the planes' gradient (level 0 in `grads`, the levels above in the
    /// field's buffers, pushed down by [`finish_field`](Self::finish_field)). Nothing for the
    /// Mip-NeRF field, whose encoding has no parameters.
    fn field_backward(
        &self,
        rec: &mut Recorder<'_>,
        model: &Model,
        samples: Samples<'_>,
        work: &ModelBuffers,
        grads: &wgpu::Buffer,
    ) -> Result<(), GpuError> {
        let (Some(f), Some(bufs), Some(d_x)) = (PlaneField::of(model), &work.field, &work.mlp.d_x) else {
            return Ok(());
        };
        self.tri_mip.scatter(rec, &f, samples, d_x, grads, bufs)
    }

    /// Before a pass over `params` (a training step's chunks, or an image's): the Tri-Mip
    /// planes' pyramid built from them, and in training (`training`) the pyramid's gradient
    /// cleared. Nothing for the Mip-NeRF field.
    ///
    /// # Errors
    /// Planes too large for one dispatch.
    pub fn prepare_field(
        &self,
        rec: &mut Recorder<'_>,
        model: &Model,
        params: &wgpu::Buffer,
        work: &ModelBuffers,
        training: bool,
    ) -> Result<(), GpuError> {
        if training {
            Self::clear_field_gradient(rec, work);
        }
        let (Some(f), Some(bufs)) = (PlaneField::of(model), &work.field) else { return Ok(()) };
        self.tri_mip.build_pyramid(rec, &f, params, bufs)
    }

    /// Before a training step whose pyramid the grid's update just built from the same
    /// parameters: the pyramid's gradient cleared, as [`prepare_field`](Self::prepare_field) in
    /// training does, without building the pyramid again. Nothing for the Mip-NeRF field.
    pub fn clear_field_gradient(rec: &mut Recorder<'_>, work: &ModelBuffers) {
        if let Some(bufs) = &work.field {
            rec.encoder().clear_buffer(&bufs.grad_pyramid, 0, None);
        }
    }

    /// Records an update of `grid`'s opacities from the model's densities at `params`: the CPU's
    /// [`OccupancyGrid::update`] up to its end, on the device. For the Tri-Mip field with a fused
    /// MLP, one dispatch over every cell (`occupancy_probe.wgsl`: its probe read from the planes,
    /// the MLP's trunk and density head, its opacity kept). Otherwise for each chunk of cells (as
    /// many as `work` holds samples): every cell's probe placed (`occupancy_update.wgsl`),
    /// encoded by the field in its probe mode (`cast_ipe.wgsl` or `tri_mip.wgsl`), the first
    /// MLP's forward pass, and the cell's opacity kept. The Tri-Mip pyramid must have been built
    /// from `params` ([`prepare_field`](Self::prepare_field)); `work`'s active rays are left as
    /// they were. Then, as the update's end, which cells are occupied and their dilations, from
    /// the opacities on the device (`occupancy_refresh.wgsl`): nothing is read back.
    ///
    /// # Errors
    /// [`GpuError::InvalidInput`] for a grid over the contracted space of a bounded model or the
    /// reverse (the probes are encoded as they are, in the field's space), and a grid too large
    /// for one dispatch a chunk.
    pub fn update_grid(
        &self,
        rec: &mut Recorder<'_>,
        model: &Model,
        params: &wgpu::Buffer,
        work: &mut ModelBuffers,
        grid: &mut DeviceGrid,
        (seed, step): (u32, u32),
    ) -> Result<(), GpuError> {
        let c = model.config();
        if c.unbounded != grid.contracted() {
            return Err(GpuError::InvalidInput(format!(
                "an occupancy grid {} the contracted space for {} scene: its probes would be read in another space",
                if grid.contracted() { "over" } else { "outside" },
                if c.unbounded { "an unbounded" } else { "a bounded" }
            )));
        }
        let r = grid.resolution();
        let up = OccupancyUpdateParams {
            resolution: r as u32,
            seed,
            step,
            contracted: u32::from(grid.contracted()),
            density_activation: c.density_activation as u32,
            bound: grid.bound(),
            cell_size: 2.0 * grid.bound() / r as f32,
            decay: grid.decay(),
            density_bias: c.density_bias,
            ..OccupancyUpdateParams::default()
        };
        let shape = &model.mlps()[0];
        let fused = PlaneField::of(model)
            .zip(work.field.as_ref())
            .and_then(|planes| work.mlp.fused_trunk(rec, shape, params).map(|trunk| (planes, trunk)));
        if let Some(((f, field), (table, trunk_weights))) = fused {
            let up = OccupancyUpdateParams {
                n_cells: (r * r * r) as u32,
                plane_resolution: f.planes.resolution as u32,
                plane_features: f.planes.features as u32,
                plane_levels: f.planes.levels as u32,
                half_side: f.half_side,
                pre_filtered: u32::from(f.pre_filtered),
                x_dim: shape.config.x_dim as u32,
                net_depth: shape.config.net_depth as u32,
                net_width: shape.config.net_width as u32,
                ..up
            };
            let bufs = ProbeBuffers { params, pyramid: &field.pyramid, table, trunk_weights, grid };
            self.occupancy_probe.encode(rec, up, bufs)?;
        } else {
            self.update_grid_in_chunks(rec, model, params, work, grid, up)?;
        }
        let warmed_up = grid.end_update(u64::from(step));
        self.occupancy_refresh.refresh(rec, grid, warmed_up)
    }

    /// [`update_grid`](Self::update_grid)'s opacities chunk after chunk of cells through the
    /// model's own passes, from the update's uniform block `up` (its grid's and model's values).
    fn update_grid_in_chunks(
        &self,
        rec: &mut Recorder<'_>,
        model: &Model,
        params: &wgpu::Buffer,
        work: &mut ModelBuffers,
        grid: &mut DeviceGrid,
        up: OccupancyUpdateParams,
    ) -> Result<(), GpuError> {
        let s = model.config().num_samples;
        let chunk = work.capacity() * s;
        grid.reserve_probes(rec.context(), chunk);
        let g = &*grid;
        let probes = g.probes().ok_or_else(|| GpuError::InvalidInput("no probe buffer".into()))?;
        let n_cells = g.resolution().pow(3);
        let active = work.n_rays();
        for first in (0..n_cells).step_by(chunk) {
            let count = chunk.min(n_cells - first);
            let rays = count.div_ceil(s);
            work.set_active(rays)?;
            let (raw_density, raw_stride) = work.mlp.raw_density();
            let up = OccupancyUpdateParams {
                first_cell: first as u32,
                n_cells: count as u32,
                raw_stride: raw_stride as u32,
                ..up
            };
            let bufs = UpdateBuffers { probes, raw_density, grid: g };
            self.occupancy_update.place_probes(rec, up, bufs)?;
            let samples = Samples { rays: probes, t_vals: &work.t_vals[0], n_rays: rays, n_samples: s, probes: true };
            self.encode_samples(rec, model, params, samples, work)?;
            // Density alone is read: the colour branch's view input is any buffer.
            self.mlp.forward(rec, &model.mlps()[0], params, &work.mlp, probes);
            self.occupancy_update.update_opacity(rec, up, bufs)?;
        }
        work.set_active(active)
    }

    /// After every chunk of a training step: the pyramid's gradient pushed down into the
    /// planes' (level 0's, in `grads`), and the planes' total variation, weighted by
    /// `planes_tv_mult`, added to it (the CPU's `field_backward_chunks` and
    /// `field_regulariser`), in one dispatch; for a step whose losses are read (`losses_read`),
    /// the total variation's loss too ([`read_planes_tv`](Self::read_planes_tv)). Nothing for
    /// the Mip-NeRF field.
    ///
    /// # Errors
    /// Planes too large for one dispatch.
    pub fn finish_field(
        &self,
        rec: &mut Recorder<'_>,
        model: &Model,
        params: &wgpu::Buffer,
        work: &ModelBuffers,
        grads: &wgpu::Buffer,
        losses_read: bool,
    ) -> Result<(), GpuError> {
        let (Some(f), Some(bufs)) = (PlaneField::of(model), &work.field) else { return Ok(()) };
        let weight = model.config().planes_tv_mult;
        let planes_tv = (weight > 0.0).then_some((weight, params));
        self.tri_mip.push_down(rec, &f, planes_tv, grads, bufs)?;
        if planes_tv.is_some() && losses_read {
            self.tri_mip.total_variation(rec, &f, params, bufs)?;
        }
        Ok(())
    }

    /// The planes' total variation of the last step [`finish_field`](Self::finish_field)
    /// recorded, weighted (read back; waits for the device). 0 when off or for the Mip-NeRF
    /// field.
    ///
    /// # Errors
    /// Any error wgpu reports.
    pub fn read_planes_tv(&self, ctx: &GpuContext, model: &Model, work: &ModelBuffers) -> Result<f32, GpuError> {
        let weight = model.config().planes_tv_mult;
        let (Some(f), Some(bufs)) = (PlaneField::of(model), &work.field) else { return Ok(0.0) };
        if weight <= 0.0 {
            return Ok(0.0);
        }
        let rows = ctx.read_f32(&bufs.tv_rows, 3 * f.planes.resolution)?;
        Ok(total_variation_loss(&f.planes, weight, &rows) as f32)
    }

    /// [`encode`](Self::encode) on only the rays of `batch` that `compaction`'s
    /// last [`upload`](Compaction::upload) kept (those that meet an occupied cell of `grid`):
    /// they are gathered into `compaction.batch` and run with `work` (its active rays set here);
    /// every level's outputs are then put back in batch order in `compaction.outs`, with the
    /// background (and its error) for the rays that were not kept. Those cost no sampling, MLP
    /// or rendering work, as on the CPU.
    ///
    /// # Errors
    /// As [`encode`](Self::encode), and `work` too small for the kept rays.
    pub fn encode_compacted(
        &self,
        rec: &mut Recorder<'_>,
        pass: Pass<'_>,
        batch: &RayBatch,
        compaction: &mut Compaction,
        work: &mut ModelBuffers,
    ) -> Result<(), GpuError> {
        if self.gather_kept(rec, batch, compaction)? {
            work.set_active(compaction.n_kept())?;
            self.encode(rec, pass, &compaction.batch, work)?;
        }
        self.expand_outputs(rec, pass.model, pass.mode, batch, compaction, &work.ray_out)
    }

    /// Records the gathering of the rays `compaction` keeps from `batch` into
    /// `compaction.batch` (active: the kept rays), with the batch's loss denominator. Returns
    /// whether any ray is kept (none: nothing is recorded).
    ///
    /// # Errors
    /// A grid too large for one dispatch.
    pub fn gather_kept(
        &self,
        rec: &mut Recorder<'_>,
        batch: &RayBatch,
        compaction: &mut Compaction,
    ) -> Result<bool, GpuError> {
        let m = compaction.n_kept();
        if m == 0 {
            return Ok(false);
        }
        self.gather.encode(rec, m, &compaction.kept, batch, &compaction.batch)?;
        rec.encoder().copy_buffer_to_buffer(&batch.norm, 0, &compaction.batch.norm, 0, 4);
        compaction.batch.set_active(m)?;
        Ok(true)
    }

    /// Records every level's outputs of `batch` in batch order into `compaction.outs`: the kept
    /// rays' from `kept_out` (one buffer per level, in kept order), the background for the
    /// others (white or black, or in training with random backgrounds the pixel's colour).
    ///
    /// # Errors
    /// A grid too large for one dispatch.
    pub fn expand_outputs(
        &self,
        rec: &mut Recorder<'_>,
        model: &Model,
        mode: Mode,
        batch: &RayBatch,
        compaction: &Compaction,
        kept_out: &[wgpu::Buffer],
    ) -> Result<(), GpuError> {
        let c = model.config();
        let (seed, step, train) = crate::kernels::mode_uniforms(mode);
        let params = ExpandParams {
            n_rays: batch.n_rays() as u32,
            background: background_code(c.white_bkgd, train && c.random_bkgd),
            seed,
            step,
            area_loss: u32::from(c.area_loss),
            ..ExpandParams::default()
        };
        for (src, dst) in kept_out.iter().zip(&compaction.outs) {
            self.expand.encode(rec, params, &compaction.slot, batch, src, dst)?;
        }
        Ok(())
    }

    /// The losses of the last batch recorded with [`encode`](Self::encode), read back from
    /// `ray_out` (one buffer per level, `n_rays x 8` floats: `ModelBuffers::ray_out`, or where a
    /// chunked step gathered them) and the batch's denominator (waits for the device).
    ///
    /// # Errors
    /// Any error wgpu reports.
    pub fn read_losses(
        &self,
        ctx: &GpuContext,
        model: &Model,
        batch: &RayBatch,
        ray_out: &[wgpu::Buffer],
    ) -> Result<LossStats, GpuError> {
        let nr = batch.n_rays();
        let pixels = nr / model.rays_per_pixel();
        let norm = f64::from(ctx.read_f32(&batch.norm, 1)?[0]);
        let mut losses = Vec::new();
        let mut mse = Vec::new();
        for out in ray_out {
            let v = ctx.read_f32(out, nr * 8)?;
            let (lm_se, se): (f64, f64) =
                v.chunks(8).fold((0.0, 0.0), |acc, o| (acc.0 + f64::from(o[5]), acc.1 + f64::from(o[6])));
            losses.push((lm_se / norm) as f32);
            mse.push((se / (3.0 * pixels as f64)) as f32);
        }
        let loss = model.level_weights().iter().zip(&losses).map(|(w, l)| w * l).sum();
        Ok(LossStats { losses, loss, mse, distortion: 0.0, regulariser: 0.0 })
    }

    /// The loss of a batch and the gradient of every parameter, computed on the device from
    /// `params` (uploaded) for `batch` (`Model::rays_per_pixel` rays a pixel, a target a pixel),
    /// with occupancy-guided sampling under `grid` where one is given (see
    /// [`encode`](Self::encode)): the device's counterpart of the CPU's `Model::loss_and_grad`.
    ///
    /// # Errors
    /// [`GpuError::InvalidInput`] for inconsistent sizes and a grid the kernel does not take;
    /// any error wgpu reports.
    pub fn loss_and_grad(
        &self,
        ctx: &GpuContext,
        model: &Model,
        params: &[f32],
        batch: TrainBatch<'_>,
        mode: Mode,
        grid: Option<&OccupancyGrid>,
    ) -> Result<(LossStats, Vec<f32>), GpuError> {
        let TrainBatch { rays, targets } = batch;
        if params.len() != model.num_params() {
            return Err(GpuError::InvalidInput(format!(
                "{} parameters for a model of {}",
                params.len(),
                model.num_params()
            )));
        }
        let batch = RayBatch::upload(ctx, rays, targets, model.rays_per_pixel(), model.config().area_loss)?;
        let mut work = ModelBuffers::new(ctx, model, rays.len())?;
        let params_buf = ctx.storage_buffer("parameters", params, true);
        let grads = ctx.storage_buffer("gradients", &vec![0.0f32; model.num_params()], true);
        let kept = grid.filter(|_| model.rays_per_pixel() == 1).and_then(|g| kept_rays(g, rays));
        let grid = grid.map(|g| DeviceGrid::new(ctx, g)).transpose()?;
        let mut rec = Recorder::new(ctx, "model step");
        self.prepare_field(&mut rec, model, &params_buf, &work, true)?;
        let pass = Pass { model, params: &params_buf, mode, grads: Some(&grads), grid: grid.as_ref() };
        let mut losses = if let Some(kept) = kept {
            // Only the rays that meet an occupied cell run, as on the CPU.
            let mut compaction = Compaction::new(ctx, rays.len(), model.config().num_levels);
            compaction.upload(ctx, &kept, rays.len())?;
            self.encode_compacted(&mut rec, pass, &batch, &mut compaction, &mut work)?;
            self.finish_field(&mut rec, model, &params_buf, &work, &grads, true)?;
            let _ = rec.submit();
            self.read_losses(ctx, model, &batch, &compaction.outs)?
        } else {
            self.encode(&mut rec, pass, &batch, &work)?;
            self.finish_field(&mut rec, model, &params_buf, &work, &grads, true)?;
            let _ = rec.submit();
            self.read_losses(ctx, model, &batch, &work.ray_out)?
        };
        losses.regulariser = self.read_planes_tv(ctx, model, &work)?;
        losses.loss += losses.regulariser;
        Ok((losses, ctx.read_f32(&grads, model.num_params())?))
    }
}

/// Every level's outputs of `n` rays (`rpp` consecutive rays per pixel, averaged), pixel-major,
/// from each level's `n x 8` ray outputs as `render.wgsl` writes them.
#[must_use]
pub fn level_outputs(levels: &[Vec<f32>], n: usize, rpp: usize) -> Vec<LevelOutput> {
    let rpp = rpp.max(1);
    let inv = 1.0 / rpp as f32;
    let mut out = Vec::with_capacity(n / rpp * levels.len());
    for p in 0..n / rpp {
        for l in levels {
            let mut o = LevelOutput::default();
            for r in p * rpp..(p + 1) * rpp {
                let v = &l[8 * r..8 * r + 8];
                for k in 0..3 {
                    o.rgb[k] += v[k] * inv;
                }
                o.distance += v[3];
                o.acc += v[4];
            }
            o.distance *= inv;
            o.acc *= inv;
            out.push(o);
        }
    }
    out
}
