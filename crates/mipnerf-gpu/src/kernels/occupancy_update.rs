//! `shaders/occupancy_update.wgsl`: an occupancy grid's update on the device, the density probes
//! placed in its cells and their opacities kept; `shaders/occupancy_probe.wgsl`: the same through
//! the Tri-Mip planes and a fused MLP in one dispatch; `shaders/occupancy_refresh.wgsl`: its end,
//! the occupied cells and their dilations found from the opacities, on the device too.
//!
//! CPU reference: [`mipnerf_core::occupancy::OccupancyGrid::update`] (its refresh:
//! [`mipnerf_core::occupancy::OccupancyGrid::packed_layers`] after it). The model's passes
//! between the two entry points are [`crate::model::GpuModel::update_grid`]'s.

use crate::kernels::Recorder;
use crate::kernels::occupancy::DeviceGrid;
use crate::{GpuContext, GpuError, kernels};

/// The WGSL source of this kernel.
pub const SOURCE: super::Shader =
    super::shader!("occupancy_update.wgsl", [OccupancyUpdateParams], includes["occupancy_cells.wgsl"]);
/// The WGSL source of the fused update through the Tri-Mip planes.
pub const PROBE_SOURCE: super::Shader = super::shader!(
    "occupancy_probe.wgsl",
    [OccupancyUpdateParams],
    includes["occupancy_cells.wgsl", "plane_taps.wgsl", "mlp_trunk.wgsl"]
);
/// The WGSL source of the refresh of the occupied cells.
pub const REFRESH_SOURCE: super::Shader = super::shader!("occupancy_refresh.wgsl", [RefreshParams]);

/// The uniform block of `occupancy_refresh.wgsl` (`struct Params`), 32 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct RefreshParams {
    /// Cells along each axis.
    pub resolution: u32,
    /// `resolution³`.
    pub n_cells: u32,
    /// Unused (0): every dilation is one dispatch.
    pub layer: u32,
    /// 1: the warm-up is over (cells are occupied by their opacity, not all of them).
    pub warmed_up: u32,
    /// The grid's threshold (before its minimum with the mean).
    pub threshold: f32,
    /// Workgroups along x of the 2-D dispatch grid.
    pub groups_x: u32,
    /// Padding.
    pub pad0: u32,
    /// Padding.
    pub pad1: u32,
}

/// The compiled entry points of `occupancy_refresh.wgsl`.
#[derive(Debug)]
pub struct OccupancyRefreshKernel {
    mean: wgpu::ComputePipeline,
    occupied: wgpu::ComputePipeline,
    dilate: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
}

/// Dispatches a refresh records: the mean, the occupied cells, and every dilation in one.
#[cfg(feature = "test-support")]
pub const REFRESH_DISPATCHES: u64 = 3;

impl OccupancyRefreshKernel {
    /// Compiles the kernel.
    ///
    /// # Errors
    /// If the device rejects it.
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        let ([mean, occupied, dilate], layout) = kernels::build_entries(
            ctx,
            "occupancy_refresh",
            REFRESH_SOURCE,
            &[true, false, false],
            ["candidate_mean", "occupied", "dilate"],
        )?;
        Ok(Self { mean, occupied, dilate, layout })
    }

    /// Records the occupied cells of `grid` and their dilations into its layers, from its
    /// opacities on the device, as the CPU's grid finds them after an update (`warmed_up`: the
    /// warm-up is over, cells are occupied by their opacity): [`REFRESH_DISPATCHES`] dispatches.
    ///
    /// # Errors
    /// A grid too large for one dispatch.
    pub fn refresh(&self, rec: &mut Recorder<'_>, grid: &DeviceGrid, warmed_up: bool) -> Result<(), GpuError> {
        let r = grid.resolution() as u32;
        let n = r * r * r;
        let (gx, gy) = kernels::dispatch_grid(u64::from(n), kernels::WORKGROUP)?;
        let p = RefreshParams {
            resolution: r,
            n_cells: n,
            warmed_up: u32::from(warmed_up),
            threshold: grid.threshold(),
            groups_x: gx,
            ..RefreshParams::default()
        };
        let bufs = [grid.opacity(), grid.layers(), grid.mean()];
        rec.encoder().clear_buffer(grid.layers(), 0, None);
        rec.dispatch("occupancy_refresh candidate_mean", &self.mean, &self.layout, &p, &bufs, (1, 1, 1));
        rec.dispatch("occupancy_refresh occupied", &self.occupied, &self.layout, &p, &bufs, (gx, gy, 1));
        rec.dispatch("occupancy_refresh dilate", &self.dilate, &self.layout, &p, &bufs, (gx, gy, 1));
        Ok(())
    }
}

super::wgsl_struct!(RefreshParams, "Params", [resolution, n_cells, layer, warmed_up, threshold, groups_x, pad0, pad1]);

/// The uniform block of `occupancy_update.wgsl` and `occupancy_probe.wgsl` (`struct Params`),
/// 96 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct OccupancyUpdateParams {
    /// The chunk's first cell.
    pub first_cell: u32,
    /// Cells in the chunk.
    pub n_cells: u32,
    /// Cells along each axis.
    pub resolution: u32,
    /// Workgroups along x of the 2-D dispatch grid.
    pub groups_x: u32,
    /// Run seed.
    pub seed: u32,
    /// The step the update is made at.
    pub step: u32,
    /// 1: the grid lies over an unbounded scene's contracted space.
    pub contracted: u32,
    /// [`mipnerf_core::render::DensityActivation`] code.
    pub density_activation: u32,
    /// Half the side of the grid's cube.
    pub bound: f32,
    /// The side of one cell.
    pub cell_size: f32,
    /// The decay of a cell's remembered opacity.
    pub decay: f32,
    /// Added to the raw density before its activation.
    pub density_bias: f32,
    /// Floats between consecutive samples' raw densities.
    pub raw_stride: u32,
    /// The fused update (`occupancy_probe.wgsl`): texels along a side of the planes' level 0.
    pub plane_resolution: u32,
    /// The fused update: features a texel.
    pub plane_features: u32,
    /// The fused update: the planes' pyramid levels, level 0 included.
    pub plane_levels: u32,
    /// The fused update: the planes' box is `[-half_side, half_side]^3`.
    pub half_side: f32,
    /// The fused update: 1 to read each probe at its footprint's level (tri-mip), 0 at level 0.
    pub pre_filtered: u32,
    /// The fused update: the MLP's input width (the planes' encoding).
    pub x_dim: u32,
    /// The fused update: the MLP's trunk layers.
    pub net_depth: u32,
    /// The fused update: the trunk's width.
    pub net_width: u32,
    /// Padding to 16 bytes.
    pub pad0: u32,
    /// Padding.
    pub pad1: u32,
    /// Padding.
    pub pad2: u32,
}

/// The buffers an update's chunk reads and writes.
#[derive(Clone, Copy, Debug)]
pub struct UpdateBuffers<'a> {
    /// One vec4 per cell of the chunk (mean, variance): written by
    /// [`OccupancyUpdateKernel::place_probes`], read by the encoders in probe mode.
    pub probes: &'a wgpu::Buffer,
    /// The MLP's raw densities of the probes.
    pub raw_density: &'a wgpu::Buffer,
    /// The grid whose opacities are kept.
    pub grid: &'a DeviceGrid,
}

/// The compiled entry points of `occupancy_update.wgsl`.
#[derive(Debug)]
pub struct OccupancyUpdateKernel {
    place: wgpu::ComputePipeline,
    update: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
}

impl OccupancyUpdateKernel {
    /// Compiles the kernel.
    ///
    /// # Errors
    /// If the device rejects it.
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        let ([place, update], layout) = kernels::build_entries(
            ctx,
            "occupancy_update",
            SOURCE,
            &[false, true, false],
            ["place_probes", "update_opacity"],
        )?;
        Ok(Self { place, update, layout })
    }

    /// Records the density probes of `params`' chunk of cells into `bufs.probes`.
    ///
    /// # Errors
    /// A chunk too large for one dispatch.
    pub fn place_probes(
        &self,
        rec: &mut Recorder<'_>,
        params: OccupancyUpdateParams,
        bufs: UpdateBuffers<'_>,
    ) -> Result<(), GpuError> {
        self.dispatch(rec, "occupancy_update place_probes", &self.place, params, bufs)
    }

    /// Records the opacities of `params`' chunk of cells kept from the probes' raw densities in
    /// `bufs.raw_density`.
    ///
    /// # Errors
    /// A chunk too large for one dispatch.
    pub fn update_opacity(
        &self,
        rec: &mut Recorder<'_>,
        params: OccupancyUpdateParams,
        bufs: UpdateBuffers<'_>,
    ) -> Result<(), GpuError> {
        self.dispatch(rec, "occupancy_update update_opacity", &self.update, params, bufs)
    }

    fn dispatch(
        &self,
        rec: &mut Recorder<'_>,
        label: &str,
        pipeline: &wgpu::ComputePipeline,
        mut params: OccupancyUpdateParams,
        bufs: UpdateBuffers<'_>,
    ) -> Result<(), GpuError> {
        let (gx, gy) = kernels::dispatch_grid(u64::from(params.n_cells), kernels::WORKGROUP)?;
        params.groups_x = gx;
        let buffers = [bufs.probes, bufs.raw_density, bufs.grid.opacity()];
        rec.dispatch(label, pipeline, &self.layout, &params, &buffers, (gx, gy, 1));
        Ok(())
    }
}

super::wgsl_struct!(
    OccupancyUpdateParams,
    "Params",
    [
        first_cell,
        n_cells,
        resolution,
        groups_x,
        seed,
        step,
        contracted,
        density_activation,
        bound,
        cell_size,
        decay,
        density_bias,
        raw_stride,
        plane_resolution,
        plane_features,
        plane_levels,
        half_side,
        pre_filtered,
        x_dim,
        net_depth,
        net_width,
        pad0,
        pad1,
        pad2,
    ]
);

/// The buffers the fused update reads.
#[derive(Clone, Copy, Debug)]
pub struct ProbeBuffers<'a> {
    /// The model's parameters (the planes' level 0 first).
    pub params: &'a wgpu::Buffer,
    /// The planes' levels 1.. (built from `params`).
    pub pyramid: &'a wgpu::Buffer,
    /// The fused MLP's table of its layers' offsets in `trunk_weights`.
    pub table: &'a wgpu::Buffer,
    /// The MLP's trunk and heads' weights, copied from `params` (a uniform block).
    pub trunk_weights: &'a wgpu::Buffer,
    /// The grid whose opacities are kept.
    pub grid: &'a DeviceGrid,
}

/// The compiled `occupancy_probe.wgsl`: an update's chunk of cells through the Tri-Mip planes
/// and a fused MLP in one dispatch.
#[derive(Debug)]
pub struct OccupancyProbeKernel {
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
}

impl OccupancyProbeKernel {
    /// Compiles the kernel.
    ///
    /// # Errors
    /// If the device rejects it.
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        let read = kernels::Binding::Storage { read_only: true };
        let bindings = [kernels::Binding::Storage { read_only: false }, read, read, read, kernels::Binding::Uniform];
        let ([pipeline], layout) =
            kernels::build_entries_bound(ctx, "occupancy_probe", PROBE_SOURCE, &bindings, ["probe_opacity"], true)?;
        Ok(Self { pipeline, layout })
    }

    /// Records the opacities of `params`' chunk of cells, kept from their probes' densities
    /// read through the planes and the MLP's trunk (`params` carries the planes' and the
    /// MLP's shape).
    ///
    /// # Errors
    /// A chunk too large for one dispatch.
    pub fn encode(
        &self,
        rec: &mut Recorder<'_>,
        mut params: OccupancyUpdateParams,
        bufs: ProbeBuffers<'_>,
    ) -> Result<(), GpuError> {
        let (gx, gy) = kernels::dispatch_grid(u64::from(params.n_cells), kernels::WORKGROUP)?;
        params.groups_x = gx;
        let buffers = [bufs.grid.opacity(), bufs.params, bufs.pyramid, bufs.table, bufs.trunk_weights];
        rec.dispatch("occupancy_probe", &self.pipeline, &self.layout, &params, &buffers, (gx, gy, 1));
        Ok(())
    }
}
