//! `mipnerf bench`: training samples/s and rendering rays/s of the backends on this machine, on
//! a synthetic dataset in memory (`mipnerf_core::bench`), as a markdown table.

use crate::session::Session;
use std::sync::Arc;

use anyhow::{Context, Result};
use clap::ValueEnum;
use mipnerf_core::backend::{ImageSpec, TrainState, WorkCounters};
use mipnerf_core::bench::{backend_throughput, synthetic_dataset};
use mipnerf_core::bf16::{Bf16Kernel, Bf16Support};
use mipnerf_core::demo;
use mipnerf_core::model::Levels;
use mipnerf_core::model::{Field, Model, TriMipRecipe};
use mipnerf_core::train::OptimConfig;
use mipnerf_core::{Camera, PixelCenters};

use crate::backend;
use crate::config::{Backend, FieldArg, PrecisionArg, PresetArg};
use mipnerf_gpu::BackendSetup;

/// Which backends `mipnerf bench` measures.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum BenchBackends {
    /// The CPU.
    Cpu,
    /// Any GPU adapter, software ones included.
    Gpu,
    /// What `--backend auto` picks.
    Auto,
    /// The CPU, then any GPU adapter.
    Both,
}

/// The settings of one measurement.
#[derive(Clone, Debug)]
pub struct BenchArgs {
    /// Which backends.
    pub backends: BenchBackends,
    /// Model sizes, measured one after the other.
    pub presets: Vec<PresetArg>,
    /// Fields, measured one after the other for each size.
    pub fields: Vec<FieldArg>,
    /// Pixels per batch.
    pub batch: usize,
    /// Timed steps.
    pub steps: usize,
    /// Side of the rendered image.
    pub render_side: u32,
    /// Precisions to measure (one row each on the CPU; a device backend runs f32 once).
    pub precisions: Vec<PrecisionArg>,
    /// The GPU to open (`--adapter`, `--gpu-memory`).
    pub device: mipnerf_gpu::DeviceOptions,
}

/// Measures and prints the table.
///
/// # Errors
/// Bad sizes, or a backend that cannot be opened or fails.
pub fn bench(a: &BenchArgs, session: &Session) -> Result<()> {
    anyhow::ensure!(a.steps > 0, "--steps must be positive");
    anyhow::ensure!(
        (1..=crate::config::MAX_BATCH_RAYS).contains(&a.batch),
        "--batch-rays must be between 1 and {}, got {}",
        crate::config::MAX_BATCH_RAYS,
        a.batch
    );
    anyhow::ensure!((1..=4096).contains(&a.render_side), "--render-side must be between 1 and 4096");
    anyhow::ensure!(!a.precisions.is_empty(), "--precision needs at least one value");
    anyhow::ensure!(!a.presets.is_empty(), "--preset needs at least one value");
    anyhow::ensure!(!a.fields.is_empty(), "--field needs at least one value");
    let ds = Arc::new(synthetic_dataset(20, 64));
    let which: &[Backend] = match a.backends {
        BenchBackends::Cpu => &[Backend::Cpu],
        BenchBackends::Gpu => &[Backend::Gpu],
        BenchBackends::Auto => &[Backend::Auto],
        BenchBackends::Both => &[Backend::Cpu, Backend::Gpu],
    };
    println!(
        "batches of {} rays, {} timed steps, render {s}x{s}; {}",
        a.batch,
        a.steps,
        bf16_line(),
        s = a.render_side
    );
    let mut rows = Vec::new();
    for (&preset, &field) in a.presets.iter().flat_map(|p| a.fields.iter().map(move |f| (p, f))) {
        let (model, optim) = bench_model(preset, field)?;
        let shape = format!("{preset:?}, {} ({} parameters)", field.name(), model.num_params()).to_lowercase();
        for (&choice, &precision) in which.iter().flat_map(|c| a.precisions.iter().map(move |p| (c, p))) {
            if choice == Backend::Gpu && precision != PrecisionArg::F32 {
                continue;
            }
            if choice == Backend::Gpu && field == FieldArg::HashGrid {
                println!("{shape}: no GPU row (the hash grid runs on the CPU backend only)");
                continue;
            }
            let setup = BackendSetup {
                model: model.clone(),
                optim: optim.clone(),
                seed: 0,
                state: TrainState::fresh(&model, 0),
                data: Some((Arc::clone(&ds), a.batch)),
                render_chunk: None,
                device: a.device.clone(),
            };
            let (mut b, _) = backend::open(choice, setup, precision, session)?;
            let work = device_work(b.as_mut(), a.render_side).with_context(|| format!("counting {}", b.describe()))?;
            let r = backend_throughput(b.as_mut(), a.batch, a.steps, a.render_side)
                .with_context(|| format!("measuring {}", b.describe()))?;
            rows.push((shape.clone(), r, work));
        }
    }
    println!("| model | backend | ms/step | training samples/s | rendering rays/s |");
    println!("|---|---|---|---|---|");
    for (shape, r, _) in &rows {
        println!(
            "| {shape} | {} | {:.1} | {:.0} | {:.0} |",
            r.backend, r.ms_per_step, r.samples_per_second, r.render_rays_per_second
        );
    }
    for (_, r, work) in &rows {
        let Some(work) = work else { continue };
        println!();
        println!("device work of {}:", r.backend);
        println!(
            "| what | dispatches | compute passes | submits | buffers created | bind groups created | bytes read back |"
        );
        println!("|---|---|---|---|---|---|---|");
        for (what, c) in work {
            println!(
                "| {what} | {} | {} | {} | {} | {} | {} |",
                c.dispatches, c.compute_passes, c.submits, c.buffers_created, c.bind_groups_created, c.bytes_read_back
            );
        }
    }
    Ok(())
}

/// Half the side of the Tri-Mip planes' cube over the synthetic dataset, whose cameras stand 4
/// units from the origin with their near bound at 2.
const BENCH_CUBE: f32 = 2.0;

/// The model of `preset` reading `field` (a Tri-Mip one with its recipe's planes and MLP over
/// [`BENCH_CUBE`]), and its optimiser's settings.
fn bench_model(preset: PresetArg, field: FieldArg) -> Result<(Model, OptimConfig)> {
    let config = preset.preset().config();
    if field == FieldArg::MipNerf {
        return Ok((Model::new(config)?, OptimConfig::default()));
    }
    if field == FieldArg::HashGrid {
        let recipe = mipnerf_core::model::HashGridRecipe::RECIPE;
        let mut config = TriMipRecipe::with_mlp(config, recipe.mlp);
        config.field = Field::HashGrid { grid: recipe.grid, half_side: BENCH_CUBE };
        return Ok((Model::new(config)?, OptimConfig { field: Some(recipe.adam), ..OptimConfig::default() }));
    }
    let recipe = TriMipRecipe::RECIPE;
    let mut config = TriMipRecipe::with_mlp(config, recipe.mlp);
    config.field = Field::TriMip {
        planes: TriMipRecipe::planes(recipe.resolution),
        half_side: BENCH_CUBE,
        pre_filtered: field == FieldArg::TriMip,
    };
    Ok((Model::new(config)?, OptimConfig { field: Some(recipe.adam), ..OptimConfig::default() }))
}

/// The header's bf16 line: the kernel [`Bf16Support::detect`] chose and, for AVX-512 BF16, the
/// rate of `vdpbf16ps` against the f32 FMA measured here and what `--precision auto` runs.
fn bf16_line() -> String {
    let support = Bf16Support::detect();
    if support.kernel() == Some(Bf16Kernel::Avx512)
        && let Ok(rate) = mipnerf_core::bf16::avx512_dot_flop_rate_against_fma()
    {
        return format!(
            "{} (vdpbf16ps at {rate:.2}x the flops per second of the f32 FMA here; precision auto runs {})",
            support.describe(),
            Bf16Support::auto().precision()
        );
    }
    support.describe()
}

/// What a device backend records, makes and reads back: the first training step, a later one,
/// a step that reports its losses, and rendering one chunk (`render_side`^2 pixels in one
/// chunk at most, the first render and a later one). `None` for the CPU.
fn device_work(
    b: &mut dyn mipnerf_core::backend::Backend,
    render_side: u32,
) -> Result<Option<Vec<(String, WorkCounters)>>> {
    let Some(start) = b.work_counters() else { return Ok(None) };
    let mut rows = Vec::new();
    let mut last = start;
    let mut take = |b: &mut dyn mipnerf_core::backend::Backend, what: &str| {
        let now = b.work_counters().unwrap_or_default();
        rows.push((what.to_string(), now - last));
        last = now;
    };
    b.train_step(false)?;
    take(b, "first training step");
    b.train_step(false)?;
    take(b, "training step");
    b.train_step(true)?;
    take(b, "training step reporting its losses");
    // Small enough to be one chunk on any device.
    let side = render_side.clamp(1, 32);
    let camera = Camera::from_camera_angle_x(side, side, 0.69, demo::camera_pose(0.3, 0.5))?;
    let spec = ImageSpec { camera, near: 2.0, far: 6.0, centers: PixelCenters::Centered, ndc: None, supersample: 1 };
    b.render(&spec, Levels::Last)?;
    take(b, &format!("first render chunk ({side}x{side} pixels)"));
    b.render(&spec, Levels::Last)?;
    take(b, &format!("render chunk ({side}x{side} pixels)"));
    Ok(Some(rows))
}
