//! The MLP's forward and backward passes over one chunk on one thread: f32, bf16 with every
//! product packing its own operands, and bf16 with each activation and gradient packed once
//! (the default): `cargo bench -p mipnerf-core --bench mlp_bf16`.
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
    println!("ms per forward + backward pass of one chunk, one thread, median of {} rounds:", rounds - 1);
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
        let mut grads = vec![0.0f32; shape.num_params];
        // (precision, each product packs its own operands)
        let mut variants = vec![(Precision::F32, false)];
        if support.available() {
            variants.extend([(Precision::Bf16, true), (Precision::Bf16, false)]);
        }
        let mut caches: Vec<MlpCache> = variants.iter().map(|_| MlpCache::default()).collect();
        let mut times = vec![Vec::new(); variants.len()];
        for round in 0..rounds {
            for (v, &(precision, each)) in variants.iter().enumerate() {
                shape.precision = precision;
                let cache = &mut caches[v];
                cache.set_training(true);
                cache.set_pack_in_each_product(each);
                let t = Instant::now();
                shape.forward(&params, &x, &view, rays, samples, cache);
                shape.backward(&params, &x, &view, samples, cache, &d_rgb, &d_density, &mut grads);
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
