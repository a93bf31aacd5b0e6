//! What a sample costs the Tri-Mip field against the Mip-NeRF MLP, on one thread:
//! `cargo bench -p mipnerf-core --bench tri_mip`.
//!
//! 64 rays x 128 samples from a camera 4 units out through the unit cube (the Blender scenes'
//! geometry, a 256 px image's cones), so that neighbouring samples read neighbouring texels as a
//! real batch's do. Prints nanoseconds per sample, the median of the repetitions, for:
//! - the Mip-NeRF MLP of the fast preset (4 x 128 with a skip, colour 1 x 64, on 96 IPE
//!   features): forward and forward + backward (the IPE itself is `--bench ipe`'s);
//! - the Tri-Mip encoding at Tri-MipRF's size (3 planes of 512² x 16 features, 8 levels): the
//!   taps and reads, and the backward scatter;
//! - the hash grid of its recipe (16 levels of 2 features, 16 to 512 cells, tables of 2^17),
//!   down-weighted at the same footprints: the reads, and the backward scatter;
//! - two MLPs after the encoding (48 features, a 16-value view encoding, no skip): Tri-MipRF's
//!   shape (2 x 128, colour 4 x 128) and a small one (2 x 64, colour 1 x 64), forward + backward
//!   with the input gradient, in f32 and (where the CPU has a bf16 kernel) in bf16 products;
//! - once a step, whatever its batch: the pyramid's build and its push-down, in milliseconds.
#![allow(missing_docs, clippy::unwrap_used)]

use std::time::Instant;

use glam::Vec3;
use mipnerf_core::bf16::{Bf16Support, Precision};
use mipnerf_core::mip::conical_frustum_moments;
use mipnerf_core::mlp::{MlpCache, MlpConfig, MlpShape};
use mipnerf_core::tri_mip::{
    Pyramid, TriMipConfig, encode, encode_backward, encode_backward_batch, encode_batch, footprint_radius, level_of,
    taps,
};

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Nanoseconds per sample of `run` over `n` samples, the median of `reps`.
fn per_sample(reps: usize, n: usize, mut run: impl FnMut()) -> f64 {
    median(
        (0..reps)
            .map(|_| {
                let start = Instant::now();
                run();
                start.elapsed().as_secs_f64() / n as f64 * 1e9
            })
            .collect(),
    )
}

/// An MLP's forward and forward + backward (with the input gradient where `input_gradient`).
fn mlp_costs(
    config: MlpConfig,
    precision: Precision,
    rays: usize,
    per_ray: usize,
    reps: usize,
    input_gradient: bool,
) -> (f64, f64) {
    let mut shape = MlpShape::new(config, 0).unwrap();
    shape.precision = precision;
    let mut params = vec![0.0; shape.num_params];
    shape.init_glorot(&mut params, 1);
    let n = rays * per_ray;
    let x: Vec<f32> = (0..n * config.x_dim).map(|i| ((i * 7919) % 1000) as f32 / 500.0 - 1.0).collect();
    let view: Vec<f32> = (0..rays * config.view_dim).map(|i| ((i * 104_729) % 1000) as f32 / 500.0 - 1.0).collect();
    let (d_rgb, d_density) = (vec![0.01; n * 3], vec![0.01; n]);
    let mut grads = vec![0.0; shape.num_params];
    let mut d_x = vec![0.0; n * config.x_dim];
    let mut cache = MlpCache::default();
    cache.set_training(true);
    let forward = per_sample(reps, n, || shape.forward(&params, &x, &view, rays, per_ray, &mut cache));
    let both = per_sample(reps, n, || {
        shape.forward(&params, &x, &view, rays, per_ray, &mut cache);
        shape.backward(
            &params,
            mipnerf_core::mlp::MlpInputs { x: &x, view: &view, samples_per_ray: per_ray },
            &mut cache,
            mipnerf_core::mlp::OutputGradients { rgb: &d_rgb, density: &d_density },
            &mut grads,
        );
        if input_gradient {
            shape.input_gradient(&params, &cache, &mut d_x);
        }
    });
    std::hint::black_box((&grads, &d_x));
    (forward, both)
}

fn main() {
    let quick = std::env::args().any(|a| a == "--quick") || !std::env::args().any(|a| a == "--bench");
    let (rays, per_ray, reps) = if quick { (4, 16, 1) } else { (64, 128, 15) };
    let planes = if quick { TriMipConfig { resolution: 64, features: 16, levels: 4 } } else { TriMipConfig::default() };
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    pool.install(|| {
        let n = rays * per_ray;
        println!("one thread, {rays} rays x {per_ray} samples, median of {reps}:");
        println!("| stage | ns per sample, forward | ns per sample, forward + backward |");
        println!("|---|---|---|");
        let fast = MlpConfig {
            net_depth: 4,
            net_width: 128,
            skip_layer: 2,
            net_width_condition: 64,
            x_dim: 96,
            view_dim: 27,
            ..MlpConfig::default()
        };
        let (f, b) = mlp_costs(fast, Precision::F32, rays, per_ray, reps, false);
        println!("| Mip-NeRF MLP, fast preset (4 x 128, skip; colour 1 x 64; 96 IPE features) | {f:.0} | {b:.0} |");

        // The samples: along rays from (0.1, -0.2, 4) towards the unit cube, t in [2, 6], in the
        // box [-1.5, 1.5]^3 mapped to [0, 1]^3.
        let (min, side) = (Vec3::splat(-1.5), 3.0f32);
        let base_radius = 0.7 / 256.0 * 2.0 / 12f32.sqrt();
        let mut samples = Vec::with_capacity(n);
        for r in 0..rays {
            let a = r as f32 / rays as f32 - 0.5;
            let (origin, direction) = (Vec3::new(0.1, -0.2, 4.0), Vec3::new(0.7 * a, 0.3 * a, -1.0));
            for j in 0..per_ray {
                let (t0, t1) = (2.0 + 4.0 * j as f32 / per_ray as f32, 2.0 + 4.0 * (j + 1) as f32 / per_ray as f32);
                let m = conical_frustum_moments(t0, t1, base_radius);
                let x = (origin + direction * m.t_mean - min) / side;
                let level = level_of(footprint_radius(&m) * direction.length() / side, &planes);
                samples.push((x, level));
            }
        }
        let mut level0 = vec![0.0; planes.num_params()];
        planes.init(&mut level0, 2);
        let mut pyramid = Pyramid::zeros(planes);
        let build = per_sample(reps.min(5), 1, || pyramid.build(&level0)) / 1e6;
        let dim = planes.encoding_dim();
        let mut x = vec![0.0; n * dim];
        let forward = per_sample(reps, n, || {
            for (k, &(p, l)) in samples.iter().enumerate() {
                encode(&planes, &level0, &pyramid, &taps(&planes, p, l), &mut x[k * dim..(k + 1) * dim]);
            }
        });
        let mut grad0 = vec![0.0; planes.num_params()];
        let mut grad_pyramid = Pyramid::zeros(planes);
        let d_x: Vec<f32> = (0..n * dim).map(|i| ((i % 17) as f32 - 8.0) * 1e-3).collect();
        let backward = per_sample(reps, n, || {
            for (k, &(p, l)) in samples.iter().enumerate() {
                let t = taps(&planes, p, l);
                encode_backward(&planes, &t, &d_x[k * dim..(k + 1) * dim], &mut grad0, &mut grad_pyramid);
            }
        });
        let push = per_sample(reps.min(5), 1, || grad_pyramid.push_down(&mut grad0)) / 1e6;
        std::hint::black_box((&x, &grad0));
        let levels: Vec<f32> = samples.iter().map(|s| s.1).collect();
        println!(
            "| Tri-Mip encoding ({}² x {} features, {} levels; levels read {:.1} to {:.1}) | {forward:.0} | {:.0} |",
            planes.resolution,
            planes.features,
            planes.levels,
            levels.iter().copied().fold(f32::INFINITY, f32::min),
            levels.iter().copied().fold(f32::NEG_INFINITY, f32::max),
            forward + backward
        );
        hash_grid_row(&samples, if quick { 1 } else { 16 }, reps);
        for (name, depth, width, cond_depth, cond_width) in [
            ("Tri-MipRF's shape (2 x 128; colour 4 x 128)", 2, 128, 4, 128),
            ("small (2 x 64; colour 1 x 64)", 2, 64, 1, 64),
        ] {
            let config = MlpConfig {
                net_depth: depth,
                net_width: width,
                skip_layer: depth + 1,
                net_depth_condition: cond_depth,
                net_width_condition: cond_width,
                x_dim: dim,
                view_dim: 16,
            };
            let (f, b) = mlp_costs(config, Precision::F32, rays, per_ray, reps, true);
            println!("| field MLP, {name}, 48 features, 16 view values | {f:.0} | {b:.0} |");
            if Bf16Support::detect().kernel().is_some() {
                let (f, b) = mlp_costs(config, Precision::Bf16, rays, per_ray, reps, true);
                println!("| field MLP, {name}, bf16 products | {f:.0} | {b:.0} |");
            }
        }
        println!(
            "once a step: the pyramid's build {build:.1} ms, its push-down {push:.1} ms ({} parameters in level 0)",
            planes.num_params()
        );
    });
    batched(planes, if quick { 256 } else { 65_536 }, reps);
}

/// The batched encoding and backward scatter (`encode_batch`, `encode_backward_batch`) on every
/// thread, over a step's worth of samples along rays, against the same samples one by one.
fn batched(planes: TriMipConfig, n: usize, reps: usize) {
    let threads = rayon::current_num_threads();
    let per_ray = 128;
    let base_radius = 0.7 / 256.0 * 2.0 / 12f32.sqrt();
    let (mut points, mut levels) = (Vec::with_capacity(n), Vec::with_capacity(n));
    for k in 0..n {
        let (r, j) = (k / per_ray, k % per_ray);
        let a = (r % 256) as f32 / 256.0 - 0.5;
        let b = (r / 256) as f32 / 256.0 - 0.5;
        let direction = Vec3::new(0.7 * a, 0.7 * b, -1.0);
        let (t0, t1) = (2.0 + 4.0 * j as f32 / per_ray as f32, 2.0 + 4.0 * (j + 1) as f32 / per_ray as f32);
        let m = conical_frustum_moments(t0, t1, base_radius);
        points.push((Vec3::new(0.1, -0.2, 4.0) + direction * m.t_mean + 1.5) / 3.0);
        levels.push(level_of(footprint_radius(&m) * direction.length() / 3.0, &planes));
    }
    let mut level0 = vec![0.0; planes.num_params()];
    planes.init(&mut level0, 3);
    let mut pyramid = Pyramid::zeros(planes);
    pyramid.build(&level0);
    let dim = planes.encoding_dim();
    let mut x = vec![0.0; n * dim];
    let mut t = vec![taps(&planes, Vec3::ZERO, 0.0); n];
    let forward = per_sample(reps, n, || encode_batch(&planes, &level0, &pyramid, &points, &levels, &mut t, &mut x));
    let d_x: Vec<f32> = (0..n * dim).map(|i| ((i % 17) as f32 - 8.0) * 1e-3).collect();
    let (mut grad0, mut grad_pyramid) = (vec![0.0; planes.num_params()], Pyramid::zeros(planes));
    let backward = per_sample(reps, n, || encode_backward_batch(&planes, &[(&t, &d_x)], &mut grad0, &mut grad_pyramid));
    let sequential = per_sample(reps, n, || {
        for (k, tk) in t.iter().enumerate() {
            encode_backward(&planes, tk, &d_x[k * dim..(k + 1) * dim], &mut grad0, &mut grad_pyramid);
        }
    });
    let build = per_sample(reps.min(5), 1, || pyramid.build(&level0)) / 1e6;
    let push = per_sample(reps.min(5), 1, || grad_pyramid.push_down(&mut grad0)) / 1e6;
    std::hint::black_box((&x, &grad0));
    println!("on {threads} threads: the pyramid's build {build:.1} ms, its push-down {push:.1} ms");
    println!(
        "batched on {threads} threads, {n} samples ({} rays of {per_ray}): encoding {forward:.0} ns a sample, \
         backward scatter (encode_backward_batch) {backward:.0} ns a sample (the per-sample calls: {sequential:.0})",
        n / per_ray
    );
}

/// The hash grid's encoding and backward scatter, one sample at a time on this thread, at the
/// recipe's shape (`levels` levels; 1 for `--quick`), the samples' footprints as the field takes
/// them (half the cross-section's radius; `samples` carry the Tri-Mip level, so the footprint is
/// taken again from it).
fn hash_grid_row(samples: &[(Vec3, f32)], levels: usize, reps: usize) {
    use mipnerf_core::hash_grid::{GridSample, Levels};
    let grid = mipnerf_core::hash_grid::HashGridConfig { levels, ..mipnerf_core::model::HashGridRecipe::RECIPE.grid };
    let levels_of = Levels::new(grid);
    let mut params = vec![0.0; grid.num_params()];
    grid.init(&mut params, 4);
    // The Tri-Mip level is log2 of the footprint's diameter in 512 texels: back to a radius.
    let points: Vec<GridSample> =
        samples.iter().map(|&(at, level)| GridSample { at, scale: 0.5 * 2f32.powf(level) / 512.0 / 2.0 }).collect();
    let (n, dim) = (points.len(), grid.encoding_dim());
    let mut x = vec![0.0; n * dim];
    let forward = per_sample(reps, n, || levels_of.encode_many(&params, &points, &mut x));
    let d_x: Vec<f32> = (0..n * dim).map(|i| ((i % 17) as f32 - 8.0) * 1e-3).collect();
    let mut grad = vec![0.0; grid.num_params()];
    let backward = per_sample(reps, n, || levels_of.encode_backward_batch(&[(&points, &d_x)], &mut grad));
    std::hint::black_box((&x, &grad));
    println!(
        "| hash grid ({} levels of {} features, {} to {} cells, tables of 2^{}) | {forward:.0} | {:.0} |",
        grid.levels,
        grid.features,
        grid.coarsest,
        grid.resolution(grid.levels - 1),
        grid.log2_table,
        forward + backward
    );
}
