//! An occupancy grid's update, the two ways the GPU backend could make it:
//! `cargo bench -p mipnerf-gpu --bench grid_update` (on the best adapter found).
//!
//! - on the host (what the GPU backend did until the device update): the parameters read back,
//!   then `OccupancyGrid::update` on the CPU's field, every core;
//! - on the device (what it does): the pyramid, `GpuModel::update_grid` (probes, the field's
//!   encoding, the MLP, the opacities, then the occupied cells and their dilations,
//!   `occupancy_refresh.wgsl`), waited for, nothing read back.
//!
//! For the fast preset's 64³ grid and its 1,024 rays a step, with the Mip-NeRF MLP and the
//! Tri-Mip field's recipe; median of a few updates after one that compiles the shaders. Options:
//! `--resolution R`, `--reps N`.
#![allow(missing_docs, clippy::unwrap_used)]

mod common;
use common::arg;

use std::time::Instant;

use mipnerf_core::backend::TrainState;
use mipnerf_core::model::{Field, Model, ModelConfig, Preset, TriMipRecipe};
use mipnerf_core::occupancy::{OccupancyConfig, OccupancyGrid};
use mipnerf_gpu::kernels::occupancy::DeviceGrid;
use mipnerf_gpu::kernels::{DispatchCache, Recorder};
use mipnerf_gpu::model::{GpuModel, ModelBuffers};

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let Some(ctx) = common::context() else { return };
    let full = common::full();
    let resolution = arg("--resolution", if full { 64 } else { 8 });
    let reps = arg("--reps", if full { 3 } else { 1 });
    let rays = if full { 1024 } else { 16 };
    println!(
        "adapter: {} ({}, {}); host: {} threads; a {resolution}³ grid, buffers of {rays} rays, median of {reps}",
        ctx.adapter().name,
        ctx.adapter().backend,
        ctx.adapter().device_type,
        rayon::current_num_threads()
    );
    println!(
        "| field | on the host: read back + update, ms | on the device: update and occupied cells, nothing read back, ms |"
    );
    println!("|---|---|---|");
    let tri_mip = {
        let field = Field::TriMip {
            planes: TriMipRecipe::planes(TriMipRecipe::RECIPE.resolution),
            half_side: 1.5,
            pre_filtered: true,
        };
        TriMipRecipe::with_mlp(ModelConfig { field, ..Preset::Fast.config() }, TriMipRecipe::RECIPE.mlp)
    };
    let kernels = GpuModel::new(&ctx).unwrap();
    for (name, cfg) in [("Mip-NeRF MLP (fast)", Preset::Fast.config()), ("Tri-Mip field (recipe)", tri_mip)] {
        let model = Model::new(cfg).unwrap();
        let params = TrainState::fresh(&model, 1).params;
        let config = OccupancyConfig { resolution, bound: 1.5, ..OccupancyConfig::default() };
        let grid = OccupancyGrid::new(config).unwrap();
        let p = ctx.storage_buffer("params", &params, true);
        let mut work = ModelBuffers::new(&ctx, &model, rays).unwrap();
        let mut on_device = DeviceGrid::new(&ctx, &grid).unwrap();
        let (mut host, mut device) = (Vec::new(), Vec::new());
        let mut cache = DispatchCache::default();
        for rep in 0..=reps {
            let step = 300 + 16 * rep as u64;
            let mut g = grid.clone();
            let t = Instant::now();
            let read = ctx.read_f32(&p, model.num_params()).unwrap();
            g.update(&model.density_field(&read), 1, step);
            host.push(t.elapsed().as_secs_f64());

            let t = Instant::now();
            let mut rec = Recorder::with_cache(&ctx, "grid update", std::mem::take(&mut cache));
            kernels.prepare_field(&mut rec, &model, &p, &work, false).unwrap();
            kernels.update_grid(&mut rec, &model, &p, &mut work, &mut on_device, (1, step as u32)).unwrap();
            cache = rec.submit();
            ctx.wait().unwrap();
            device.push(t.elapsed().as_secs_f64());
        }
        // The first of each: shader compilation and first-touch allocations.
        for v in [&mut host, &mut device] {
            v.remove(0);
        }
        println!("| {name} | {:.1} | {:.1} |", median(host) * 1e3, median(device) * 1e3);
    }
}
