//! `shaders/gather.wgsl` and `shaders/expand.wgsl`: a batch compacted to the rays an occupancy
//! grid lets through, and their outputs put back in batch order with the background for the
//! others, so that rays that meet no occupied cell cost no sampling, MLP or rendering work (the
//! CPU's guided `Model::loss_and_grad` and `render_guided` do the same).
//!
//! Which rays meet an occupied cell is decided on the host, with the CPU's own traversal of the
//! CPU's own rays (`OccupancyGrid::active_rays`), so both backends skip exactly the same rays;
//! the host uploads the list ([`Compaction::upload`]) in order with the step's commands.
//!
//! CPU reference: the compaction of [`mipnerf_core::model::Model::loss_and_grad`] with a grid.

use mipnerf_core::occupancy::OccupancyGrid;

use crate::kernels::Recorder;
use crate::kernels::batch::RayBatch;
use crate::{GpuContext, GpuError, kernels};

/// The WGSL source of the gather kernel.
pub const GATHER_SOURCE: super::Shader = super::shader!("gather.wgsl", [GatherParams]);
/// The WGSL source of the expand kernel.
pub const EXPAND_SOURCE: super::Shader = super::shader!("expand.wgsl", [ExpandParams]);

/// `slot` of a batch ray that meets no occupied cell (WGSL: `0xffffffffu`).
pub const NOT_KEPT: u32 = u32::MAX;

/// The uniform block of `gather.wgsl` (`struct Params`), 16 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GatherParams {
    /// Rays kept.
    pub n_kept: u32,
    /// Workgroups along x.
    pub groups_x: u32,
    /// Padding.
    pub _pad: [u32; 2],
}

/// The uniform block of `expand.wgsl` (`struct Params`), 32 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct ExpandParams {
    /// Rays in the batch.
    pub n_rays: u32,
    /// Workgroups along x.
    pub groups_x: u32,
    /// `render::BACKGROUND_*`: what a ray that meets nothing renders.
    pub background: u32,
    /// Run seed (random backgrounds).
    pub seed: u32,
    /// Step (random backgrounds).
    pub step: u32,
    /// 1: weight the loss terms by lossmult.
    pub area_loss: u32,
    /// Padding.
    pub _pad: [u32; 2],
}

/// The compiled `gather` pipeline.
#[derive(Debug)]
pub struct GatherKernel {
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
}

impl GatherKernel {
    /// Compiles the kernel.
    ///
    /// # Errors
    /// If the device rejects it.
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        let mut read_only = vec![true; 5];
        read_only.extend([false; 5]);
        let ([pipeline], layout) = kernels::build_entries(ctx, "gather", GATHER_SOURCE, &read_only, ["gather"])?;
        Ok(Self { pipeline, layout })
    }

    /// Records the copy of the `n_kept` rays listed in `kept` (batch indices) from `batch` into
    /// `out` (its first `n_kept` rays, with their batch indices in `out.ids`).
    ///
    /// # Errors
    /// [`GpuError::InvalidInput`] for more rays than `out` holds, or a grid too large.
    pub fn encode(
        &self,
        rec: &mut Recorder<'_>,
        n_kept: usize,
        kept: &wgpu::Buffer,
        batch: &RayBatch,
        out: &RayBatch,
    ) -> Result<(), GpuError> {
        if n_kept > out.capacity() {
            return Err(GpuError::InvalidInput(format!("{n_kept} kept rays in buffers for {}", out.capacity())));
        }
        let (gx, gy) = kernels::dispatch_grid(n_kept as u64, kernels::WORKGROUP)?;
        let p = GatherParams { n_kept: n_kept as u32, groups_x: gx, _pad: [0; 2] };
        let bufs = [
            kept,
            &batch.rays,
            &batch.bounds,
            &batch.viewdirs,
            &batch.targets,
            &out.rays,
            &out.bounds,
            &out.viewdirs,
            &out.targets,
            &out.ids,
        ];
        rec.dispatch("gather", &self.pipeline, &self.layout, &p, &bufs, (gx, gy, 1));
        Ok(())
    }
}

/// The compiled `expand` pipeline.
#[derive(Debug)]
pub struct ExpandKernel {
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
}

impl ExpandKernel {
    /// Compiles the kernel.
    ///
    /// # Errors
    /// If the device rejects it.
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        let read_only = [true, true, true, true, true, false];
        let ([pipeline], layout) = kernels::build_entries(ctx, "expand", EXPAND_SOURCE, &read_only, ["expand"])?;
        Ok(Self { pipeline, layout })
    }

    /// Records one level's outputs of every ray of `batch` into `out` (two vec4 per ray): a kept
    /// ray's from `kept_out` at its `slot`, the background for the others.
    ///
    /// # Errors
    /// [`GpuError::InvalidInput`] for a grid too large.
    pub fn encode(
        &self,
        rec: &mut Recorder<'_>,
        mut params: ExpandParams,
        slot: &wgpu::Buffer,
        batch: &RayBatch,
        kept_out: &wgpu::Buffer,
        out: &wgpu::Buffer,
    ) -> Result<(), GpuError> {
        let (gx, gy) = kernels::dispatch_grid(u64::from(params.n_rays), kernels::WORKGROUP)?;
        params.groups_x = gx;
        let bufs = [slot, &batch.rays, &batch.bounds, &batch.targets, kept_out, out];
        rec.dispatch("expand", &self.pipeline, &self.layout, &params, &bufs, (gx, gy, 1));
        Ok(())
    }
}

/// The buffers of a compacted batch: the kept rays' batch indices and each batch ray's slot
/// (uploaded from the host), the kept rays, and every level's outputs in batch order.
#[derive(Debug)]
pub struct Compaction {
    /// Batch indices of the kept rays (ascending), `u32` each.
    pub kept: wgpu::Buffer,
    /// Per batch ray: its kept ray's index, or [`NOT_KEPT`].
    pub slot: wgpu::Buffer,
    /// The kept rays.
    pub batch: RayBatch,
    /// Per level, two vec4 per batch ray: the outputs in batch order.
    pub outs: Vec<wgpu::Buffer>,
    n_kept: usize,
}

impl Compaction {
    /// Buffers for batches of up to `n_rays` rays of a model of `levels` levels.
    #[must_use]
    pub fn new(ctx: &GpuContext, n_rays: usize, levels: usize) -> Self {
        let n = n_rays.max(1);
        Self {
            kept: ctx.storage_buffer("kept ray indices", &vec![0u32; n], false),
            slot: ctx.storage_buffer("kept ray slots", &vec![NOT_KEPT; n], false),
            batch: RayBatch::new(ctx, n),
            outs: (0..levels)
                .map(|l| ctx.storage_buffer(&format!("expanded ray outputs level {l}"), &vec![f32::NAN; n * 8], true))
                .collect(),
            n_kept: 0,
        }
    }

    /// Device bytes held.
    #[must_use]
    pub fn bytes(&self) -> u64 {
        let b = &self.batch;
        [&self.kept, &self.slot, &b.ids, &b.rays, &b.bounds, &b.viewdirs, &b.targets, &b.norm]
            .iter()
            .chain(self.outs.iter().collect::<Vec<_>>().iter())
            .map(|x| x.size())
            .sum()
    }

    /// Writes the list of `kept` rays (ascending batch indices) of a batch of `n_rays`, in order
    /// with the commands submitted after it.
    ///
    /// # Errors
    /// [`GpuError::InvalidInput`] for a batch larger than these buffers or an index out of order
    /// or range.
    pub fn upload(&mut self, ctx: &GpuContext, kept: &[u32], n_rays: usize) -> Result<(), GpuError> {
        if n_rays > self.batch.capacity() || kept.len() > n_rays {
            return Err(GpuError::InvalidInput(format!(
                "{} kept of {n_rays} rays in buffers for {}",
                kept.len(),
                self.batch.capacity()
            )));
        }
        let mut slot = vec![NOT_KEPT; n_rays.max(1)];
        let mut last = None;
        for (j, &i) in kept.iter().enumerate() {
            if i as usize >= n_rays || last.is_some_and(|l| l >= i) {
                return Err(GpuError::InvalidInput(format!("kept ray {i} out of order or of {n_rays}")));
            }
            last = Some(i);
            slot[i as usize] = j as u32;
        }
        if !kept.is_empty() {
            ctx.queue().write_buffer(&self.kept, 0, bytemuck::cast_slice(kept));
        }
        ctx.queue().write_buffer(&self.slot, 0, bytemuck::cast_slice(&slot));
        self.n_kept = kept.len();
        Ok(())
    }

    /// Rays kept by the last [`upload`](Self::upload).
    #[must_use]
    pub fn n_kept(&self) -> usize {
        self.n_kept
    }
}

/// The batch indices of the `rays` that `grid` lets through, or `None` when it lets every ray
/// through (no compaction needed): [`OccupancyGrid::active_rays`].
#[must_use]
pub fn kept_rays(grid: &OccupancyGrid, rays: &[mipnerf_core::Ray]) -> Option<Vec<u32>> {
    if grid.is_full() {
        return None;
    }
    let kept = grid.active_rays(rays);
    (kept.len() < rays.len()).then_some(kept)
}

super::wgsl_struct!(GatherParams, "Params", [n_kept, groups_x, _pad]);
super::wgsl_struct!(ExpandParams, "Params", [n_rays, groups_x, background, seed, step, area_loss, _pad]);
