//! Throughput measurements shared by `mipnerf bench` and `cargo bench`: CPU training steps in
//! samples per second, the machine's sgemm rate for reference, and any [`Backend`]'s training
//! samples and rendering rays per second.

use std::time::Instant;

use std::path::{Path, PathBuf};

use crate::backend::{Backend, BackendError, ImageSpec};
use crate::camera::{Camera, PixelCenters};
use crate::cone::Ray;
use crate::dataset::{Dataset, Pixels, Split, View};
use crate::demo;
use crate::linalg::{Layout, Product, matmul};
use crate::model::{Levels, Model, ModelConfig};
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
    let flops_per_sample = model.mlps()[0].flops_per_sample();
    let samples_per_ray = model.config().num_samples * model.config().num_levels;
    let params = model.num_params();
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
                matmul(c, a, Layout::Normal, &b, Layout::Normal, Product { m: mm, k, n, accumulate: false });
            });
            t.elapsed().as_secs_f64()
        })
        .collect();
    times.sort_by(f64::total_cmp);
    2.0 * (m * k * n) as f64 / times[times.len() / 2] / 1e9
}

/// A matrix product with [`matmul`]'s signature: `c (m x n) = [c +] a · b`.
pub type ProductFn = dyn Fn(&mut [f32], &[f32], Layout, &[f32], Layout, Product) + Sync;

/// GFLOP/s of one thread's product of shape `p` (not accumulating) and layouts (`a` is `m x k`, `b` `k x n`
/// as the product sees them) on [`product_operands`], timed by [`timed_gflops`]: to compare the
/// f32 and bf16 kernels on the MLP's three products (forward, input gradient, weight gradient).
///
/// # Panics
/// As [`timed_gflops`].
#[must_use]
pub fn product_gflops(
    product: &ProductFn,
    (la, lb): (Layout, Layout),
    p: Product,
    reps: usize,
    c_past_line: usize,
) -> f64 {
    let Product { m, k, n, .. } = p;
    let (a, b) = product_operands(m, k, n);
    timed_gflops(m, k, n, reps, c_past_line, |c| product(c, &a, la, &b, lb, p))
}

/// The deterministic operands the product benchmarks multiply: `a` (`m x k` values) and `b`
/// (`k x n`), in [-0.5, 0.5).
#[must_use]
pub fn product_operands(m: usize, k: usize, n: usize) -> (Vec<f32>, Vec<f32>) {
    let a = (0..m * k).map(|i| ((i * 7919 % 1000) as f32 - 500.0) * 1e-3).collect();
    let b = (0..k * n).map(|i| ((i * 104_729 % 1000) as f32 - 500.0) * 1e-3).collect();
    (a, b)
}

/// GFLOP/s of `product`, which writes an `m x k · k x n` product into the `c` it is given:
/// median of `reps` (at least 1) after one untimed run. `c` starts `c_past_line` bytes (a
/// multiple of 4) past a 64-byte cache line: 0 as the MLP's buffers do
/// ([`crate::mlp::MlpCache`]), 16 as a large block from `malloc` does.
///
/// # Panics
/// If `c_past_line` is not a multiple of 4 below 64.
#[must_use]
pub fn timed_gflops(
    m: usize,
    k: usize,
    n: usize,
    reps: usize,
    c_past_line: usize,
    mut product: impl FnMut(&mut [f32]),
) -> f64 {
    assert!(c_past_line < 64 && c_past_line.is_multiple_of(4), "c_past_line {c_past_line}");
    let mut raw = vec![0.0f32; m * n + 16];
    let on_line = (64 - raw.as_ptr() as usize % 64) % 64 / 4;
    let c = &mut raw[on_line + c_past_line / 4..][..m * n];
    product(c);
    let mut times: Vec<f64> = (0..reps.max(1))
        .map(|_| {
            let t = Instant::now();
            product(c);
            t.elapsed().as_secs_f64()
        })
        .collect();
    times.sort_by(f64::total_cmp);
    2.0 * (m * k * n) as f64 / times[times.len() / 2] / 1e9
}

/// A training set for throughput measurements: `views` views of `side x side` pixels around the
/// demo scene's cameras, with pseudo-random RGBA8 pixels (throughput does not depend on them).
///
/// # Panics
/// If `side` is 0 or `views` is 0.
#[must_use]
pub fn synthetic_dataset(views: usize, side: u32) -> Dataset {
    let mut state = 1u32;
    let views = demo::view_poses(views, 0.0)
        .into_iter()
        .enumerate()
        .map(|(i, pose)| {
            let camera = Camera::from_camera_angle_x(side, side, 0.69, pose).unwrap_or_else(|e| unreachable!("{e}"));
            let bytes = (0..side * side * 4)
                .map(|_| {
                    state = crate::rng::pcg_hash(state);
                    (state >> 24) as u8
                })
                .collect();
            View {
                file: PathBuf::from(format!("synthetic_{i}.png")),
                camera,
                pixels: Pixels::Rgba8(bytes),
                near: 2.0,
                far: 6.0,
                lossmult: 1.0,
                scale: 0,
            }
        })
        .collect();
    Dataset::new(Path::new("synthetic"), Split::Train, views, true).unwrap_or_else(|e| panic!("synthetic dataset: {e}"))
}

/// What one backend does per second.
#[derive(Clone, Debug, serde::Serialize)]
pub struct BackendThroughput {
    /// The backend, as it describes itself.
    pub backend: String,
    /// Pixels per training batch.
    pub batch: usize,
    /// Mean milliseconds per training step.
    pub ms_per_step: f64,
    /// Training samples per second: rays x samples over all levels, per second.
    pub samples_per_second: f64,
    /// Rays rendered per second (evaluation mode, all levels).
    pub render_rays_per_second: f64,
}

/// Times `steps` training steps of batches of `batch` pixels (after two untimed ones, which
/// compile a device's shaders), reading the losses every 10th step as `mipnerf train` does, then
/// the render of a `render_side x render_side` image (after a small untimed one). The backend
/// must hold training data with `batch` pixels per batch.
///
/// # Errors
/// The backend's errors.
pub fn backend_throughput(
    b: &mut dyn Backend,
    batch: usize,
    steps: usize,
    render_side: u32,
) -> Result<BackendThroughput, BackendError> {
    let c = &b.model().config();
    let rays_per_step = batch * c.supersample * c.supersample;
    let samples_per_ray = c.num_samples * c.num_levels;
    for _ in 0..2 {
        b.train_step(true)?;
    }
    let steps = steps.max(1);
    let t = Instant::now();
    for i in 0..steps {
        b.train_step(i % 10 == 9 || i + 1 == steps)?;
    }
    let train_s = t.elapsed().as_secs_f64();
    let pose = demo::camera_pose(0.3, 0.5);
    let camera = |side: u32| {
        Camera::from_camera_angle_x(side.max(1), side.max(1), 0.69, pose)
            .map_err(|e| BackendError::Invalid(e.to_string()))
    };
    let supersample = b.model().config().supersample;
    let spec =
        |camera| ImageSpec { camera, near: 2.0, far: 6.0, centers: PixelCenters::Centered, ndc: None, supersample };
    b.render(&spec(camera(8)?), Levels::Last)?;
    let image = spec(camera(render_side)?);
    let t = Instant::now();
    b.render(&image, Levels::Last)?;
    let render_s = t.elapsed().as_secs_f64();
    Ok(BackendThroughput {
        backend: b.describe(),
        batch,
        ms_per_step: train_s / steps as f64 * 1e3,
        samples_per_second: (steps * rays_per_step * samples_per_ray) as f64 / train_s,
        render_rays_per_second: image.pixels() as f64 / render_s,
    })
}
