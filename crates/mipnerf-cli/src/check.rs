//! `mipnerf check`: the GPU against the CPU reference on synthetic data, in three stages: the
//! IPE kernel, one whole model step (losses and every gradient), and a few training steps of both
//! backends from one seed (device-drawn batches, Adam, loss read-back).

use std::sync::Arc;

use anyhow::{Context, Result};
use clap::ValueEnum;
use mipnerf_core::backend::{Backend as _, CpuBackend, TrainState};
use mipnerf_core::bf16::Precision;
use mipnerf_core::compare::{KernelCheck, Tolerance, check_kernel};
use mipnerf_core::data::demo;
use mipnerf_core::model::{Mode, Model, ModelConfig, PointEncoding, Preset};
use mipnerf_core::sampling::Spacing;
use mipnerf_core::train::OptimConfig;
use mipnerf_core::{Ray, RayShape, stages};
use mipnerf_gpu::{GpuBackend, GpuContext};

/// IPE features: GPU vs CPU, absolute (features are bounded by 1; lavapipe measures < 5e-6).
const TOL_IPE_ABS: f32 = 1e-4;
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
    let n = 32usize;
    let ids: Vec<u32> = (0..rays.len() as u32).collect();
    let mut t = vec![0.0; rays.len() * (n + 1)];
    stages::sample_intervals(&rays, n, Spacing::Depth, Mode::Eval, &ids, &mut t);
    let kernel = mipnerf_gpu::kernels::cast_ipe::CastIpeKernel::new(&ctx)?;
    let degrees = (0, 16);
    let ipe = check_kernel(
        "cast_ipe",
        |(rays, t): &(&[Ray], &[f32])| {
            let mut x = vec![0.0; rays.len() * n * mipnerf_core::mip::ipe_len(degrees.0, degrees.1)];
            stages::cast_and_encode(
                rays,
                t,
                (n, false),
                RayShape::Cone,
                (PointEncoding::Integrated, Precision::F32),
                degrees,
                &mut x,
            );
            vec![("features", x)]
        },
        |(rays, t)| {
            kernel
                .run(&ctx, rays, t, n as u32, (RayShape::Cone, false), degrees.0, degrees.1)
                .map(|x| vec![("features", x)])
        },
        &(&rays[..], &t[..]),
        |_| Tolerance::abs(TOL_IPE_ABS),
    );
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
    let model = Model::new(ModelConfig { num_samples: 16, ..Preset::Tiny.config() })?;
    let params = model.init_params(1);
    let targets: Vec<[f32; 3]> = (0..rays.len()).map(|i| [(i % 5) as f32 / 5.0, 0.5, (i % 3) as f32 / 3.0]).collect();
    let mode = Mode::Train { seed: 1, step: 0 };
    let mut grads = vec![0.0; model.num_params()];
    let cpu = model.loss_and_grad(&params, rays, &targets, mode, &mut grads);
    let scale = grads.iter().fold(0.0f32, |m, x| m.max(x.abs())).max(1e-20);
    let gpu = mipnerf_gpu::model::GpuModel::new(ctx)?;
    println!(
        "model step: {} rays, tiny preset, {} parameters, cpu loss {:.6}",
        rays.len(),
        model.num_params(),
        cpu.loss
    );
    let step = check_kernel(
        "model step (loss; gradients, absolute, against the largest)",
        |_: &()| vec![("loss", vec![cpu.loss]), ("gradients", grads.clone())],
        |_| {
            let (stats, g) = gpu.loss_and_grad(ctx, &model, &params, rays, &targets, mode)?;
            Ok::<_, mipnerf_gpu::GpuError>(vec![("loss", vec![stats.loss]), ("gradients", g)])
        },
        &(),
        |name| {
            if name == "loss" { Tolerance::rel(TOL_STEP_LOSS_REL) } else { Tolerance::abs(TOL_STEP_GRAD_REL * scale) }
        },
    );
    report(&step)
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
