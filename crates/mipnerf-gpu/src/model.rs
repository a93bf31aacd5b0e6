//! The whole Mip-NeRF loss and gradient of a batch on the device: the same computation as
//! `mipnerf_core::model::Model::loss_and_grad`, composed from this crate's kernels, with every
//! intermediate kept on the device and one read-back at the end.
//!
//! Per level: edges (`sample.wgsl`: stratified, or resampled from the previous level's weights),
//! Gaussians and IPE (`cast_ipe.wgsl`), the MLP forward pass, rendering with the loss gradient
//! (`render.wgsl`), and the MLP backward pass into the gradient buffer. Random numbers are the
//! CPU's, so a training-mode batch gives the CPU's result to rounding.

use mipnerf_core::Ray;
use mipnerf_core::mip::RayShape;
use mipnerf_core::model::{LossStats, Mode, Model, PointEncoding};

use crate::kernels::cast_ipe::{CastIpeKernel, CastIpeParams};
use crate::kernels::render::{RenderBuffers, RenderKernel, RenderParams};
use crate::kernels::sample::{SampleKernels, SampleParams};
use crate::kernels::view_enc::ViewEncKernel;
use crate::mlp::{GpuMlp, MlpBuffers};
use crate::{GpuContext, GpuError};

/// The kernels of a model step.
#[derive(Debug)]
pub struct GpuModel {
    sample: SampleKernels,
    cast: CastIpeKernel,
    view: ViewEncKernel,
    mlp: GpuMlp,
    render: RenderKernel,
}

impl GpuModel {
    /// Compiles every kernel.
    ///
    /// # Errors
    /// If the device rejects one.
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        Ok(Self {
            sample: SampleKernels::new(ctx)?,
            cast: CastIpeKernel::new(ctx)?,
            view: ViewEncKernel::new(ctx)?,
            mlp: GpuMlp::new(ctx)?,
            render: RenderKernel::new(ctx)?,
        })
    }

    /// The loss of a batch and the gradient of every parameter, computed on the device from
    /// `params` (uploaded) for `rays` (one per pixel) and `targets`.
    ///
    /// # Errors
    /// [`GpuError::InvalidInput`] for what the GPU path does not do yet (NeRF's positional
    /// encoding, density noise, supersampling, separate MLPs per level) or inconsistent sizes;
    /// any error wgpu reports.
    pub fn loss_and_grad(
        &self,
        ctx: &GpuContext,
        model: &Model,
        params: &[f32],
        rays: &[Ray],
        targets: &[[f32; 3]],
        mode: Mode,
    ) -> Result<(LossStats, Vec<f32>), GpuError> {
        let c = &model.config;
        let unsupported =
            |what: &str| Err(GpuError::InvalidInput(format!("the GPU model does not support {what} yet")));
        if c.point_encoding == PointEncoding::Nerf {
            return unsupported("NeRF's positional encoding");
        }
        if c.supersample != 1 {
            return unsupported("supersampling");
        }
        if c.separate_mlps {
            return unsupported("one MLP per level");
        }
        if matches!(mode, Mode::Train { .. }) && c.density_noise > 0.0 {
            return unsupported("density noise");
        }
        if rays.len() != targets.len() || rays.is_empty() || params.len() != model.num_params {
            return Err(GpuError::InvalidInput(format!(
                "{} rays, {} targets, {} parameters",
                rays.len(),
                targets.len(),
                params.len()
            )));
        }
        let (nr, s) = (rays.len(), c.num_samples);
        let n = nr * s;
        let shape = &model.mlps[0];
        let (seed, step, randomized) = match mode {
            Mode::Train { seed, step } => (seed, step, true),
            Mode::Eval => (0, 0, false),
        };
        // Inputs.
        let packed: Vec<[f32; 4]> = rays
            .iter()
            .flat_map(|r| [r.origin.extend(r.radius).to_array(), r.direction.extend(r.lossmult).to_array()])
            .collect();
        let rays_buf = ctx.storage_buffer("batch rays", &packed, false);
        let bounds: Vec<f32> = rays.iter().flat_map(|r| [r.near, r.far]).collect();
        let bounds_buf = ctx.storage_buffer("batch bounds", &bounds, false);
        let viewdirs: Vec<f32> = rays.iter().flat_map(|r| r.viewdir.to_array()).collect();
        let viewdirs_buf = ctx.storage_buffer("batch view directions", &viewdirs, false);
        let tg: Vec<[f32; 4]> = targets.iter().map(|t| [t[0], t[1], t[2], 0.0]).collect();
        let targets_buf = ctx.storage_buffer("batch targets", &tg, false);
        let params_buf = ctx.storage_buffer("parameters", params, false);
        let grads = ctx.storage_buffer("gradients", &vec![0.0f32; model.num_params], true);
        // Intermediates.
        let bufs = MlpBuffers::new(ctx, shape, nr, s);
        let nan = |label: &str, len: usize| ctx.storage_buffer(label, &vec![f32::NAN; len], true);
        let t_bufs: Vec<wgpu::Buffer> =
            (0..c.num_levels).map(|l| nan(&format!("edges level {l}"), nr * (s + 1))).collect();
        let ray_out: Vec<wgpu::Buffer> =
            (0..c.num_levels).map(|l| nan(&format!("ray outputs level {l}"), nr * 8)).collect();
        let (weights, d_rgb, d_den) = (nan("weights", n), nan("d raw rgb", n * 3), nan("d raw density", n));
        let lossmult = |r: &Ray| if c.area_loss { r.lossmult } else { 1.0 };
        let norm = 3.0 * rays.iter().map(|r| f64::from(lossmult(r))).sum::<f64>() as f32;
        let level_w = model.level_weights();
        let mut enc = ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("model step") });
        self.view.encode(ctx, &mut enc, nr, c.deg_view, &viewdirs_buf, &bufs.view)?;
        for level in 0..c.num_levels {
            let sp = SampleParams {
                n_rays: nr as u32,
                n_samples: s as u32,
                lindisp: u32::from(c.lindisp),
                randomized: u32::from(randomized),
                seed,
                step,
                first_ray: 0,
                level: level as u32,
                resample_padding: c.resample_padding,
                ..SampleParams::default()
            };
            if level == 0 {
                self.sample.stratified(ctx, &mut enc, sp, &bounds_buf, &t_bufs[0])?;
            } else {
                self.sample.resample(ctx, &mut enc, sp, &t_bufs[level - 1], &weights, &t_bufs[level])?;
            }
            let cp = CastIpeParams {
                n_rays: nr as u32,
                n_samples: s as u32,
                min_deg: c.min_deg_point,
                max_deg: c.max_deg_point,
                ray_shape: u32::from(c.ray_shape == RayShape::Cylinder),
                groups_x: 0,
                zero_cov: u32::from(c.point_encoding == PointEncoding::Mean),
                _pad: 0,
            };
            self.cast.encode(ctx, &mut enc, cp, &rays_buf, &t_bufs[level], &bufs.x)?;
            self.mlp.forward(ctx, &mut enc, shape, &params_buf, &bufs);
            let rb = RenderBuffers {
                raw_rgb: &bufs.raw_rgb,
                raw_density: &bufs.raw_density,
                t_vals: &t_bufs[level],
                rays: &rays_buf,
                targets: &targets_buf,
                weights: &weights,
                d_raw_rgb: &d_rgb,
                d_raw_density: &d_den,
                ray_out: &ray_out[level],
            };
            self.render.encode(ctx, &mut enc, RenderParams::new(c, nr, level_w[level], norm, true), &rb)?;
            self.mlp.backward(ctx, &mut enc, shape, &params_buf, &bufs, &d_rgb, &d_den, &grads);
        }
        ctx.queue.submit([enc.finish()]);
        let g = ctx.read_f32(&grads, model.num_params)?;
        let mut losses = Vec::new();
        let mut mse = Vec::new();
        for out in &ray_out {
            let v = ctx.read_f32(out, nr * 8)?;
            let (lm_se, se): (f64, f64) =
                v.chunks(8).fold((0.0, 0.0), |acc, o| (acc.0 + f64::from(o[5]), acc.1 + f64::from(o[6])));
            losses.push((lm_se / f64::from(norm)) as f32);
            mse.push((se / (3.0 * nr as f64)) as f32);
        }
        let loss = level_w.iter().zip(&losses).map(|(w, l)| w * l).sum();
        Ok((LossStats { losses, loss, mse }, g))
    }
}
