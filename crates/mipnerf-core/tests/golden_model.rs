//! The whole model against the official code: the same parameters in give the same colours,
//! depths and opacities per level, the same losses, and the same gradients
//! (`model_small.json`, from `MipNerfModel.apply` and `train.train_step`).
#![allow(clippy::unwrap_used, missing_docs)]

mod common;
use common::*;
use mipnerf_core::Ray;
use mipnerf_core::model::{GradWith, TrainBatch};
use mipnerf_core::model::{Mode, Model, ModelConfig};
use mipnerf_core::test_support::{Mismatches, f, flat, golden};
use serde_json::Value;

/// Model outputs and losses: sums over samples and layers in a different order than XLA.
const TOL_MODEL: Tol = Tol { rel: 1e-5, abs: 1e-6 };
/// Gradients: sums over the batch in a different order than XLA.
const TOL_GRAD: Tol = Tol { rel: 1e-4, abs: 1e-6 };
/// The official loss sums the squared error over the 3 channels before dividing by sum(lossmult):
/// 3x the per-channel loss that this project reports (see `LossStats::losses`).
const OFFICIAL_LOSS_FACTOR: f32 = 3.0;

fn small_model() -> Model {
    let model = Model::new(ModelConfig {
        num_samples: 8,
        min_deg_point: 0,
        max_deg_point: 4,
        deg_view: 2,
        net_depth: 2,
        net_width: 16,
        net_depth_condition: 1,
        net_width_condition: 8,
        skip_layer: 1,
        ..ModelConfig::default()
    })
    .unwrap();
    // The golden numbers pin the f32 path (bf16 is an opt-in on the CPU, checked in bf16.rs).
    assert_eq!(model.precision(), mipnerf_core::bf16::Precision::F32);
    model
}

/// Writes every `params/MLP_0/Dense_k/{kernel,bias}` entry of `list` into the flat layout.
fn load(model: &Model, list: &Value, flat_params: &mut [f32]) -> usize {
    let mut n = 0;
    for p in list.as_array().unwrap() {
        let path = p["path"].as_str().unwrap();
        let parts: Vec<&str> = path.split('/').collect();
        assert_eq!(parts[1], "MLP_0", "{path}");
        let layer = model.mlps()[0].layers.iter().find(|l| l.name == parts[2]).unwrap_or_else(|| panic!("{path}"));
        let values = flat(&p["values"]);
        let (off, len) = match parts[3] {
            "kernel" => (layer.kernel, layer.fan_in * layer.fan_out),
            "bias" => (layer.bias, layer.fan_out),
            other => panic!("{other}"),
        };
        assert_eq!(values.len(), len, "{path}: shape");
        flat_params[off..off + len].copy_from_slice(&values);
        n += len;
    }
    n
}

fn rays(g: &Value) -> Vec<Ray> {
    let r = &g["rays"];
    (0..2)
        .map(|i| Ray {
            origin: v3(&r["origins"][i]),
            direction: v3(&r["directions"][i]),
            viewdir: v3(&r["viewdirs"][i]),
            radius: f(&r["radii"][i][0]),
            lossmult: f(&r["lossmult"][i][0]),
            near: f(&r["near"][i][0]),
            far: f(&r["far"][i][0]),
        })
        .collect()
}

fn params(model: &Model, g: &Value, perturbed: bool) -> Vec<f32> {
    let mut p = vec![f32::NAN; model.num_params()];
    let mut n = load(model, &g["params"], &mut p);
    if perturbed {
        load(model, &g["bias_perturbed"]["biases"], &mut p);
    }
    n = n.max(p.iter().filter(|x| x.is_finite()).count());
    assert_eq!(n, model.num_params(), "golden parameters do not cover the model");
    p
}

fn check_forward(model: &Model, p: &[f32], rays: &[Ray], want: &Value, what: &str, mm: &mut Mismatches) {
    let out = model.render(p, rays);
    for level in 0..2 {
        let w = &want["levels"][level];
        for r in 0..2 {
            let o = out[r * 2 + level];
            mm.check(&format!("{what} level {level} ray {r} comp_rgb"), &o.rgb, &flat(&w["comp_rgb"][r]), TOL_MODEL);
            mm.check(
                &format!("{what} level {level} ray {r} distance"),
                &[o.distance],
                &[f(&w["distance"][r])],
                TOL_MODEL,
            );
            mm.check(&format!("{what} level {level} ray {r} acc"), &[o.acc], &[f(&w["acc"][r])], TOL_MODEL);
        }
    }
}

#[test]
fn small_model_forward_matches_official() {
    let g = golden("model_small.json");
    let model = small_model();
    assert_eq!(model.num_params(), 24 * 16 + 16 + 16 * 16 + 16 + 40 + 1 + 40 * 16 + 16 + 31 * 8 + 8 + 8 * 3 + 3);
    let rays = rays(&g);
    let mut mm = Mismatches::default();
    check_forward(&model, &params(&model, &g, false), &rays, &g["forward"], "init", &mut mm);
    check_forward(&model, &params(&model, &g, true), &rays, &g["bias_perturbed"]["forward"], "biased", &mut mm);
    mm.finish("small_model_forward_matches_official");
}

fn check_loss_and_grads(
    model: &Model,
    p: &[f32],
    batch: TrainBatch<'_>,
    official: &Value,
    what: &str,
    mm: &mut Mismatches,
) {
    let (stats, grads) = (&official["train_step_stats"], &official["grads"]);
    let mut g = vec![0.0; model.num_params()];
    let s = model.loss_and_grad(p, batch, Mode::Eval, &mut g, GradWith::default());
    let ours: Vec<f32> = s.losses.iter().map(|l| l * OFFICIAL_LOSS_FACTOR).collect();
    mm.check(&format!("{what} losses"), &ours, &flat(&stats["losses"]), TOL_MODEL);
    mm.check(&format!("{what} loss"), &[s.loss * OFFICIAL_LOSS_FACTOR], &[f(&stats["loss"])], TOL_MODEL);
    let scaled: Vec<f32> = g.iter().map(|x| x * OFFICIAL_LOSS_FACTOR).collect();
    let mut want = vec![f32::NAN; model.num_params()];
    load(model, grads, &mut want);
    mm.check(&format!("{what} grads"), &scaled, &want, TOL_GRAD);
    let norm = scaled.iter().map(|x| f64::from(*x).powi(2)).sum::<f64>().sqrt() as f32;
    mm.check(&format!("{what} grad_norm"), &[norm], &[f(&stats["grad_norm"])], TOL_GRAD);
}

#[test]
fn small_model_losses_and_gradients_match_official_train_step() {
    let g = golden("model_small.json");
    let model = small_model();
    let rays = rays(&g);
    let targets: Vec<[f32; 3]> = (0..2).map(|i| v3(&g["loss"]["target_pixels"][i]).to_array()).collect();
    let mut mm = Mismatches::default();
    // At the official initialisation, and with its biases perturbed (so that every bias's
    // gradient is exercised away from zero).
    for (perturbed, golden, label) in [(false, "loss", "init"), (true, "bias_perturbed", "biased")] {
        let batch = TrainBatch { rays: &rays, targets: &targets };
        check_loss_and_grads(&model, &params(&model, &g, perturbed), batch, &g[golden], label, &mut mm);
    }
    // Our per-channel losses are the lossmult-weighted MSE the README of the golden files derives.
    let mut grads = vec![0.0; model.num_params()];
    let s = model.loss_and_grad(
        &params(&model, &g, false),
        TrainBatch { rays: &rays, targets: &targets },
        Mode::Eval,
        &mut grads,
        GradWith::default(),
    );
    for level in 0..2 {
        let d = &g["loss"]["derived_per_level_from_eager_forward"][level];
        mm.check(
            &format!("level {level} weighted mse"),
            &[s.losses[level]],
            &[f(&d["lossmult_weighted_per_channel_mse"])],
            TOL_MODEL,
        );
        mm.check(&format!("level {level} plain mse"), &[s.mse[level]], &[f(&d["plain_per_channel_mse"])], TOL_MODEL);
    }
    mm.finish("small_model_losses_and_gradients_match_official_train_step");
}
