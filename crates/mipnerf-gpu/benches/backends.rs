//! Training and rendering throughput of both backends on this machine:
//! `cargo bench -p mipnerf-gpu --bench backends -- [--preset tiny|small|paper] [--batch N]
//! [--steps N] [--render-side N] [--cpu-only | --gpu-only]`.
//!
//! Trains on a synthetic multiscale-like dataset held in memory (20 views of 64x64 with random
//! pixels: throughput does not depend on the content) through the same `Backend` trait the CLI
//! uses, timing steps after a warm-up (which compiles the shaders); losses are read back every
//! 10th step, as `mipnerf train` does by default. Then renders a `side x side` image (evaluation
//! mode, both levels). Prints a markdown table: training samples/s (rays x samples of all levels,
//! per second) and rendering rays/s.
#![allow(missing_docs, clippy::unwrap_used)]

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use mipnerf_core::backend::{Backend, CpuBackend, ImageSpec, TrainState};
use mipnerf_core::camera::{Camera, PixelCenters};
use mipnerf_core::data::{Dataset, Pixels, Split, View, demo};
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

fn dataset() -> Dataset {
    let mut state = 1u32;
    let views = demo::view_poses(20, 0.0)
        .into_iter()
        .enumerate()
        .map(|(i, pose)| {
            let camera = Camera::from_camera_angle_x(64, 64, 0.69, pose).unwrap();
            let bytes = (0..64 * 64 * 4)
                .map(|_| {
                    state = mipnerf_core::rng::pcg_hash(state);
                    (state >> 24) as u8
                })
                .collect();
            View {
                file: PathBuf::from(format!("{i}.png")),
                camera,
                pixels: Pixels::Rgba8(bytes),
                near: 2.0,
                far: 6.0,
                lossmult: 1.0,
                scale: 0,
            }
        })
        .collect();
    Dataset::new(&PathBuf::from("synthetic"), Split::Train, views, true).unwrap()
}

struct Row {
    backend: String,
    train_ms: f64,
    samples_per_s: f64,
    render_rays_per_s: f64,
}

fn measure(mut b: Box<dyn Backend>, batch: usize, steps: usize, side: u32) -> Row {
    let (samples, levels) = (b.model().config.num_samples, b.model().config.num_levels);
    let samples_per_ray = samples * levels;
    for _ in 0..2 {
        b.train_step(true).unwrap();
    }
    let t = Instant::now();
    for i in 0..steps {
        b.train_step(i % 10 == 9 || i + 1 == steps).unwrap();
    }
    let train_s = t.elapsed().as_secs_f64();
    let pose = demo::camera_pose(0.3, 0.5);
    let camera = Camera::from_camera_angle_x(side, side, 0.69, pose).unwrap();
    let image = ImageSpec { camera, near: 2.0, far: 6.0, centers: PixelCenters::Centered, ndc: None, supersample: 1 };
    // Warm-up render (compiles the evaluation pipelines on a device), then the timed one.
    let small = ImageSpec { camera: Camera::from_camera_angle_x(8, 8, 0.69, pose).unwrap(), ..image.clone() };
    b.render_image(&small).unwrap();
    let t = Instant::now();
    let out = b.render_image(&image).unwrap();
    let render_s = t.elapsed().as_secs_f64();
    assert_eq!(out.len(), (side * side) as usize * levels);
    Row {
        backend: b.describe(),
        train_ms: train_s / steps as f64 * 1e3,
        samples_per_s: (steps * batch * samples_per_ray) as f64 / train_s,
        render_rays_per_s: f64::from(side * side) / render_s,
    }
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
    let ds = Arc::new(dataset());
    let optim = OptimConfig::default();
    println!(
        "preset {preset:?} ({} parameters), batch {batch} rays, {steps} timed steps, render {side}x{side}",
        model.num_params
    );
    println!("| backend | ms/step | training samples/s | rendering rays/s |");
    println!("|---|---|---|---|");
    let mut rows = Vec::new();
    if !flag("--gpu-only") {
        let cpu = CpuBackend::new(model.clone(), optim.clone(), 0, TrainState::fresh(&model, 0))
            .unwrap()
            .with_data(Arc::clone(&ds), batch);
        rows.push(measure(Box::new(cpu), batch, steps, side));
    }
    if !flag("--cpu-only") {
        match GpuContext::new(AdapterChoice::Any) {
            Ok(ctx) => {
                let gpu = GpuBackend::new(ctx, model.clone(), optim, 0, TrainState::fresh(&model, 0))
                    .unwrap()
                    .with_data(&ds, batch)
                    .unwrap();
                rows.push(measure(Box::new(gpu), batch, steps, side));
            }
            Err(e) => println!("(no GPU adapter: {e})"),
        }
    }
    for r in rows {
        println!("| {} | {:.1} | {:.0} | {:.0} |", r.backend, r.train_ms, r.samples_per_s, r.render_rays_per_s);
    }
}
