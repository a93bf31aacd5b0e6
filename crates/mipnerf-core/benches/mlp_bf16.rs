//! The MLP's forward and backward passes over one chunk on each thread at once: f32, bf16 with every
//! product packing its own operands, and bf16 with each activation and gradient packed once
//! (the default): `cargo bench -p mipnerf-core --bench mlp_bf16 [-- --threads N]`.
//!
//! The three run in turn, round after round, so that a shared machine's drift falls on each
//! alike; the medians and their ratios are printed. The chunk is the training step's
//! (`CHUNK_RAYS` rays x the preset's samples per level).
#![allow(missing_docs)]

use std::time::Instant;

use mipnerf_core::bf16::{Bf16Support, Precision};
use mipnerf_core::mlp::{MlpCache, MlpShape};
use mipnerf_core::model::{CHUNK_RAYS, Model, Preset};

/// Deterministic values in [-1, 1).
fn values(len: usize, seed: u32) -> Vec<f32> {
    let mut s = seed | 1;
    (0..len)
        .map(|_| {
            s = mipnerf_core::rng::pcg_hash(s);
            (s >> 8) as f32 / (1u32 << 23) as f32 - 1.0
        })
        .collect()
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let quick = std::env::args().any(|a| a == "--quick") || !std::env::args().any(|a| a == "--bench");
    let support = Bf16Support::detect();
    println!("{}", support.describe());
    let (rays, rounds) = if quick { (2, 2) } else { (CHUNK_RAYS, 15) };
    // `-- --threads N`: N threads at once (default: all the machine's).
    let args: Vec<String> = std::env::args().collect();
    let threads = args
        .iter()
        .position(|a| a == "--threads")
        .and_then(|i| args.get(i + 1)?.parse().ok())
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, usize::from))
        .max(1);
    println!(
        "ms per forward + backward pass of one chunk on each of {threads} threads at once, median of {} rounds:",
        rounds - 1
    );
    println!(
        "| preset | samples | f32 | bf16, packed in each product | bf16, packed once | once vs each | f32 vs once |"
    );
    println!("|---|---|---|---|---|---|---|");
    for (name, preset) in [("small", Preset::Small), ("paper", Preset::Paper)] {
        let config = preset.config();
        let model = Model::new(config.clone()).unwrap_or_else(|e| panic!("{name}: {e}"));
        let mut shape: MlpShape = model.mlps()[0].clone();
        let c = shape.config;
        let samples = config.num_samples;
        let n = rays * samples;
        let mut params = vec![0.0f32; shape.num_params];
        shape.init_glorot(&mut params, 7);
        let x = values(n * c.x_dim, 1);
        let view = values(rays * c.view_dim, 2);
        let d_rgb: Vec<f32> = values(n * 3, 3).iter().map(|v| v * 1e-3).collect();
        let d_density: Vec<f32> = values(n, 4).iter().map(|v| v * 1e-3).collect();
        // (precision, each product packs its own operands)
        let mut variants = vec![(Precision::F32, false)];
        if support.available() {
            variants.extend([(Precision::Bf16, true), (Precision::Bf16, false)]);
        }
        // One cache and gradient per variant and thread: every thread runs the same chunk at
        // once, as the training step's threads do (they share the memory bandwidth).
        let mut caches: Vec<Vec<(MlpCache, Vec<f32>)>> = variants
            .iter()
            .map(|_| (0..threads).map(|_| (MlpCache::default(), vec![0.0f32; shape.num_params])).collect())
            .collect();
        let mut times = vec![Vec::new(); variants.len()];
        for round in 0..rounds {
            for (v, &(precision, each)) in variants.iter().enumerate() {
                shape.precision = precision;
                let shape = &shape;
                let (params, x, view, d_rgb, d_density) = (&params, &x, &view, &d_rgb, &d_density);
                let t = Instant::now();
                std::thread::scope(|scope| {
                    for (cache, grads) in &mut caches[v] {
                        scope.spawn(move || {
                            cache.set_training(true);
                            cache.set_pack_in_each_product(each);
                            shape.forward(params, x, view, rays, samples, cache);
                            shape.backward(
                                params,
                                mipnerf_core::mlp::MlpInputs { x, view, samples_per_ray: samples },
                                cache,
                                mipnerf_core::mlp::OutputGradients { rgb: d_rgb, density: d_density },
                                grads,
                            );
                        });
                    }
                });
                // The first round warms the buffers and is not counted.
                if round > 0 {
                    times[v].push(t.elapsed().as_secs_f64() * 1e3);
                }
            }
        }
        let ms: Vec<f64> = times.iter_mut().map(|t| median(t)).collect();
        let cell = |v: usize| ms.get(v).map_or("not measured".to_string(), |m| format!("{m:.1}"));
        let ratio = |a: usize, b: usize| match (ms.get(a), ms.get(b)) {
            (Some(a), Some(b)) => format!("{:.3}x", a / b),
            _ => "-".to_string(),
        };
        println!("| {name} | {n} | {} | {} | {} | {} | {} |", cell(0), cell(1), cell(2), ratio(1, 2), ratio(0, 2));
    }
}
