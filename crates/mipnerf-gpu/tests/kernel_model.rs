//! The whole model's pass on the device against `Model::loss_and_grad`, and a missing adapter as an error.
//! How every kernel test runs and compares: `tests/common/mod.rs`.
#![allow(clippy::unwrap_used, missing_docs)]

mod common;
use common::*;

#[test]
fn a_missing_hardware_gpu_is_an_error_not_a_panic() {
    use mipnerf_gpu::{AdapterChoice, GpuContext};
    match GpuContext::new(AdapterChoice::HardwareOnly) {
        Ok(ctx) => assert!(!ctx.adapter().is_software, "HardwareOnly returned {}", ctx.adapter().name),
        Err(e) => {
            let GpuError::NoAdapter { passed_over, .. } = &e else { panic!("{e:?}") };
            // Every adapter wgpu saw is listed with why it was passed over.
            assert_eq!(passed_over.len(), mipnerf_gpu::list_adapters().len(), "{e:?}");
            let msg = e.to_string();
            assert!(
                msg.contains("no GPU adapter found for a hardware GPU") && msg.contains("`BackendChoice::Cpu`"),
                "{msg}"
            );
            for a in mipnerf_gpu::list_adapters() {
                assert!(msg.contains(&a.name) && msg.contains("a software adapter"), "{a:?} not in: {msg}");
            }
        }
    }
}

#[test]
fn whole_model_loss_and_gradients_match_cpu_reference() {
    use mipnerf_core::model::{Model, ModelConfig, Preset};
    use mipnerf_gpu::model::{GpuModel, KernelSet};
    let Some(ctx) = context_or_skip("whole_model_loss_and_gradients_match_cpu_reference") else { return };
    let rays = test_rays(8);
    let targets: Vec<[f32; 3]> = (0..rays.len()).map(|i| [(i % 7) as f32 / 7.0, 0.4, (i % 3) as f32 / 3.0]).collect();
    let mut bad = Vec::new();
    let tiny = ModelConfig { num_samples: 16, ..Preset::Tiny.config() };
    // Both kernel sets, whatever the adapter would pick: the hardware set runs on lavapipe too.
    for set in [KernelSet::Software, KernelSet::Hardware] {
        let gpu = GpuModel::with_kernel_set(&ctx, set).unwrap();
        for (ci, (cfg, mode)) in [
            (tiny.clone(), Mode::Train { seed: 3, step: 7 }),
            (ModelConfig { point_encoding: PointEncoding::Mean, ..tiny.clone() }.without_misc(), Mode::Eval),
            // The NeRF baseline: positional encoding with the identity, one MLP per level.
            (tiny.clone().nerf(), Mode::Train { seed: 1, step: 2 }),
            // Noise on raw density in training (the same random numbers on both sides).
            (ModelConfig { density_noise: 1.0, ..tiny.clone() }, Mode::Train { seed: 4, step: 9 }),
            // The noise part-way through its fade (0.55 of it at step 9 of 20).
            (
                ModelConfig { density_noise: 1.0, density_noise_steps: 20, ..tiny.clone() },
                Mode::Train { seed: 4, step: 9 },
            ),
            // The supersampled NeRF: 2x2 rays per pixel, the loss on their mean.
            (ModelConfig { supersample: 2, ..tiny.clone().nerf() }, Mode::Train { seed: 6, step: 1 }),
            // Random backgrounds (one colour per pixel of the batch), per ray and supersampled.
            (ModelConfig { random_bkgd: true, ..tiny.clone() }, Mode::Train { seed: 8, step: 4 }),
            (
                ModelConfig { random_bkgd: true, supersample: 2, ..tiny.clone().nerf() },
                Mode::Train { seed: 2, step: 3 },
            ),
        ]
        .into_iter()
        .enumerate()
        {
            let model = Model::new(cfg).unwrap();
            let params = model.init_params(11);
            // k x k rays per pixel of the same camera for a supersampled model.
            let k = model.config().supersample;
            let rays: Vec<Ray> = if k > 1 {
                let cam = demo::oblique_camera(8);
                let mut out = Vec::new();
                for p in 0..64u32 {
                    let (x, y) = (p % 8, p / 8);
                    let spec = mipnerf_core::dataset::RaySpec {
                        centers: PixelCenters::Centered,
                        bounds: (2.0, 6.0),
                        lossmult: 1.0,
                        ndc: None,
                    };
                    mipnerf_core::dataset::push_camera_rays(&cam, x, y, spec, k, &mut out);
                }
                out
            } else {
                rays.clone()
            };
            let mut cpu_grads = vec![0.0; model.num_params()];
            let cpu = model.loss_and_grad(
                &params,
                TrainBatch { rays: &rays, targets: &targets },
                mode,
                &mut cpu_grads,
                GradWith::default(),
            );
            if model.config().density_noise > 0.0 {
                // The case is only meaningful if the noise moves the loss well beyond the tolerance.
                let quiet = Model::new(ModelConfig { density_noise: 0.0, ..model.config().clone() }).unwrap();
                let plain = quiet.loss_and_grad(
                    &params,
                    TrainBatch { rays: &rays, targets: &targets },
                    mode,
                    &mut vec![0.0; model.num_params()],
                    GradWith::default(),
                );
                assert!((plain.loss - cpu.loss).abs() > 20.0 * TOL_GPU_MODEL_REL * cpu.loss, "noise changes nothing");
            }
            let scale = cpu_grads.iter().fold(0.0f32, |m, g| m.max(g.abs()));
            // The encodings without the IPE's damping (the NeRF baseline's, the means') take sines
            // of 2^15 x undamped: an ulp of a position moves them by 4e-3, so on a hardware GPU
            // the gradients follow the CPU's only as closely as the CPU follows itself when the
            // rays move by a rounding.
            let moved = hardware_perturbations(&ctx, 8, HARDWARE_ROUNDING_REL, |n| {
                rays.iter().map(|r| n.ray(r)).collect::<Vec<Ray>>()
            });
            let check = check_kernel_conditioned(
                &format!("{set:?} case {ci}"),
                |rays: &[Ray]| {
                    let mut g = vec![0.0; model.num_params()];
                    let out = model.loss_and_grad(
                        &params,
                        TrainBatch { rays, targets: &targets },
                        mode,
                        &mut g,
                        GradWith::default(),
                    );
                    vec![("losses", out.losses), ("mse", out.mse), ("grads", g)]
                },
                |rays| {
                    let (stats, grads) =
                        gpu.loss_and_grad(&ctx, &model, &params, TrainBatch { rays, targets: &targets }, mode, None)?;
                    Ok::<_, GpuError>(vec![("losses", stats.losses), ("mse", stats.mse), ("grads", grads)])
                },
                (&rays[..], &moved, SPREAD_FACTOR),
                model_tolerance(scale),
            );
            bad.extend(check.into_mismatches());
        }
    }
    assert_none(&bad);
}
