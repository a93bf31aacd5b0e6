//! `mipnerf check`: the GPU against the CPU reference on synthetic data, in three stages: the
//! IPE kernel, one whole model step (losses and every gradient), and a few training steps of both
//! backends from one seed (device-drawn batches, Adam, loss read-back).

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{Context, Result};
use clap::ValueEnum;
use mipnerf_core::backend::{Backend as _, CpuBackend, TrainState};
use mipnerf_core::data::{Dataset, Pixels, Split, View, demo};
use mipnerf_core::model::{Mode, Model, ModelConfig, Preset};
use mipnerf_core::train::OptimConfig;
use mipnerf_core::{Camera, Ray};
use mipnerf_gpu::{GpuBackend, GpuContext};

/// Loss of one model step: GPU vs CPU, relative (the kernels' tests measure about 1e-5).
const TOL_STEP_LOSS_REL: f32 = 2e-3;
/// Gradients of one model step: GPU vs CPU, relative to the largest gradient.
const TOL_STEP_GRAD_REL: f32 = 2e-3;
/// Losses of the training steps: GPU vs CPU, relative (the test suite measures 4e-6 on lavapipe).
const TOL_TRAIN_LOSS_REL: f32 = 1e-3;

/// `--backend` of `mipnerf check`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum CheckBackend {
    /// Nothing to check: the CPU is the reference.
    Cpu,
    /// Any GPU adapter, software ones included.
    Gpu,
    /// A hardware GPU only.
    Auto,
}

/// Runs the three stages on the adapter `backend` selects and prints each one's agreement.
///
/// # Errors
/// No adapter (for `gpu`), or a stage whose GPU result is outside its tolerance.
pub fn check(backend: CheckBackend, device: &mipnerf_gpu::DeviceOptions) -> Result<()> {
    use mipnerf_core::{RayShape, cone};
    let choice = match backend {
        CheckBackend::Cpu => {
            println!("the CPU backend is the reference; nothing to compare it with");
            return Ok(());
        }
        CheckBackend::Gpu => device.adapter.clone().unwrap_or(mipnerf_gpu::AdapterChoice::Any),
        CheckBackend::Auto => device.adapter.clone().unwrap_or(mipnerf_gpu::AdapterChoice::HardwareOnly),
    };
    let ctx = match mipnerf_gpu::GpuContext::new(choice) {
        Ok(c) => c,
        Err(e) if backend == CheckBackend::Auto => {
            println!("auto: {e}; the CPU backend would be used");
            return Ok(());
        }
        Err(e) => return Err(e).context("opening the GPU"),
    };
    println!("checking on {} ({}, {})", ctx.adapter().name, ctx.adapter().backend, ctx.adapter().device_type);
    let c2w = [[0.8, 0.0, 0.6, 2.4], [0.36, 0.8, -0.48, -1.92], [-0.48, 0.6, 0.64, 2.56]];
    let cam = mipnerf_core::Camera::from_camera_angle_x(32, 32, 0.69, c2w)?;
    let rays = cam.generate_rays(mipnerf_core::PixelCenters::Centered, 2.0, 6.0, 1.0);
    let n = 32usize;
    let mut t = vec![0.0; rays.len() * (n + 1)];
    for (r, chunk) in t.chunks_mut(n + 1).enumerate() {
        mipnerf_core::sample_along_rays(rays[r].near, rays[r].far, false, None, chunk);
    }
    let kernel = mipnerf_gpu::kernels::cast_ipe::CastIpeKernel::new(&ctx)?;
    let gpu = kernel.run(&ctx, &rays, &t, n as u32, RayShape::Cone, 0, 16)?;
    let cpu = cone::cast_and_encode(&rays, &t, n, RayShape::Cone, 0, 16);
    let max = gpu
        .iter()
        .zip(&cpu)
        .map(|(a, b)| if a.is_nan() { f32::INFINITY } else { (a - b).abs() })
        .fold(0.0f32, f32::max);
    println!("cast_ipe: {} features, max |gpu - cpu| = {max:e}", gpu.len());
    anyhow::ensure!(max <= 1e-4, "the GPU's IPE features differ from the CPU reference by {max:e} (> 1e-4)");
    model_step(&ctx, &rays)?;
    training(ctx)?;
    println!("ok");
    Ok(())
}

fn model_step(ctx: &GpuContext, rays: &[Ray]) -> Result<()> {
    let model = Model::new(ModelConfig { num_samples: 16, ..Preset::Tiny.config() })?;
    let params = model.init_params(1);
    let targets: Vec<[f32; 3]> = (0..rays.len()).map(|i| [(i % 5) as f32 / 5.0, 0.5, (i % 3) as f32 / 3.0]).collect();
    let mode = Mode::Train { seed: 1, step: 0 };
    let mut grads = vec![0.0; model.num_params()];
    let cpu = model.loss_and_grad(&params, rays, &targets, mode, &mut grads);
    let gpu = mipnerf_gpu::model::GpuModel::new(ctx)?;
    let (stats, g) = gpu.loss_and_grad(ctx, &model, &params, rays, &targets, mode)?;
    let loss_rel = (stats.loss - cpu.loss).abs() / cpu.loss.abs().max(1e-12);
    let scale = grads.iter().fold(0.0f32, |m, x| m.max(x.abs())).max(1e-20);
    let grad_rel = g
        .iter()
        .zip(&grads)
        .map(|(a, b)| if a.is_nan() { f32::INFINITY } else { (a - b).abs() / scale })
        .fold(0.0f32, f32::max);
    println!(
        "model step ({} rays, tiny preset, {} parameters): loss cpu {:.6} gpu {:.6} (relative {loss_rel:.1e}); \
         max gradient difference {grad_rel:.1e} of the largest gradient",
        rays.len(),
        model.num_params(),
        cpu.loss,
        stats.loss
    );
    anyhow::ensure!(loss_rel <= TOL_STEP_LOSS_REL, "the GPU's loss differs from the CPU's by {loss_rel:e} relative");
    anyhow::ensure!(grad_rel <= TOL_STEP_GRAD_REL, "the GPU's gradients differ from the CPU's by {grad_rel:e}");
    Ok(())
}

/// Eight 32x32 views of the demo scene, in memory.
fn demo_views() -> Result<Dataset> {
    let views = demo::view_poses(8, 0.0)
        .into_iter()
        .enumerate()
        .map(|(i, pose)| {
            let camera = Camera::from_camera_angle_x(32, 32, 0.69, pose)?;
            let pixels = Pixels::RgbaF32(demo::render_view(&camera, 1));
            Ok(View {
                file: PathBuf::from(format!("demo_{i}")),
                camera,
                pixels,
                near: 2.0,
                far: 6.0,
                lossmult: 1.0,
                scale: 0,
            })
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(Dataset::new(&PathBuf::from("demo scene (in memory)"), Split::Train, views, true)?)
}

fn training(ctx: GpuContext) -> Result<()> {
    let ds = Arc::new(demo_views()?);
    let model = Model::new(Preset::Tiny.config())?;
    let (seed, batch, steps) = (2u32, 64usize, 5u64);
    let optim = OptimConfig::default();
    let state = TrainState::fresh(&model, seed);
    let mut cpu = CpuBackend::new(model.clone(), optim.clone(), seed, state.clone())?.with_data(Arc::clone(&ds), batch);
    let mut gpu = GpuBackend::new(ctx, model, optim, seed, state)?.with_data(&ds, batch)?;
    let mut worst = 0.0f32;
    let mut losses = Vec::new();
    for _ in 0..steps {
        let c = cpu.train_step(true)?.context("the CPU reports when asked")?;
        let g = gpu.train_step(true)?.context("the GPU reports when asked")?;
        let rel = (g.stats.loss - c.stats.loss).abs() / c.stats.loss.abs().max(1e-12);
        worst = worst.max(if rel.is_nan() { f32::INFINITY } else { rel });
        losses.push(format!("{:.5}/{:.5}", c.stats.loss, g.stats.loss));
    }
    println!(
        "training ({steps} steps of {batch} rays from one seed, cpu/gpu loss): {}; worst relative difference {worst:.1e}",
        losses.join(" ")
    );
    anyhow::ensure!(worst <= TOL_TRAIN_LOSS_REL, "the backends' losses differ by {worst:e} relative");
    Ok(())
}
