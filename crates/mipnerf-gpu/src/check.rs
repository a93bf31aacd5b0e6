//! The device against the CPU reference on synthetic data, as `mipnerf check` runs it: the IPE
//! kernel on the rays of an oblique camera, and one whole model step (the loss and every
//! gradient). Each returns the [`KernelCheck`] that says how far apart the two are.

use mipnerf_core::bf16::Precision;
use mipnerf_core::compare::{KernelCheck, Tolerance, check_kernel};
use mipnerf_core::model::{GradWith, TrainBatch};
use mipnerf_core::model::{Mode, Model, ModelConfig, PointEncoding, Preset};
use mipnerf_core::sampling::Spacing;
use mipnerf_core::{Ray, RayShape, stages};

use crate::kernels::cast_ipe::CastIpeKernel;
use crate::model::GpuModel;
use crate::{GpuContext, GpuError};

/// IPE features: device against CPU, absolute (features are bounded by 1; lavapipe measures
/// under 5e-6).
pub const TOL_IPE_ABS: f32 = 1e-4;
/// Loss of one model step: device against CPU, relative (the kernels' tests measure about 1e-5).
pub const TOL_STEP_LOSS_REL: f32 = 2e-3;
/// Gradients of one model step: device against CPU, relative to the largest gradient.
pub const TOL_STEP_GRAD_REL: f32 = 2e-3;

/// Samples per ray of both checks.
const SAMPLES: usize = 32;

/// The cast-and-IPE kernel (`cast_ipe.wgsl`) against [`stages::cast_and_encode`] on `rays`, 32
/// samples each from near to far, degrees 0 to 16.
///
/// # Errors
/// The kernel's device errors.
pub fn cast_ipe(ctx: &GpuContext, rays: &[Ray]) -> Result<KernelCheck, GpuError> {
    let n = SAMPLES;
    let ids: Vec<u32> = (0..rays.len() as u32).collect();
    let mut t = vec![0.0; rays.len() * (n + 1)];
    stages::sample_intervals(
        rays,
        stages::Sample { n_samples: n, spacing: Spacing::Depth, mode: Mode::Eval },
        &ids,
        &mut t,
    );
    let kernel = CastIpeKernel::new(ctx)?;
    let degrees = (0, 16);
    let stage = stages::CastIpe {
        n_samples: n,
        shape: RayShape::Cone,
        unbounded: false,
        encoding: PointEncoding::Integrated,
        min_deg: degrees.0,
        max_deg: degrees.1,
    };
    Ok(check_kernel(
        "cast_ipe",
        |(rays, t): &(&[Ray], &[f32])| {
            let mut x = vec![0.0; rays.len() * n * mipnerf_core::mip::ipe_len(degrees.0, degrees.1)];
            stages::cast_and_encode(rays, t, stage, Precision::F32, &mut x);
            vec![("features", x)]
        },
        |(rays, t)| kernel.run(ctx, rays, t, stage).map(|x| vec![("features", x)]),
        &(rays, &t[..]),
        |_| Tolerance::abs(TOL_IPE_ABS),
    ))
}

/// What [`model_step`] compared.
#[derive(Debug)]
pub struct ModelStepCheck {
    /// The loss and the gradients, device against CPU.
    pub check: KernelCheck,
    /// Parameters of the tiny model checked.
    pub num_params: usize,
    /// The CPU's loss.
    pub cpu_loss: f32,
}

/// One training-mode step of the tiny preset (16 samples per level) on `rays`: the device's
/// loss and gradients against [`Model::loss_and_grad`].
///
/// # Errors
/// A model that cannot be built, or the device's errors.
pub fn model_step(ctx: &GpuContext, rays: &[Ray]) -> Result<ModelStepCheck, GpuError> {
    let model = Model::new(ModelConfig { num_samples: 16, ..Preset::Tiny.config() })
        .map_err(|e| GpuError::InvalidInput(e.to_string()))?;
    let params = model.init_params(1);
    let targets: Vec<[f32; 3]> = (0..rays.len()).map(|i| [(i % 5) as f32 / 5.0, 0.5, (i % 3) as f32 / 3.0]).collect();
    let mode = Mode::Train { seed: 1, step: 0 };
    let mut grads = vec![0.0; model.num_params()];
    let cpu =
        model.loss_and_grad(&params, TrainBatch { rays, targets: &targets }, mode, &mut grads, GradWith::default());
    let scale = grads.iter().fold(0.0f32, |m, x| m.max(x.abs())).max(1e-20);
    let gpu = GpuModel::new(ctx)?;
    let check = check_kernel(
        "model step (loss; gradients, absolute, against the largest)",
        |_: &()| vec![("loss", vec![cpu.loss]), ("gradients", grads.clone())],
        |_| {
            let (stats, g) =
                gpu.loss_and_grad(ctx, &model, &params, TrainBatch { rays, targets: &targets }, mode, None)?;
            Ok::<_, GpuError>(vec![("loss", vec![stats.loss]), ("gradients", g)])
        },
        &(),
        |name| {
            if name == "loss" { Tolerance::rel(TOL_STEP_LOSS_REL) } else { Tolerance::abs(TOL_STEP_GRAD_REL * scale) }
        },
    );
    Ok(ModelStepCheck { check, num_params: model.num_params(), cpu_loss: cpu.loss })
}
