//! `mipnerf check`: the GPU against the CPU reference on synthetic data, in three stages: the
//! IPE kernel, one whole model step (losses and every gradient), and a few training steps of both
//! backends from one seed (device-drawn batches, Adam, loss read-back).

use std::sync::Arc;

use anyhow::{Context, Result};
use clap::ValueEnum;
use mipnerf_core::Ray;
use mipnerf_core::backend::{Backend as _, CpuBackend, TrainState};
use mipnerf_core::compare::KernelCheck;
use mipnerf_core::demo;
use mipnerf_core::model::{Model, Preset};
use mipnerf_core::train::OptimConfig;
use mipnerf_gpu::{GpuBackend, GpuContext};

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
    let rays = demo::oblique_camera(32).generate_rays(mipnerf_core::PixelCenters::Centered, 2.0, 6.0, 1.0);
    let ipe = mipnerf_gpu::check::cast_ipe(&ctx, &rays)?;
    report(&ipe)?;
    model_step(&ctx, &rays)?;
    training(ctx)?;
    println!("ok");
    Ok(())
}

/// Prints a check's largest differences; fails with its first mismatches.
fn report(check: &KernelCheck) -> Result<()> {
    println!("{}", check.summary());
    let bad = &check.mismatches;
    anyhow::ensure!(
        bad.is_empty(),
        "{} values differ from the CPU reference beyond the tolerance:\n{}",
        bad.len(),
        bad.iter().take(10).cloned().collect::<Vec<_>>().join("\n")
    );
    Ok(())
}

fn model_step(ctx: &GpuContext, rays: &[Ray]) -> Result<()> {
    let step = mipnerf_gpu::check::model_step(ctx, rays)?;
    println!(
        "model step: {} rays, tiny preset, {} parameters, cpu loss {:.6}",
        rays.len(),
        step.num_params,
        step.cpu_loss
    );
    report(&step.check)
}

fn training(ctx: GpuContext) -> Result<()> {
    // Eight 32x32 views of the demo scene, in memory.
    let ds = Arc::new(demo::dataset(8, 32)?);
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
