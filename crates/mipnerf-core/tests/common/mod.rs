//! Shared helpers for the core crate's tests: golden-file loading and tolerant comparison that
//! reports every mismatch at once.
#![allow(dead_code, clippy::unwrap_used, missing_docs)]

pub mod scene;

use mipnerf_core::test_support::flat;
use serde_json::Value;

/// Functions that accumulate (sums, cumulative sums, CDF inversion).
pub const TOL_ACCUMULATED: Tol = Tol { rel: 1e-5, abs: 1e-6 };
/// Rays: ours are computed in f64 and rounded once, the official Blender loader in f32.
pub const TOL_RAYS: Tol = Tol { rel: 1e-6, abs: 1e-7 };

/// The workspace's one tolerance type (`|got - want| <= abs + rel |want|`).
pub use mipnerf_core::compare::Tolerance as Tol;

/// The central difference of `loss` in parameter `i` of `p` with step `h`, divided by the step
/// as `f32` actually took it (`p` is left as it was).
pub fn central_difference(loss: impl Fn(&[f32]) -> f64, p: &mut [f32], i: usize, h: f32) -> f64 {
    let x0 = p[i];
    p[i] = x0 + h;
    let up = loss(p);
    p[i] = x0 - h;
    let down = loss(p);
    p[i] = x0;
    (up - down) / (f64::from(x0 + h) - f64::from(x0 - h))
}

/// The loss of `model` on `batch` at parameters `p` in `mode` (its gradient dropped): what a
/// finite-difference check of the whole loss differentiates.
pub fn batch_loss(
    model: &mipnerf_core::model::Model,
    batch: mipnerf_core::model::TrainBatch<'_>,
    mode: mipnerf_core::model::Mode,
) -> impl Fn(&[f32]) -> f64 {
    move |p: &[f32]| {
        let mut g = vec![0.0; model.num_params()];
        let with = mipnerf_core::model::GradWith::default();
        f64::from(model.loss_and_grad(p, batch, mode, &mut g, with).loss)
    }
}

/// Finite-difference step of the whole loss's checks: steps of 1e-2 keep f32 rounding noise
/// (~1e-7 of a loss of ~0.1, divided by the step) below the tolerance.
pub const FD_STEP: f32 = 1e-2;
/// A parameter whose differences at `FD_STEP` and half of it disagree by more than this sits on a
/// kink (a ReLU's, a clamp's) and is skipped; an analytic gradient further than this from the
/// difference is wrong.
pub const FD_ABS: f64 = 3e-5;
/// The relative part of the same bounds.
pub const FD_REL: f64 = 3e-2;

/// Checks the analytic gradient `grads` of `loss` at `params` against central differences at
/// the parameters `picks` (each named for the message): all agree, and at most a quarter sit on
/// kinks.
///
/// # Panics
/// With every disagreement, or when too many picks sit on kinks.
pub fn assert_gradients_match_finite_differences(
    picks: Vec<(String, usize)>,
    grads: &[f32],
    params: &mut [f32],
    loss: impl Fn(&[f32]) -> f64,
) {
    let (mut bad, mut checked, mut skipped) = (Vec::new(), 0, 0);
    for (what, i) in picks {
        let (a, b) =
            (central_difference(&loss, params, i, FD_STEP), central_difference(&loss, params, i, FD_STEP / 2.0));
        if (a - b).abs() > FD_ABS + FD_REL * a.abs() {
            skipped += 1;
            continue;
        }
        checked += 1;
        let g = f64::from(grads[i]);
        if (g - b).abs() > FD_ABS + FD_REL * b.abs() {
            bad.push(format!("{what} param {i}: analytic {g:e}, finite difference {b:e}"));
        }
    }
    assert!(skipped * 4 <= checked + skipped, "{skipped} of {} parameters sat on kinks", checked + skipped);
    assert!(bad.is_empty(), "{} of {checked} gradients disagree:\n{}", bad.len(), bad.join("\n"));
}

/// The default optimiser with a learning rate decaying from `lr_init` to `lr_final` over
/// `steps` steps, without warm-up.
pub fn optim_decaying(lr_init: f32, lr_final: f32, steps: u64) -> mipnerf_core::train::OptimConfig {
    mipnerf_core::train::OptimConfig {
        lr: mipnerf_core::schedule::LrSchedule {
            lr_init,
            lr_final,
            max_steps: steps,
            lr_delay_steps: 0,
            lr_delay_mult: 1.0,
            decay_steps: None,
        },
        ..mipnerf_core::train::OptimConfig::default()
    }
}

/// `steps` training steps of `trainer`, each on 256 rays drawn at random (from `seed`) from
/// `rays` and their `colours`; the losses, every one checked finite.
pub fn train_on_random_batches(
    trainer: &mut mipnerf_core::train::Trainer,
    rays: &[mipnerf_core::cone::Ray],
    colours: &[[f32; 3]],
    steps: usize,
    seed: u64,
) -> Vec<f32> {
    use rand::{Rng, SeedableRng};
    let mut rng = rand::rngs::SmallRng::seed_from_u64(seed);
    (0..steps)
        .map(|_| {
            let idx: Vec<usize> = (0..256).map(|_| rng.random_range(0..rays.len())).collect();
            let r: Vec<_> = idx.iter().map(|&i| rays[i]).collect();
            let c: Vec<_> = idx.iter().map(|&i| colours[i]).collect();
            let rep = trainer.train_step(&r, &c);
            assert!(rep.stats.loss.is_finite(), "step {}: loss {}", rep.step, rep.stats.loss);
            rep.stats.loss
        })
        .collect()
}

pub fn v3(v: &Value) -> glam::Vec3 {
    let x = flat(v);
    assert_eq!(x.len(), 3);
    glam::Vec3::new(x[0], x[1], x[2])
}

/// Saves a checkpoint of `model` holding made-up parameters and Adam moments, loads it back and
/// checks it is bit for bit what was saved; returns the file's folder and path (the folder kept
/// alive for the caller to read the file).
pub fn checkpoint_round_trip(model: &mipnerf_core::model::Model) -> (tempfile::TempDir, std::path::PathBuf) {
    use mipnerf_core::checkpoint::{self, Checkpoint};
    use mipnerf_core::train::AdamState;
    let n = model.num_params();
    let f = |k: f32| (0..n).map(|i| (i as f32 * 0.37 + k).sin()).collect::<Vec<f32>>();
    let ck = Checkpoint {
        step: 5,
        params: f(0.0),
        adam: AdamState { m: f(1.0), v: f(2.0).into_iter().map(f32::abs).collect(), t: 5 },
        occupancy: None,
    };
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("ck.safetensors");
    checkpoint::save(&path, model, &ck).unwrap();
    let back = checkpoint::load(&path, model).unwrap();
    assert!(back.params == ck.params && back.adam.m == ck.adam.m && back.adam.v == ck.adam.v);
    (dir, path)
}

/// The occupancy grid's density probes of `model` (a grid field) read its field at each probe's
/// footprint: each probe's density is the MLP's on the field's encoding of its Gaussian, and
/// other field parameters give other densities.
pub fn assert_probes_read_the_field(model: &mipnerf_core::model::Model) {
    use mipnerf_core::mip::Gaussian;
    use mipnerf_core::mlp::MlpCache;
    use mipnerf_core::occupancy::DensityField;
    use rand::{Rng, SeedableRng};
    let mut params = model.init_params(6);
    let mut rng = rand::rngs::SmallRng::seed_from_u64(7);
    for p in &mut params[..model.field_params()] {
        *p = rng.random_range(-0.5..0.5);
    }
    let probes: Vec<Gaussian> = (0..50)
        .map(|_| Gaussian {
            mean: glam::Vec3::new(
                rng.random_range(-1.4..1.4),
                rng.random_range(-1.4..1.4),
                rng.random_range(-1.4..1.4),
            ),
            cov_diag: glam::Vec3::splat(rng.random_range(0.0..0.01)),
        })
        .collect();
    let got = model.density_field(&params).densities(&probes, false);
    let state = model.field_state(&params);
    let dim = model.config().x_dim();
    let mut x = vec![0.0; probes.len() * dim];
    for (g, dst) in probes.iter().zip(x.chunks_exact_mut(dim)) {
        model.encode_probe(&params, &state, g, false, dst);
    }
    let mut cache = MlpCache::default();
    model.mlps()[0].density(&params, &x, probes.len(), &mut cache);
    let c = model.config();
    let want: Vec<f32> = cache.raw_density.iter().map(|&r| c.density_activation.forward(r, c.density_bias)).collect();
    assert_eq!(got, want);
    for p in &mut params[..model.field_params()] {
        *p = -*p;
    }
    assert_ne!(model.density_field(&params).densities(&probes, false), got);
}
