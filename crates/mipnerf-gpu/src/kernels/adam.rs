//! `shaders/adam.wgsl`: gradient clipping and the Adam update on the device.
//!
//! CPU reference: [`mipnerf_core::stages::adam_step`].

use mipnerf_core::optim::FieldAdam;
use mipnerf_core::stages::AdamStep;

use crate::kernels::Recorder;
use crate::{GpuContext, GpuError, kernels};

/// The WGSL source of this kernel.
pub const SOURCE: super::Shader = super::shader!("adam.wgsl", [AdamParams]);

/// Gradients per workgroup of the norm's first pass.
const NORM_GROUP: u64 = kernels::REDUCE_WORKGROUP as u64;

/// The uniform block of `adam.wgsl` (`struct Params`), 64 bytes.
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
    /// `1 - beta1^t`, computed on the host in f32 as the CPU does.
    pub c1: f32,
    /// `1 - beta2^t`, likewise.
    pub c2: f32,
    /// Clip each gradient entry to `±max_val` (0: off).
    pub max_val: f32,
    /// Scale the gradient to this norm if larger (0: off).
    pub max_norm: f32,
    /// Workgroups of the norm's first pass, `grad_sq_partial` (entries of `partials`).
    pub n_partials: u32,
    /// The parameters before this index are the field's own (the Tri-Mip planes), updated with
    /// `field_lr` and `field_eps` (0: none).
    pub split: u32,
    /// The field's learning rate.
    pub field_lr: f32,
    /// The field's epsilon.
    pub field_eps: f32,
    /// 1: the field's entries whose gradient is 0 are left as they are, moments included
    /// ([`FieldAdam::skip_untouched`]); 0: updated.
    pub field_skip_untouched: u32,
    /// `l2 · p` added to the gradient of the parameters from `split` on (the MLP's;
    /// [`AdamConfig::l2`](mipnerf_core::optim::AdamConfig::l2)); 0: off.
    pub mlp_l2: f32,
}

/// The buffers of an update of `count` parameters.
#[derive(Debug)]
pub struct AdamBuffers {
    /// Parameters.
    pub count: usize,
    /// Gradients (read).
    pub grads: wgpu::Buffer,
    /// Parameters (updated).
    pub params: wgpu::Buffer,
    /// First moments (updated).
    pub m: wgpu::Buffer,
    /// Second moments (updated).
    pub v: wgpu::Buffer,
    /// Per-workgroup sums of squares (scratch).
    pub partials: wgpu::Buffer,
    /// `[norm after value clipping, clipping factor]`, written when clipping by norm.
    pub stats: wgpu::Buffer,
}

impl AdamBuffers {
    /// Buffers holding `params`, `m`, `v` and zero gradients.
    ///
    /// # Panics
    /// If the lengths differ.
    #[must_use]
    pub fn new(ctx: &GpuContext, params: &[f32], m: &[f32], v: &[f32]) -> Self {
        let n = params.len();
        assert!(m.len() == n && v.len() == n, "adam buffers: lengths");
        let partials = n.div_ceil(NORM_GROUP as usize).max(1);
        Self {
            count: n,
            grads: ctx.storage_buffer("gradients", &vec![0.0f32; n], true),
            params: ctx.storage_buffer("parameters", params, true),
            m: ctx.storage_buffer("adam first moments", m, true),
            v: ctx.storage_buffer("adam second moments", v, true),
            partials: ctx.storage_buffer("gradient norm partial sums", &vec![0.0f32; partials], false),
            stats: ctx.storage_buffer("gradient norm", &[f32::NAN; 2], true),
        }
    }
}

/// The compiled pipelines of `adam.wgsl`.
#[derive(Debug)]
pub struct AdamKernel {
    update: wgpu::ComputePipeline,
    sq_partial: wgpu::ComputePipeline,
    norm_finish: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
}

impl AdamKernel {
    /// Compiles the kernels.
    ///
    /// # Errors
    /// If the device rejects them.
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        let read_only = [true, false, false, false, false, false];
        let ([update, sq_partial, norm_finish], layout) =
            kernels::build_entries(ctx, "adam", SOURCE, &read_only, ["main", "grad_sq_partial", "grad_norm_finish"])?;
        Ok(Self { update, sq_partial, norm_finish, layout })
    }

    /// Records the clipping (when on) and update `step` of every parameter in `b`, Adam's
    /// update number `t` (1-based; the CPU's `AdamState::t` after the update).
    ///
    /// # Errors
    /// [`GpuError::InvalidInput`] for too many parameters for one dispatch.
    pub fn encode(&self, rec: &mut Recorder<'_>, step: &AdamStep, t: u64, b: &AdamBuffers) -> Result<(), GpuError> {
        let t = t as i32;
        let cfg = &step.cfg;
        let (split, field) = step.split.unwrap_or((0, FieldAdam::mlp(cfg)));
        if split > b.count {
            return Err(GpuError::InvalidInput(format!("adam: {split} field parameters of {}", b.count)));
        }
        let mut p = AdamParams {
            count: b.count as u32,
            groups_x: 0,
            lr: step.lr,
            beta1: cfg.beta1,
            beta2: cfg.beta2,
            eps: cfg.eps,
            c1: 1.0 - cfg.beta1.powi(t),
            c2: 1.0 - cfg.beta2.powi(t),
            max_val: step.max_val,
            max_norm: step.max_norm,
            n_partials: b.count.div_ceil(NORM_GROUP as usize) as u32,
            split: split as u32,
            field_lr: step.lr * field.lr_mult,
            field_eps: field.eps,
            field_skip_untouched: u32::from(field.skip_untouched),
            mlp_l2: step.cfg.l2,
        };
        let bufs = [&b.grads, &b.params, &b.m, &b.v, &b.partials, &b.stats];
        if step.max_norm > 0.0 {
            let (gx, gy) = kernels::dispatch_grid(b.count as u64, NORM_GROUP as u32)?;
            p.groups_x = gx;
            rec.dispatch("adam norm", &self.sq_partial, &self.layout, &p, &bufs, (gx, gy, 1));
            rec.dispatch("adam norm finish", &self.norm_finish, &self.layout, &p, &bufs, (1, 1, 1));
        }
        let (gx, gy) = kernels::dispatch_grid(b.count as u64, kernels::WORKGROUP)?;
        p.groups_x = gx;
        rec.dispatch("adam", &self.update, &self.layout, &p, &bufs, (gx, gy, 1));
        Ok(())
    }
}

super::wgsl_struct!(
    AdamParams,
    "Params",
    [
        count,
        groups_x,
        lr,
        beta1,
        beta2,
        eps,
        c1,
        c2,
        max_val,
        max_norm,
        n_partials,
        split,
        field_lr,
        field_eps,
        field_skip_untouched,
        mlp_l2
    ]
);
