//! Training and rendering throughput of both backends on this machine:
//! `cargo bench -p mipnerf-gpu --bench backends -- [--preset tiny|small|paper] [--batch N]
//! [--steps N] [--render-side N] [--cpu-only | --gpu-only]` (the same measurement as
//! `mipnerf bench`).
//!
//! Trains on a synthetic dataset held in memory (20 views of 64x64 with pseudo-random pixels:
//! throughput does not depend on the content) through the `Backend` trait the CLI uses, with
//! `mipnerf_core::bench::backend_throughput`. Prints a markdown table: training samples/s (rays x
//! samples of all levels, per second) and rendering rays/s.
#![allow(missing_docs, clippy::unwrap_used)]

use std::sync::Arc;

use mipnerf_core::backend::{Backend, CpuBackend, TrainState};
use mipnerf_core::bench::{backend_throughput, synthetic_dataset};
use mipnerf_core::model::{Model, Preset};
use mipnerf_core::train::OptimConfig;
use mipnerf_gpu::{AdapterChoice, GpuBackend, GpuContext};

fn arg<T: std::str::FromStr>(name: &str, default: T) -> T {
    let args: Vec<String> = std::env::args().collect();
    args.iter().position(|a| a == name).and_then(|i| args.get(i + 1)).and_then(|v| v.parse().ok()).unwrap_or(default)
}

fn flag(name: &str) -> bool {
    std::env::args().any(|a| a == name)
}

fn main() {
    let preset = match arg("--preset", "tiny".to_string()).as_str() {
        "paper" => Preset::Paper,
        "small" => Preset::Small,
        _ => Preset::Tiny,
    };
    // Without --bench (under `cargo test --all-targets`) only prove that it runs, at a small size.
    let full = flag("--bench");
    let batch = arg("--batch", if full { 1024usize } else { 16 });
    let steps = arg("--steps", if full { 10usize } else { 1 });
    let side = arg("--render-side", if full { 64u32 } else { 8 });
    let model = Model::new(preset.config()).unwrap();
    let ds = Arc::new(synthetic_dataset(20, 64));
    let optim = OptimConfig::default();
    println!(
        "preset {preset:?} ({} parameters), batch {batch} rays, {steps} timed steps, render {side}x{side}",
        model.num_params()
    );
    let mut backends: Vec<Box<dyn Backend>> = Vec::new();
    if !flag("--gpu-only") {
        let cpu = CpuBackend::new(model.clone(), optim.clone(), 0, TrainState::fresh(&model, 0)).unwrap();
        backends.push(Box::new(cpu.with_data(Arc::clone(&ds), batch)));
    }
    if !flag("--cpu-only") {
        match GpuContext::new(AdapterChoice::Any) {
            Ok(ctx) => {
                let gpu = GpuBackend::new(ctx, model.clone(), optim, 0, TrainState::fresh(&model, 0)).unwrap();
                backends.push(Box::new(gpu.with_data(&ds, batch).unwrap()));
            }
            Err(e) => println!("(no GPU adapter: {e})"),
        }
    }
    println!("| backend | ms/step | training samples/s | rendering rays/s |");
    println!("|---|---|---|---|");
    for mut b in backends {
        let r = backend_throughput(b.as_mut(), batch, steps, side).unwrap();
        println!(
            "| {} | {:.1} | {:.0} | {:.0} |",
            r.backend, r.ms_per_step, r.samples_per_second, r.render_rays_per_second
        );
    }
}
