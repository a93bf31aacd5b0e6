//! `shaders/view_enc.wgsl`: the positional encoding of view directions.
//!
//! CPU reference: [`mipnerf_core::stages::encode_view_directions`].

use crate::kernels::Recorder;
use crate::{GpuContext, GpuError, kernels};

/// The WGSL source of this kernel.
pub const SOURCE: super::Shader = super::shader!("view_enc.wgsl", [ViewEncParams], includes["view_encoding.wgsl"]);

/// The uniform block of `view_enc.wgsl` (`struct Params`), 16 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct ViewEncParams {
    /// Rays.
    pub n_rays: u32,
    /// Degrees `0..deg_view`.
    pub deg_view: u32,
    /// Workgroups along x.
    pub groups_x: u32,
    /// Padding.
    pub _pad: u32,
}

/// The compiled view-encoding pipeline.
#[derive(Debug)]
pub struct ViewEncKernel {
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
}

impl ViewEncKernel {
    /// Compiles the kernel.
    ///
    /// # Errors
    /// If the device rejects it.
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        let (pipeline, layout) = crate::kernels::build(ctx, "view_enc", SOURCE, &[true, false])?;
        Ok(Self { pipeline, layout })
    }

    /// Records the encoding of `n_rays` view directions (3 floats each) into `out`
    /// (`3 + 6 deg_view` floats per ray).
    ///
    /// # Errors
    /// [`GpuError::InvalidInput`] for too many rays for one dispatch or `deg_view > 16`.
    pub fn encode(
        &self,
        rec: &mut Recorder<'_>,
        n_rays: usize,
        deg_view: u32,
        viewdirs: &wgpu::Buffer,
        out: &wgpu::Buffer,
    ) -> Result<(), GpuError> {
        if deg_view > 16 {
            return Err(GpuError::InvalidInput(format!("view_enc: {deg_view} degrees (at most 16)")));
        }
        let (gx, gy) = kernels::dispatch_grid(n_rays as u64, kernels::WORKGROUP)?;
        let p = ViewEncParams { n_rays: n_rays as u32, deg_view, groups_x: gx, _pad: 0 };
        rec.dispatch("view_enc", &self.pipeline, &self.layout, &p, &[viewdirs, out], (gx, gy, 1));
        Ok(())
    }
}

super::wgsl_struct!(ViewEncParams, "Params", [n_rays, deg_view, groups_x, _pad]);
