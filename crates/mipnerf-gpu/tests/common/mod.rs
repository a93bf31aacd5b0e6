//! What the kernel tests share: the imports, the tolerances of the IPE's sines, the demo's
//! rays and the modes. Each kernel test (`kernel_*.rs`, one file a stage) runs its kernel on a
//! real adapter (lavapipe in CI) and compares it with its CPU reference in
//! `mipnerf_core::stages` through one check, `mipnerf_core::compare::check_kernel`.
#![allow(dead_code, unused_imports)]

pub use glam::Vec3;
pub use mipnerf_core::bf16::Precision;
pub use mipnerf_core::compare::{Outputs, Tolerance, assert_none, check_kernel, check_kernel_conditioned, mismatches};
pub use mipnerf_core::contract::UNBOUNDED_FAR;
pub use mipnerf_core::demo;
pub use mipnerf_core::mip::{self, ipe_len};
pub use mipnerf_core::model::{GradWith, TrainBatch};
pub use mipnerf_core::model::{Mode, PointEncoding};
pub use mipnerf_core::sampling::Spacing;
pub use mipnerf_core::{PixelCenters, Ray, RayShape, stages};
pub use mipnerf_gpu::GpuError;
pub use mipnerf_gpu::kernels::Recorder;
pub use mipnerf_gpu::kernels::cast_ipe::CastIpeKernel;
pub use mipnerf_gpu::test_support::{
    HARDWARE_ROUNDING_REL, context_or_skip, contexts_of_each_atomics, hardware_perturbations,
};

/// How far past the CPU reference's own spread under perturbed inputs a hardware GPU may land
/// (`check_kernel_conditioned`): twice it, the perturbations being a sample.
pub const SPREAD_FACTOR: f32 = 2.0;

/// GPU vs CPU, IPE features. Both sides compute the frustum moments in f32 in the same order; the
/// difference comes from the GPU's `sin`/`exp` and fused multiply-adds. Features are bounded by 1,
/// so an absolute tolerance is the meaningful one. lavapipe measures < 5e-6.
pub const TOL_GPU_IPE_ABS: f32 = 2e-5;

/// WGSL's bound on the absolute error of `sin` on [-pi, pi] (the spec's accuracy table), which a
/// hardware driver may use (real GPUs do far better: NVIDIA's approximate sine is within 2^-20.9
/// there). The kernels reduce every argument to [-pi, pi] first, without relying on fused
/// multiply-adds, so this is the whole of a vendor's latitude on a sine feature.
pub const WGSL_SIN_ABS: f32 = 1.0 / 2048.0;

/// The tolerance of a feature computed with one `sin` on `ctx`: what lavapipe measures plus, on
/// a hardware adapter, the spec's bound.
pub fn sin_feature_tolerance(ctx: &mipnerf_gpu::GpuContext) -> f32 {
    if ctx.adapter().is_software { TOL_GPU_IPE_ABS } else { TOL_GPU_IPE_ABS + WGSL_SIN_ABS }
}

/// The rays of the demo's oblique camera at `n_side` x `n_side` pixels, bounds 2 to 6.
pub fn test_rays(n_side: u32) -> Vec<Ray> {
    demo::oblique_camera(n_side).generate_rays(PixelCenters::Centered, 2.0, 6.0, 1.0)
}

/// A mode that draws random numbers (training, `seed` and `step`) when `randomized`, else
/// evaluation.
pub fn mode_of(randomized: bool, seed: u32, step: u32) -> Mode {
    if randomized { Mode::Train { seed, step } } else { Mode::Eval }
}

/// GPU vs CPU interval edges: the same f32 operations; WGSL bounds division to 2.5 ulp (the only
/// operation here that is not correctly rounded), on every vendor.
pub const TOL_GPU_SAMPLE_REL: f32 = 2e-6;
/// GPU vs CPU edges of an unbounded scene, compared in the normalised distance `s` they are
/// drawn in (`contract::ray_distance_to_s`), absolutely: `s` lies in `[0, 1)`, and an ulp of `s`
/// near 1 (6e-8) is a relative change of `t` as large as `t · 1.2e-7` (6% at `t = 1e6`), so `t`
/// itself is the wrong scale. The mapping's division (2.5 ulp in WGSL) and the stratification's
/// own rounding stay within a few ulp of 1.
pub const TOL_GPU_SAMPLE_S_ABS: f32 = 1e-6;
/// GPU vs CPU, the whole model step: the IPE differs by ~1e-6 between the two, and that flows
/// through the MLP, rendering and every gradient. On a hardware adapter this assumes `sin` within
/// about 2^-20 on [-pi, pi], which NVIDIA, AMD, Intel and Apple drivers deliver; a driver using
/// WGSL's full 2^-11 latitude passes the IPE test (which allows it) and fails this one, as it
/// should: its training would not follow the CPU's.
pub const TOL_GPU_MODEL_REL: f32 = 2e-3;
pub const TOL_GPU_MODEL_ABS: f32 = 2e-6;
/// The tolerance of a whole model's outputs: losses and MSE as they are, gradients relative to
/// their overall scale (`grad_scale`, the CPU's largest).
pub fn model_tolerance(grad_scale: f32) -> impl Fn(&str) -> Tolerance {
    move |name| match name {
        "grads" => Tolerance::new(TOL_GPU_MODEL_REL * grad_scale, TOL_GPU_MODEL_REL),
        _ => Tolerance::new(TOL_GPU_MODEL_ABS, TOL_GPU_MODEL_REL),
    }
}
