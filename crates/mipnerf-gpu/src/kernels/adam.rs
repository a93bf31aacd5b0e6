//! `shaders/adam.wgsl`: the Adam update on the device.

use mipnerf_core::train::AdamConfig;

use crate::{GpuContext, GpuError, kernels};

/// The WGSL source of this kernel.
pub const SOURCE: &str = include_str!("../../../../shaders/adam.wgsl");

/// The uniform block of `adam.wgsl` (`struct Params`), 32 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct AdamParams {
    /// Parameters.
    pub count: u32,
    /// Workgroups along x.
    pub groups_x: u32,
    /// Learning rate.
    pub lr: f32,
    /// Adam's beta1.
    pub beta1: f32,
    /// Adam's beta2.
    pub beta2: f32,
    /// Adam's epsilon.
    pub eps: f32,
    /// `1 - beta1^t`.
    pub c1: f32,
    /// `1 - beta2^t`.
    pub c2: f32,
}

/// The compiled Adam pipeline.
#[derive(Debug)]
pub struct AdamKernel {
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
}

impl AdamKernel {
    /// Compiles the kernel.
    ///
    /// # Errors
    /// If the device rejects it.
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        let (pipeline, layout) = crate::kernels::build(ctx, "adam", SOURCE, &[true, false, false, false])?;
        Ok(Self { pipeline, layout })
    }

    /// Records update number `t` (1-based) of `count` parameters with learning rate `lr`.
    ///
    /// # Errors
    /// [`GpuError::InvalidInput`] for too many parameters for one dispatch.
    #[allow(clippy::too_many_arguments)]
    pub fn encode(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        cfg: &AdamConfig,
        t: u64,
        lr: f32,
        count: usize,
        grads: &wgpu::Buffer,
        params: &wgpu::Buffer,
        m: &wgpu::Buffer,
        v: &wgpu::Buffer,
    ) -> Result<(), GpuError> {
        let (gx, gy) = kernels::dispatch_grid(count as u64, 64)?;
        let t = t as i32;
        let p = AdamParams {
            count: count as u32,
            groups_x: gx,
            lr,
            beta1: cfg.beta1,
            beta2: cfg.beta2,
            eps: cfg.eps,
            c1: 1.0 - cfg.beta1.powi(t),
            c2: 1.0 - cfg.beta2.powi(t),
        };
        kernels::dispatch(ctx, enc, "adam", &self.pipeline, &self.layout, &p, &[grads, params, m, v], (gx, gy, 1));
        Ok(())
    }
}
