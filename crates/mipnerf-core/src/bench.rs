//! Throughput measurements shared by `mipnerf bench` and `cargo bench`: CPU training steps in
//! samples per second, and the machine's sgemm rate for reference.

use std::time::Instant;

use crate::camera::{Camera, PixelCenters, Ray};
use crate::linalg::{Layout, matmul};
use crate::model::{Model, ModelConfig};
use crate::train::{OptimConfig, Trainer};
use rayon::prelude::*;

/// One benchmark's result.
#[derive(Clone, Debug, serde::Serialize)]
pub struct TrainThroughput {
    /// What was measured.
    pub name: String,
    /// Rays per batch.
    pub rays: usize,
    /// Samples per ray summed over levels.
    pub samples_per_ray: usize,
    /// Parameters.
    pub params: usize,
    /// Median seconds per step.
    pub seconds_per_step: f64,
    /// Training samples per second (rays x samples over all levels, per second).
    pub samples_per_second: f64,
    /// GFLOP/s of the MLP's matrix products (forward + backward).
    pub mlp_gflops: f64,
}

/// Rays of a synthetic 64x64 camera looking at the origin, repeated to `n`.
#[must_use]
pub fn synthetic_rays(n: usize) -> Vec<Ray> {
    let pose = [[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, -4.0], [0.0, 1.0, 0.0, 0.5]];
    let cam = Camera::from_camera_angle_x(64, 64, 0.69, pose).unwrap_or_else(|e| unreachable!("{e}"));
    cam.generate_rays(PixelCenters::Centered, 2.0, 6.0, 1.0).into_iter().cycle().take(n).collect()
}

/// Times `steps` CPU training steps (after `warmup` untimed ones) of `config` on `rays` rays.
#[must_use]
pub fn train_throughput(name: &str, config: ModelConfig, rays: usize, warmup: usize, steps: usize) -> TrainThroughput {
    let model = Model::new(config).unwrap_or_else(|e| panic!("benchmark config: {e}"));
    let flops_per_sample = model.mlps[0].flops_per_sample();
    let samples_per_ray = model.config.num_samples * model.config.num_levels;
    let params = model.num_params;
    let mut trainer = Trainer::new(model, OptimConfig::default(), 0);
    let batch = synthetic_rays(rays);
    let targets = vec![[0.5f32, 0.4, 0.3]; rays];
    for _ in 0..warmup {
        let _ = trainer.train_step(&batch, &targets);
    }
    let mut times: Vec<f64> = (0..steps.max(1))
        .map(|_| {
            let t = Instant::now();
            let _ = trainer.train_step(&batch, &targets);
            t.elapsed().as_secs_f64()
        })
        .collect();
    times.sort_by(f64::total_cmp);
    let sps = times[times.len() / 2];
    let samples = (rays * samples_per_ray) as f64;
    TrainThroughput {
        name: name.to_string(),
        rays,
        samples_per_ray,
        params,
        seconds_per_step: sps,
        samples_per_second: samples / sps,
        mlp_gflops: samples * flops_per_sample / sps / 1e9,
    }
}

/// GFLOP/s of a `m x k · k x n` single-precision product on all cores (`m` split across rayon
/// threads, the same way the training step splits rays), median of `reps`.
#[must_use]
pub fn sgemm_gflops(m: usize, k: usize, n: usize, reps: usize) -> f64 {
    let a = vec![0.5f32; m * k];
    let b = vec![0.25f32; k * n];
    let mut c = vec![0.0f32; m * n];
    let threads = rayon::current_num_threads().max(1);
    let rows = m.div_ceil(threads);
    let mut times: Vec<f64> = (0..reps.max(1))
        .map(|_| {
            let t = Instant::now();
            c.par_chunks_mut(rows * n).zip(a.par_chunks(rows * k)).for_each(|(c, a)| {
                let mm = a.len() / k;
                matmul(c, a, Layout::Normal, &b, Layout::Normal, mm, k, n, false);
            });
            t.elapsed().as_secs_f64()
        })
        .collect();
    times.sort_by(f64::total_cmp);
    2.0 * (m * k * n) as f64 / times[times.len() / 2] / 1e9
}
