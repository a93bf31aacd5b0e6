//! `shaders/cast_ipe.wgsl`: rays to frustum Gaussians to IPE features.
//!
//! CPU reference: [`mipnerf_core::stages::cast_and_encode`].

use mipnerf_core::{Ray, stages::CastIpe};

use crate::kernels::Recorder;
use crate::kernels::{WORKGROUP, dispatch_grid};
use crate::{GpuContext, GpuError};

/// The uniform block of `cast_ipe.wgsl` (`struct Params`), 48 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
pub struct CastIpeParams {
    /// Number of rays.
    pub n_rays: u32,
    /// Samples (intervals) per ray; each ray has `n_samples + 1` edges.
    pub n_samples: u32,
    /// First IPE degree (0 in Mip-NeRF).
    pub min_deg: u32,
    /// One past the last IPE degree (16 in Mip-NeRF).
    pub max_deg: u32,
    /// 0 for a cone, 1 for a cylinder.
    pub ray_shape: u32,
    /// Workgroups along x of the 2-D dispatch grid.
    pub groups_x: u32,
    /// 0: IPE; 1: zero covariance (the frustum means' PE through the IPE path, the "w/o IPE"
    /// ablation); 2: NeRF's positional encoding of the means, `[mean | sin | cos]`, plain sines
    /// without the `100 pi` guard (mipnerf-core's `pos_enc` with the identity).
    pub encoding: u32,
    /// 1: an unbounded scene, the Gaussians carried through the scene contraction
    /// ([`mipnerf_core::contract::contract_frustum`]).
    pub unbounded: u32,
    /// 1: the rays buffer holds one Gaussian per sample, (mean, variance on each axis), in the
    /// encoding's space (an occupancy grid's density probes); the edges are not read.
    pub probes: u32,
    /// Padding to 16 bytes.
    pub pad0: u32,
    /// Padding.
    pub pad1: u32,
    /// Padding.
    pub pad2: u32,
}

/// The compiled `cast_ipe.wgsl` pipeline and its bind-group layout.
#[derive(Debug)]
pub struct CastIpeKernel {
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
}

/// The WGSL source of this kernel.
pub const SOURCE: super::Shader = super::shader!("cast_ipe.wgsl", [CastIpeParams]);

impl CastIpeKernel {
    /// Compiles the kernel on `ctx`'s device.
    ///
    /// # Errors
    /// [`GpuError::Wgpu`] if the device rejects the shader or pipeline.
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        let (pipeline, layout) = crate::kernels::build(ctx, "cast_ipe", SOURCE, &[true, true, false])?;
        Ok(Self { pipeline, layout })
    }

    /// Records the kernel over `params.n_rays * params.n_samples` intervals: `rays` holds two vec4
    /// per ray ((origin, radius), (direction, anything)), `t_vals` the edges, `out` the features.
    ///
    /// # Errors
    /// [`GpuError::InvalidInput`] for a grid too large for one dispatch.
    pub fn encode(
        &self,
        rec: &mut Recorder<'_>,
        mut params: CastIpeParams,
        rays: &wgpu::Buffer,
        t_vals: &wgpu::Buffer,
        out: &wgpu::Buffer,
    ) -> Result<(), GpuError> {
        let (gx, gy) = dispatch_grid(u64::from(params.n_rays) * u64::from(params.n_samples), WORKGROUP)?;
        params.groups_x = gx;
        rec.dispatch("cast_ipe", &self.pipeline, &self.layout, &params, &[rays, t_vals, out], (gx, gy, 1));
        Ok(())
    }

    /// Casts every ray's intervals (`t_vals`: `stage.n_samples + 1` edges per ray, row-major)
    /// and encodes them as `stage` says, as [`mipnerf_core::stages::cast_and_encode`] does with
    /// the same `stage`; returns `rays.len() * n_samples` rows of the encoding's width, sample
    /// after sample.
    ///
    /// The output buffer is filled with NaN before the kernel runs, so a feature the kernel failed
    /// to write shows up as NaN.
    ///
    /// # Errors
    /// [`GpuError::InvalidInput`] for inconsistent sizes, or any error wgpu reports.
    pub fn run(&self, ctx: &GpuContext, rays: &[Ray], t_vals: &[f32], stage: CastIpe) -> Result<Vec<f32>, GpuError> {
        let CastIpe { n_samples, shape, unbounded, encoding, min_deg, max_deg } = stage;
        let n_samples = u32::try_from(n_samples)
            .map_err(|_| GpuError::InvalidInput(format!("cast_ipe: {n_samples} samples per ray")))?;
        if n_samples == 0 || t_vals.len() != rays.len() * (n_samples as usize + 1) {
            return Err(GpuError::InvalidInput(format!(
                "cast_ipe: {} t values for {} rays of {n_samples} samples",
                t_vals.len(),
                rays.len()
            )));
        }
        if max_deg <= min_deg || max_deg > 24 {
            return Err(GpuError::InvalidInput(format!("cast_ipe: degrees {min_deg}..{max_deg}")));
        }
        let n_items = rays.len() as u64 * u64::from(n_samples);
        let (gx, gy) = dispatch_grid(n_items, WORKGROUP)?;
        let params = CastIpeParams {
            n_rays: rays.len() as u32,
            n_samples,
            min_deg,
            max_deg,
            ray_shape: shape as u32,
            groups_x: gx,
            encoding: encoding as u32,
            unbounded: u32::from(unbounded),
            ..CastIpeParams::default()
        };
        let packed = super::packed_rays(rays);
        let out_len = n_items as usize * encoding.width(min_deg, max_deg);
        let ray_buf = ctx.storage_buffer("cast_ipe rays", &packed, false);
        let t_buf = ctx.storage_buffer("cast_ipe t_vals", t_vals, false);
        let out_buf = ctx.storage_buffer("cast_ipe encoded", &vec![f32::NAN; out_len], true);
        let mut rec = Recorder::new(ctx, "cast_ipe");
        rec.dispatch("cast_ipe", &self.pipeline, &self.layout, &params, &[&ray_buf, &t_buf, &out_buf], (gx, gy, 1));
        let _ = rec.submit();
        ctx.read_f32(&out_buf, out_len)
    }
}

super::wgsl_struct!(
    CastIpeParams,
    "Params",
    [n_rays, n_samples, min_deg, max_deg, ray_shape, groups_x, encoding, unbounded, probes, pad0, pad1, pad2]
);
