//! GPU MLP throughput: `cargo bench -p mipnerf-gpu --bench mlp_gpu` (on the best adapter found).
//!
//! Times the MLP forward pass and the backward pass (input and weight gradients) of the `paper`
//! shape and the small shape on the device, median of a few runs after a warm-up that compiles
//! the shaders, and prints GFLOP/s of the matrix products. Options: `--samples N`, `--reps R`.
#![allow(missing_docs, clippy::unwrap_used)]

mod common;
use common::arg;

use std::time::Instant;

use mipnerf_core::mlp::{MlpConfig, MlpShape};
use mipnerf_gpu::GpuContext;
use mipnerf_gpu::kernels::{DispatchCache, Recorder};
use mipnerf_gpu::mlp::{GpuMlp, MlpBuffers};

fn time(ctx: &GpuContext, reps: usize, mut record: impl FnMut(&mut Recorder<'_>)) -> f64 {
    let mut cache = DispatchCache::default();
    let mut times: Vec<f64> = (0..reps.max(1) + 1)
        .map(|_| {
            let mut rec = Recorder::with_cache(ctx, "bench", std::mem::take(&mut cache));
            record(&mut rec);
            let t = Instant::now();
            cache = rec.submit();
            ctx.wait().unwrap();
            t.elapsed().as_secs_f64()
        })
        .collect();
    times.remove(0); // warm-up: shader compilation
    times.sort_by(f64::total_cmp);
    times[times.len() / 2]
}

fn main() {
    let Some(ctx) = common::context() else { return };
    let full = common::full();
    let samples = arg("--samples", if full { 8192 } else { 256 });
    let reps = arg("--reps", if full { 3 } else { 1 });
    println!(
        "adapter: {} ({}, {}), {samples} samples, median of {reps}",
        ctx.adapter().name,
        ctx.adapter().backend,
        ctx.adapter().device_type
    );
    println!("| shape | forward ms | forward GFLOP/s | backward ms | backward GFLOP/s |");
    println!("|---|---|---|---|---|");
    let mlp = GpuMlp::new(&ctx).unwrap();
    let small =
        MlpConfig { net_depth: 4, net_width: 128, skip_layer: 2, net_width_condition: 64, ..MlpConfig::default() };
    for (name, cfg) in [("paper (8x256)", MlpConfig::default()), ("small (4x128)", small)] {
        let shape = MlpShape::new(cfg, 0).unwrap();
        let mut params = vec![0.0; shape.num_params];
        shape.init_glorot(&mut params, 1);
        let spr = 64;
        let n_rays = samples / spr;
        let bufs = MlpBuffers::new(&ctx, &shape, n_rays, spr);
        let n = n_rays * spr;
        ctx.queue().write_buffer(&bufs.x, 0, bytemuck::cast_slice(&vec![0.3f32; n * cfg.x_dim]));
        ctx.queue().write_buffer(&bufs.view, 0, bytemuck::cast_slice(&vec![0.2f32; n_rays * cfg.view_dim]));
        let p = ctx.storage_buffer("params", &params, true);
        let g = ctx.storage_buffer("grads", &vec![0.0f32; shape.num_params], false);
        let dr = ctx.storage_buffer("d rgb", &vec![0.01f32; n * 3], false);
        // The rays' directions (the fused kernels' view input; these shapes run as products).
        let dirs = ctx.storage_buffer("view directions", &vec![0.577f32; n_rays * 3], false);
        let (dd, stride) = bufs.d_raw_density();
        ctx.queue().write_buffer(dd, 0, bytemuck::cast_slice(&vec![0.01f32; n * stride]));
        let fwd = time(&ctx, reps, |rec| mlp.forward(rec, &shape, &p, &bufs, &dirs));
        let pg = mipnerf_gpu::mlp::ParamBuffers { params: &p, grads: &g };
        let bwd = time(&ctx, reps, |rec| mlp.backward(rec, &shape, pg, &bufs, &dr, &dirs).expect("backward"));
        let fwd_flops: f64 = shape.layers.iter().map(|l| 2.0 * (l.fan_in * l.fan_out) as f64).sum::<f64>() * n as f64;
        let bwd_flops = shape.flops_per_sample() * n as f64 - fwd_flops;
        println!(
            "| {name} | {:.1} | {:.2} | {:.1} | {:.2} |",
            fwd * 1e3,
            fwd_flops / fwd / 1e9,
            bwd * 1e3,
            bwd_flops / bwd / 1e9
        );
    }
}
