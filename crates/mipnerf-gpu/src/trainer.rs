//! [`GpuBackend`]: training and rendering entirely on the device.
//!
//! Uploaded once: the training images and cameras (`DeviceImages`), the parameters and Adam's
//! moments. Each training step is one command buffer: the batch is drawn on the device
//! (`batch.wgsl`, the CPU's pixels for the same seed and step), both levels run forward and
//! backward (`GpuModel`), and Adam updates the parameters (`adam.wgsl`). Nothing is read back
//! unless the caller asks for the step's losses; checkpoints read the parameters and moments. A
//! batch whose intermediates would exceed one device binding or the device's memory budget
//! ([`GpuContext::memory_budget`]) runs in
//! chunks within the step (gradients add up; random numbers are drawn per batch ray), so the
//! step is the same whatever the device's limits.
//!
//! With an occupancy grid (the fast preset), the coarse edges come from `occupancy.wgsl` on the
//! grid on the device; every few steps the grid is updated there as the CPU backend updates it
//! (`occupancy_update.wgsl`: the same probes through the same field; `occupancy_refresh.wgsl`:
//! the occupied cells and their dilations), with nothing read back. The rays that miss the
//! masks' hull (every cell not carved, which training does not change) are found on the host
//! (the CPU's traversal of the CPU's rays for the same pixels) and compacted away on the device
//! (`kernels::compact`): they render the background without sampling, MLP or rendering work. A
//! ray in the hull that meets no occupied cell runs on intervals of zero length: the background,
//! no gradient, as the CPU backend's skipping gives it. An image reads the grid's opacities once
//! and compacts its rays against the occupied cells themselves, as the CPU does.
//!
//! Rendering runs an image in chunks of a fixed number of rays through buffers that are reused
//! from chunk to chunk, so the device memory it takes is set by the chunk size, not the image.

use mipnerf_core::backend::{Backend, BackendError, ImageSpec, RenderedImage, TrainState, WorkCounters};
use mipnerf_core::checkpoint::Checkpoint;
use mipnerf_core::dataset::Dataset;
use mipnerf_core::model::{LevelOutput, Levels, Mode, Model};
use mipnerf_core::occupancy::OccupancyGrid;
use mipnerf_core::stages::AdamStep;
use mipnerf_core::train::{AdamState, OptimConfig, StepReport};

use crate::GradientAtomics;
use crate::kernels::adam::{AdamBuffers, AdamKernel};
use crate::kernels::batch::{BatchKernel, DeviceImages, Draw};
use crate::kernels::compact::{Compaction, kept_rays};
use crate::kernels::occupancy::DeviceGrid;
use crate::kernels::{DispatchCache, Recorder};
use crate::model::{GpuModel, ModelBuffers, Pass, RayBatch};
use crate::{GpuContext, GpuError};

/// Most rays per render chunk when chosen automatically.
pub const MAX_RENDER_CHUNK: usize = 16 * 1024;

/// Training steps submitted before the host waits for the device (bounds the queued work).
pub const MAX_STEPS_IN_FLIGHT: u32 = 8;

/// The share of [`GpuContext::memory_budget`] the render buffers may take when the chunk size
/// is chosen automatically (the training buffers may take all of it).
pub const RENDER_BUDGET_SHARE: u64 = 4;

impl From<GpuError> for BackendError {
    fn from(e: GpuError) -> Self {
        match e {
            GpuError::InvalidInput(m) => Self::Invalid(m),
            GpuError::Unsupported(u) => Self::Unsupported(u),
            e @ (GpuError::OutOfMemory(_) | GpuError::BatchTooLarge { .. }) => Self::OutOfMemory(Box::new(e)),
            e @ GpuError::DeviceLost { .. } => Self::DeviceLost(Box::new(e)),
            other => Self::Device(Box::new(other)),
        }
    }
}

/// The training data on the device, with the buffers of one batch.
#[derive(Debug)]
struct TrainData {
    images: DeviceImages,
    /// The whole batch, as `batch.wgsl` makes it.
    batch: RayBatch,
    /// The model's buffers, for one chunk of the batch.
    work: ModelBuffers,
    /// When the batch runs in chunks: each chunk's rays, copied from `batch`, and every level's
    /// per-ray outputs gathered over the chunks (for the losses).
    chunks: Option<(RayBatch, Vec<wgpu::Buffer>)>,
    /// With an occupancy grid: the cameras (no pixels), to find on the host which of a step's
    /// rays meet an occupied cell, and the buffers of the compacted batch.
    compaction: Option<(Dataset, Compaction)>,
}

/// Training and rendering on a wgpu device. See the [module docs](self).
#[derive(Debug)]
pub struct GpuBackend {
    ctx: GpuContext,
    model: Model,
    optim: OptimConfig,
    seed: u32,
    step: u64,
    adam_t: u64,
    kernels: GpuModel,
    batch_kernel: BatchKernel,
    adam_kernel: AdamKernel,
    state: AdamBuffers,
    train: Option<TrainData>,
    render_chunk: usize,
    /// The render chunk's rays and buffers, and two staging buffers its outputs alternate in.
    render: Option<(RayBatch, ModelBuffers, [wgpu::Buffer; 2])>,
    /// The render chunk's compaction buffers (with an occupancy grid).
    render_compaction: Option<Compaction>,
    in_flight: u32,
    /// Bind groups and uniforms of the training step's dispatches, and of a render chunk's.
    train_cache: DispatchCache,
    render_cache: DispatchCache,
    /// The bind groups of an image's field preparation (the Tri-Mip pyramid), reused.
    field_cache: DispatchCache,
    /// The bind groups of the occupancy grid's update, reused.
    grid_cache: DispatchCache,
    /// The camera of the image being rendered, rewritten in place for each image.
    render_cams: Option<DeviceImages>,
    /// The occupancy grid guiding sampling: on the device, where it is updated.
    occupancy: Option<Occupancy>,
}

/// The occupancy grid of a GPU run. It is updated on the device alone (opacities, occupied cells
/// and dilations), so a training step reads nothing back; the host's copy is brought up to date
/// (its opacities read) only when a checkpoint or an image needs it.
#[derive(Debug)]
struct Occupancy {
    /// The grid on the device, which samples and updates.
    device: DeviceGrid,
    /// The grid on the host as last read (its settings and carving are always current; the
    /// warm-up is the device's, [`DeviceGrid::warmed_up`]).
    host: OccupancyGrid,
    /// Whether the device has updated the grid since the host's was read.
    host_stale: bool,
    /// Every cell not carved occupied: the rays that miss it are skipped in training. A ray that
    /// meets only cells the device found empty runs the model on intervals of zero length and
    /// renders the background with no gradient, as the CPU's skipping gives it.
    hull: OccupancyGrid,
}

impl Occupancy {
    fn new(ctx: &GpuContext, grid: OccupancyGrid) -> Result<Self, GpuError> {
        let device = DeviceGrid::new(ctx, &grid)?;
        let hull = OccupancyGrid::from_state(grid.config, grid.opacity.clone(), false)
            .map_err(|e| GpuError::InvalidInput(e.to_string()))?;
        Ok(Self { device, host: grid, host_stale: false, hull })
    }

    /// The grid as the device holds it: its opacities read, the occupied cells found from them.
    fn read(&self, ctx: &GpuContext) -> Result<OccupancyGrid, GpuError> {
        if !self.host_stale {
            return Ok(self.host.clone());
        }
        let opacity = ctx.read_f32(self.device.opacity(), self.host.opacity.len())?;
        OccupancyGrid::from_state(self.host.config, opacity, self.device.warmed_up())
            .map_err(|e| GpuError::InvalidInput(e.to_string()))
    }

    /// Brings the host's grid up to date, and the device's layers to the host's (the host's
    /// mean is in f64: the two agree but for a cell at the threshold to rounding), so that the
    /// rays the host finds for an image's compaction are those the device samples.
    fn sync(&mut self, ctx: &GpuContext) -> Result<(), GpuError> {
        if self.host_stale {
            self.host = self.read(ctx)?;
            self.device.update(ctx, &self.host)?;
            self.host_stale = false;
        }
        Ok(())
    }
}

impl GpuBackend {
    /// Device bytes one ray of a batch or render chunk of `model` takes (the model's buffers for
    /// its samples), for sizing batches to a memory budget.
    #[must_use]
    pub fn bytes_per_ray(model: &Model) -> u64 {
        crate::model::ModelBuffers::bytes_per_ray(model)
    }
}

impl GpuBackend {
    /// A backend on `ctx` for `model` starting from `state`, training with `optim` and `seed`.
    ///
    /// # Errors
    /// [`GpuError::InvalidInput`] for a state that does not fit the model; device errors.
    pub fn new(
        ctx: GpuContext,
        model: Model,
        optim: OptimConfig,
        seed: u32,
        state: TrainState,
    ) -> Result<Self, GpuError> {
        state.check(&model).map_err(|e| GpuError::InvalidInput(e.to_string()))?;
        let occupancy = state.occupancy.map(|grid| Occupancy::new(&ctx, grid)).transpose()?;
        let render_chunk = auto_chunk(&ctx, &model);
        Ok(Self {
            kernels: GpuModel::new(&ctx)?,
            batch_kernel: BatchKernel::new(&ctx)?,
            adam_kernel: AdamKernel::new(&ctx)?,
            state: AdamBuffers::new(&ctx, &state.params, &state.adam.m, &state.adam.v),
            ctx,
            model,
            optim,
            seed,
            step: state.step,
            adam_t: state.adam.t,
            train: None,
            render_chunk,
            render: None,
            render_compaction: None,
            in_flight: 0,
            train_cache: DispatchCache::default(),
            render_cache: DispatchCache::default(),
            field_cache: DispatchCache::default(),
            grid_cache: DispatchCache::default(),
            render_cams: None,
            occupancy,
        })
    }

    /// Uploads the training images and cameras of `ds` and the buffers of batches of
    /// `batch_rays` pixels (`Model::rays_per_pixel` rays each). A batch whose buffers would not
    /// fit one device binding or [`GpuContext::memory_budget`] runs in chunks.
    ///
    /// # Errors
    /// [`GpuError::InvalidInput`] for data that does not fit the device, or supersampling with
    /// forward-facing (NDC) data; device errors.
    pub fn with_data(self, ds: &Dataset, batch_rays: usize) -> Result<Self, GpuError> {
        let model = &self.model;
        let bind = self.ctx.max_binding_bytes();
        let by_binding = bind / ModelBuffers::largest_buffer_bytes_per_ray(model).max(1);
        let by_budget = self.ctx.memory_budget() / ModelBuffers::bytes_per_ray(model).max(1);
        let chunk = by_binding.min(by_budget).max(1) as usize;
        self.with_data_in_chunks(ds, batch_rays, chunk)
    }

    /// [`with_data`](Self::with_data) running each batch in chunks of at most `chunk_rays` rays
    /// (rounded down to whole pixels, at least one).
    ///
    /// # Errors
    /// As [`with_data`](Self::with_data).
    pub fn with_data_in_chunks(mut self, ds: &Dataset, batch_rays: usize, chunk_rays: usize) -> Result<Self, GpuError> {
        if batch_rays == 0 {
            return Err(GpuError::InvalidInput("a batch needs at least one ray".into()));
        }
        mipnerf_core::backend::check_ndc_supersample(ds.ndc, self.model.config().supersample)
            .map_err(|e| GpuError::InvalidInput(e.to_string()))?;
        let images = DeviceImages::upload(&self.ctx, ds)?;
        // Each pixel is `rays_per_pixel` rays.
        let rpp = self.model.rays_per_pixel();
        let n_rays = batch_rays * rpp;
        let chunk = (chunk_rays / rpp).max(1) * rpp;
        let need = ModelBuffers::bytes_for(&self.model, chunk.min(n_rays));
        let (batch, work, chunks) = self.ctx.allocating(need, || {
            let batch = RayBatch::new(&self.ctx, n_rays);
            if chunk >= n_rays {
                return Ok((batch, ModelBuffers::new(&self.ctx, &self.model, n_rays)?, None));
            }
            let outs = (0..self.model.config().num_levels)
                .map(|l| {
                    self.ctx.storage_buffer(&format!("batch ray outputs level {l}"), &vec![f32::NAN; n_rays * 8], true)
                })
                .collect();
            let work = ModelBuffers::new(&self.ctx, &self.model, chunk)?;
            Ok((batch, work, Some((RayBatch::new(&self.ctx, chunk), outs))))
        })?;
        // Compaction only guides one ray per pixel, as on the CPU.
        let compaction = (self.occupancy.is_some() && rpp == 1).then(|| {
            let levels = self.model.config().num_levels;
            (ds.without_pixels(), Compaction::new(&self.ctx, n_rays, levels))
        });
        self.ctx.check()?;
        self.train = Some(TrainData { images, batch, work, chunks, compaction });
        Ok(self)
    }

    /// Renders in chunks of `rays` rays (at least 1) instead of the automatic size.
    #[must_use]
    pub fn with_render_chunk(mut self, rays: usize) -> Self {
        self.render_chunk = rays.max(1);
        self.render = None;
        self
    }

    /// The device context.
    #[must_use]
    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }

    /// Rays per render chunk.
    #[must_use]
    pub fn render_chunk(&self) -> usize {
        self.render_chunk
    }

    /// Device bytes of the render buffers (0 before the first render): the same for every image.
    #[must_use]
    pub fn render_buffer_bytes(&self) -> u64 {
        let compaction = self.render_compaction.as_ref().map_or(0, Compaction::bytes);
        compaction
            + self.render.as_ref().map_or(0, |(b, w, _)| {
                w.bytes()
                    + [&b.ids, &b.rays, &b.bounds, &b.viewdirs, &b.targets, &b.norm]
                        .iter()
                        .map(|x| x.size())
                        .sum::<u64>()
            })
    }

    /// Device bytes of the training images (0 without training data).
    #[must_use]
    pub fn image_bytes(&self) -> u64 {
        self.train.as_ref().map_or(0, |t| t.images.pixel_bytes)
    }

    fn read_checkpoint(&self) -> Result<Checkpoint, GpuError> {
        let n = self.model.num_params();
        let params = self.ctx.read_f32(&self.state.params, n)?;
        let m = self.ctx.read_f32(&self.state.m, n)?;
        let v = self.ctx.read_f32(&self.state.v, n)?;
        let occupancy = self.occupancy.as_ref().map(|o| o.read(&self.ctx)).transpose()?;
        Ok(Checkpoint { step: self.step, params, adam: AdamState { m, v, t: self.adam_t }, occupancy })
    }

    /// The grid's update when one is due, before the step, from the current parameters (the
    /// CPU trainer's order): the densities, opacities, occupied cells and dilations on the device,
    /// nothing read back. Whether it ran (and so built the Tri-Mip pyramid from the step's
    /// parameters, which the step then uses as it is).
    fn update_grid_if_due(&mut self) -> Result<bool, GpuError> {
        let (Some(data), Some(occupancy)) = (self.train.as_mut(), self.occupancy.as_mut()) else {
            return Ok(false);
        };
        if !occupancy.host.updates_at(self.step) {
            return Ok(false);
        }
        let (model, params) = (&self.model, &self.state.params);
        let mut rec = Recorder::with_cache(&self.ctx, "occupancy update", std::mem::take(&mut self.grid_cache));
        self.kernels.prepare_field(&mut rec, model, params, &data.work, false)?;
        let at = (self.seed, self.step as u32);
        self.kernels.update_grid(&mut rec, model, params, &mut data.work, &mut occupancy.device, at)?;
        self.grid_cache = rec.submit();
        occupancy.host_stale = true;
        Ok(true)
    }

    fn run_step(&mut self, report: bool) -> Result<Option<StepReport>, GpuError> {
        let pyramid_built = self.update_grid_if_due()?;
        let data = self.train.as_mut().ok_or_else(|| GpuError::InvalidInput("no training data".into()))?;
        let grid = self.occupancy.as_ref().map(|o| &o.device);
        let ctx = &self.ctx;
        let step = self.step;
        let mode = Mode::Train { seed: self.seed, step: step as u32 };
        let lr = self.optim.lr.lr(step);
        let TrainData { images, batch, work, chunks, compaction } = data;
        let n = batch.n_rays();
        // The rays that meet a cell of the hull, found on the host for the pixels the device draws.
        let mut kept: Option<&mut Compaction> = None;
        if let (Some(Occupancy { hull, .. }), Some((cameras, c))) = (&self.occupancy, compaction.as_mut())
            && !hull.is_full()
        {
            let rays: Vec<mipnerf_core::Ray> =
                cameras.batch_pixels(n, self.seed, step as u32).map(|(v, x, y)| cameras.ray(v, x, y)).collect();
            if let Some(list) = kept_rays(hull, &rays) {
                c.upload(ctx, &list, n)?;
                kept = Some(c);
            }
        }
        let mut rec = Recorder::with_cache(ctx, "train step", std::mem::take(&mut self.train_cache));
        rec.encoder().clear_buffer(&self.state.grads, 0, None);
        if pyramid_built {
            GpuModel::clear_field_gradient(&mut rec, work);
        } else {
            self.kernels.prepare_field(&mut rec, &self.model, &self.state.params, work, true)?;
        }
        let draw = Draw::Random { seed: self.seed, step: step as u32, random_bkgd: self.model.config().random_bkgd };
        let (area_loss, k) = (self.model.config().area_loss, self.model.config().supersample);
        self.batch_kernel.encode(&mut rec, images, draw, area_loss, k, batch)?;
        let pass = Pass { model: &self.model, params: &self.state.params, mode, grads: Some(&self.state.grads), grid };
        // The rays that run: the whole batch, or the kept ones gathered out of it.
        let n_src = match kept.as_deref_mut() {
            Some(c) => {
                if self.kernels.gather_kept(&mut rec, batch, c)? {
                    c.n_kept()
                } else {
                    0
                }
            }
            None => n,
        };
        let src: &RayBatch = kept.as_deref().map_or(&*batch, |c| &c.batch);
        encode_batch(&self.kernels, &mut rec, pass, (src, n_src), work, chunks.as_mut())?;
        // Every level's outputs in batch order, for the losses a report reads: the background
        // for the rays that were not kept (a step that does not report reads no loss, and the
        // gradient is the kept rays' alone, so it puts nothing back).
        let ray_out: &[wgpu::Buffer] = match (&kept, chunks.as_ref()) {
            (Some(c), chunked) => {
                if report {
                    let kept_out = chunked.map_or(&work.ray_out, |(_, outs)| outs);
                    self.kernels.expand_outputs(&mut rec, &self.model, mode, batch, c, kept_out)?;
                }
                &c.outs
            }
            (None, Some((_, outs))) => outs,
            (None, None) => &work.ray_out,
        };
        let adam = AdamStep {
            cfg: self.optim.adam,
            lr,
            max_val: self.optim.grad_max_val,
            max_norm: self.optim.grad_max_norm,
            split: self.optim.field.map(|f| (self.model.field_params(), f)),
        };
        self.kernels.finish_field(&mut rec, &self.model, &self.state.params, work, &self.state.grads, report)?;
        self.adam_kernel.encode(&mut rec, &adam, self.adam_t + 1, &self.state)?;
        self.train_cache = rec.submit();
        self.adam_t += 1;
        self.step += 1;
        if !report {
            self.in_flight += 1;
            if self.in_flight >= MAX_STEPS_IN_FLIGHT {
                ctx.wait()?;
                self.in_flight = 0;
            }
            ctx.check()?;
            return Ok(None);
        }
        self.in_flight = 0;
        let mut stats = self.kernels.read_losses(ctx, &self.model, batch, ray_out)?;
        stats.regulariser = self.kernels.read_planes_tv(ctx, &self.model, work)?;
        stats.loss += stats.regulariser;
        let grad_norm =
            if self.optim.grad_max_norm > 0.0 { Some(ctx.read_f32(&self.state.stats, 1)?[0]) } else { None };
        Ok(Some(StepReport { step, lr, stats, grad_norm }))
    }

    fn render_all(&mut self, image: &ImageSpec) -> Result<Vec<LevelOutput>, GpuError> {
        let rpp = self.model.rays_per_pixel();
        if let Some(o) = self.occupancy.as_mut() {
            o.sync(&self.ctx)?;
        }
        match &mut self.render_cams {
            Some(c) => c.set_camera(&self.ctx, image)?,
            None => self.render_cams = Some(DeviceImages::camera_only(&self.ctx, image)?),
        }
        let Some(cams) = &self.render_cams else { unreachable!("the render camera was just set") };
        let total = cams.total_pixels() as usize;
        // Whole pixels per chunk.
        let chunk_pixels = (self.render_chunk / rpp).max(1);
        let levels = self.model.config().num_levels;
        if self.render.as_ref().is_none_or(|(b, _, _)| b.capacity() != chunk_pixels * rpp) {
            let rays = chunk_pixels * rpp;
            let need = ModelBuffers::bytes_for(&self.model, rays);
            // Drop the old buffers, and the bind groups that hold them, before making new ones.
            self.render = None;
            self.render_compaction = None;
            self.render_cache = DispatchCache::default();
            self.field_cache = DispatchCache::default();
            let ctx = &self.ctx;
            let made = ctx.allocating(need, || {
                let staging_bytes = (levels * rays * 32) as u64;
                let staging = [0, 1].map(|i| ctx.staging_buffer(&format!("render readback {i}"), staging_bytes));
                Ok((RayBatch::new(ctx, rays), ModelBuffers::new(ctx, &self.model, rays)?, staging))
            })?;
            self.render = Some(made);
        }
        if self.render_compaction.is_none() && self.occupancy.is_some() && rpp == 1 {
            self.render_compaction = Some(Compaction::new(&self.ctx, chunk_pixels, levels));
        }
        let Some((batch, work, staging)) = &mut self.render else { unreachable!("render buffers were just made") };
        // The planes' pyramid, once an image.
        let mut rec = Recorder::with_cache(&self.ctx, "render field", std::mem::take(&mut self.field_cache));
        self.kernels.prepare_field(&mut rec, &self.model, &self.state.params, work, false)?;
        self.field_cache = rec.submit();
        let mut out = Vec::with_capacity(total * levels);
        let ctx = &self.ctx;
        let k = self.model.config().supersample;
        let grid = self.occupancy.as_ref().map(|o| &o.device);
        // Double buffering: chunk i's outputs are copied to staging[i % 2] in its own command
        // buffer and read back while chunk i + 1 runs.
        let read = |slot: usize, n: usize, after: wgpu::SubmissionIndex| -> Result<Vec<LevelOutput>, GpuError> {
            let all = ctx.read_staged(&staging[slot], levels * n * 8, after)?;
            let per_level: Vec<Vec<f32>> = all.chunks(n * 8).map(<[f32]>::to_vec).collect();
            Ok(crate::model::level_outputs(&per_level, n, rpp))
        };
        let mut pending: Option<(usize, usize, wgpu::SubmissionIndex)> = None;
        let mut host_rays = Vec::new();
        for (i, first) in (0..total).step_by(chunk_pixels).enumerate() {
            let n = chunk_pixels.min(total - first) * rpp;
            batch.set_active(n)?;
            work.set_active(n)?;
            // The chunk's rays that meet an occupied cell, found on the host.
            let mut kept = None;
            if let (Some(Occupancy { host: host_grid, .. }), Some(c)) =
                (&self.occupancy, self.render_compaction.as_mut())
                && !host_grid.is_full()
            {
                host_rays.clear();
                image.push_rays(first, n, &mut host_rays);
                if let Some(list) = kept_rays(host_grid, &host_rays) {
                    c.upload(ctx, &list, n)?;
                    kept = Some(c);
                }
            }
            let mut rec = Recorder::with_cache(ctx, "render chunk", std::mem::take(&mut self.render_cache));
            let draw = Draw::Sequential { first: first as u32 };
            self.batch_kernel.encode(&mut rec, cams, draw, false, k, batch)?;
            let pass = Pass { model: &self.model, params: &self.state.params, mode: Mode::Eval, grads: None, grid };
            let outs = match kept {
                Some(c) => {
                    self.kernels.encode_compacted(&mut rec, pass, batch, c, work)?;
                    &c.outs
                }
                None => {
                    self.kernels.encode(&mut rec, pass, batch, work)?;
                    &work.ray_out
                }
            };
            let slot = i % 2;
            for (l, src) in outs.iter().enumerate() {
                rec.encoder().copy_buffer_to_buffer(src, 0, &staging[slot], (l * n * 32) as u64, (n * 32) as u64);
            }
            let (cache, index) = rec.submit_indexed();
            self.render_cache = cache;
            if let Some((s, m, after)) = pending.take() {
                out.extend(read(s, m, after)?);
            }
            pending = Some((slot, n, index));
        }
        if let Some((s, m, after)) = pending {
            out.extend(read(s, m, after)?);
        }
        Ok(out)
    }
}

/// The largest power-of-two chunk (at most [`MAX_RENDER_CHUNK`]) whose buffers fit in a
/// [`RENDER_BUDGET_SHARE`]th of the device's memory budget and its binding size.
fn auto_chunk(ctx: &GpuContext, model: &Model) -> usize {
    let per_ray = ModelBuffers::bytes_per_ray(model).max(1);
    let largest = ModelBuffers::largest_buffer_bytes_per_ray(model).max(1);
    let bind = ctx.max_binding_bytes();
    let mut chunk = MAX_RENDER_CHUNK;
    while chunk > 1
        && (chunk as u64 * per_ray > ctx.memory_budget() / RENDER_BUDGET_SHARE || chunk as u64 * largest > bind)
    {
        chunk /= 2;
    }
    chunk
}

impl Backend for GpuBackend {
    fn describe(&self) -> String {
        let a = &self.ctx.adapter();
        let mib = |b: u64| b as f64 / 1048576.0;
        let atomics = match self.ctx.gradient_atomics() {
            GradientAtomics::Float => "float atomics",
            GradientAtomics::CompareExchange => "compare-exchange",
        };
        let mut s = format!("GPU: {} ({}, {}; shared gradients by {atomics})", a.name, a.backend, a.device_type);
        if let Some(t) = &self.train {
            let chunks =
                t.chunks.as_ref().map_or(String::new(), |(sub, _)| format!(" in chunks of {} rays", sub.capacity()));
            s += &format!(
                "; on the device: {:.1} MiB of training images, {:.1} MiB of batch buffers{chunks}",
                mib(t.images.pixel_bytes),
                mib(t.work.bytes())
            );
        }
        s
    }

    fn model(&self) -> &Model {
        &self.model
    }

    fn step(&self) -> u64 {
        self.step
    }

    fn train_step(&mut self, report: bool) -> Result<Option<StepReport>, BackendError> {
        if self.train.is_none() {
            return Err(BackendError::NoData);
        }
        Ok(self.run_step(report)?)
    }

    fn set_lr_schedule(&mut self, lr: mipnerf_core::schedule::LrSchedule) {
        self.optim.lr = lr;
    }

    fn checkpoint(&mut self) -> Result<Checkpoint, BackendError> {
        Ok(self.read_checkpoint()?)
    }

    fn render(&mut self, image: &ImageSpec, levels: Levels) -> Result<RenderedImage, BackendError> {
        image.check_for(&self.model)?;
        // Every level runs in full here; with `Levels::Last` the coarse level's outputs are
        // dropped.
        let out = self.render_all(image)?;
        let (w, h) = (image.camera.width, image.camera.height);
        let all = RenderedImage::from_outputs(w, h, (self.model.config().num_levels, Levels::All), &out);
        Ok(match levels {
            Levels::All => all,
            Levels::Last => RenderedImage { coarse: None, ..all },
        })
    }

    fn work_counters(&self) -> Option<WorkCounters> {
        Some(self.ctx.counters())
    }
}

/// Records the model on the first `n` rays of `src` (`(src, n)`) with `work`: at once, or in
/// chunks of `chunks`' batch, each chunk's rays copied out of `src`, its outputs copied into
/// `chunks`' per-level buffers at the chunk's place (the gradients add up in `pass.grads`).
fn encode_batch(
    kernels: &GpuModel,
    rec: &mut Recorder<'_>,
    pass: Pass<'_>,
    (src, n): (&RayBatch, usize),
    work: &mut ModelBuffers,
    chunks: Option<&mut (RayBatch, Vec<wgpu::Buffer>)>,
) -> Result<(), GpuError> {
    let Some((sub, outs)) = chunks else {
        if n > 0 {
            work.set_active(n)?;
            kernels.encode(rec, pass, src, work)?;
        }
        return Ok(());
    };
    let chunk = sub.capacity();
    for first in (0..n).step_by(chunk) {
        let m = chunk.min(n - first);
        for (from, to, floats) in [
            (&src.rays, &sub.rays, 8),
            (&src.bounds, &sub.bounds, 2),
            (&src.viewdirs, &sub.viewdirs, 3),
            (&src.targets, &sub.targets, 4),
            (&src.ids, &sub.ids, 1),
        ] {
            let per_ray = floats * 4;
            rec.encoder().copy_buffer_to_buffer(from, (first * per_ray) as u64, to, 0, (m * per_ray) as u64);
        }
        rec.encoder().copy_buffer_to_buffer(&src.norm, 0, &sub.norm, 0, 4);
        sub.set_active(m)?;
        work.set_active(m)?;
        kernels.encode(rec, pass, sub, work)?;
        for (from, to) in work.ray_out.iter().zip(outs.iter()) {
            rec.encoder().copy_buffer_to_buffer(from, 0, to, (first * 32) as u64, (m * 32) as u64);
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use std::error::Error as _;

    use super::*;

    /// A device error becomes the backend error of its kind, and keeps wgpu's error as the source.
    #[test]
    fn gpu_errors_map_to_typed_backend_errors_and_keep_their_source() {
        let oom = GpuError::OutOfMemory(wgpu::Error::OutOfMemory {
            source: Box::new(std::io::Error::other("vkAllocateMemory failed")),
        });
        let e = BackendError::from(oom);
        assert!(matches!(e, BackendError::OutOfMemory(_)), "{e:?}");
        assert_eq!(e.to_string(), "the GPU ran out of memory");
        let wgpu_err = e.source().expect("the wgpu error is kept as the source");
        assert!(wgpu_err.to_string().contains("Out of Memory") || wgpu_err.source().is_some(), "{wgpu_err}");

        let lost = GpuError::DeviceLost { reason: wgpu::DeviceLostReason::Unknown, message: "reset".into() };
        let e = BackendError::from(lost);
        assert!(matches!(e, BackendError::DeviceLost(_)), "{e:?}");
        assert!(e.to_string().contains("reset"), "{e}");

        let e = BackendError::from(GpuError::InvalidInput("3 rays in buffers for 2".into()));
        assert!(matches!(e, BackendError::Invalid(ref m) if m == "3 rays in buffers for 2"), "{e:?}");

        let e = BackendError::from(GpuError::Poll(wgpu::PollError::Timeout));
        assert!(matches!(e, BackendError::Device(_)), "{e:?}");
        assert!(e.source().is_some(), "the poll error is kept as the source: {e:?}");
    }
}
