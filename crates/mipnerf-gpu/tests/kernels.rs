//! Each kernel run on a real adapter (lavapipe in CI) and compared with the CPU reference.
#![allow(clippy::unwrap_used, missing_docs)]

use glam::Vec3;
use mipnerf_core::mip::{self, Gaussian, RayShape};
use mipnerf_core::rng::{RayRng, Stream};
use mipnerf_core::sampling::sample_along_rays;
use mipnerf_core::{Camera, PixelCenters, Ray};
use mipnerf_gpu::kernels::cast_ipe::CastIpeKernel;
use mipnerf_gpu::test_support::context_or_skip;

/// GPU vs CPU, IPE features. Both sides compute the frustum moments in f32 in the same order; the
/// difference comes from the GPU's `sin`/`exp` and fused multiply-adds. Features are bounded by 1,
/// so an absolute tolerance is the meaningful one. lavapipe measures < 5e-6; Vulkan only promises
/// 2^-11 absolute for `sin` on [-pi, pi], which real GPUs beat by far.
const TOL_GPU_IPE_ABS: f32 = 2e-5;

fn test_rays(n_side: u32) -> Vec<Ray> {
    let c2w = [[0.8, 0.0, 0.6, 2.4], [0.36, 0.8, -0.48, -1.92], [-0.48, 0.6, 0.64, 2.56]];
    let cam = Camera::from_camera_angle_x(n_side, n_side, 0.69, c2w).unwrap();
    cam.generate_rays(PixelCenters::Centered, 2.0, 6.0, 1.0)
}

fn cpu_cast_ipe(rays: &[Ray], t: &[f32], n: usize, shape: RayShape) -> Vec<f32> {
    let len = mip::ipe_len(0, 16);
    let mut out = vec![0.0; rays.len() * n * len];
    let mut gs = vec![Gaussian::default(); n];
    for (r, ray) in rays.iter().enumerate() {
        mip::cast_ray(&t[r * (n + 1)..(r + 1) * (n + 1)], ray.origin, ray.direction, ray.radius, shape, &mut gs);
        for (s, g) in gs.iter().enumerate() {
            mip::integrated_pos_enc(g, 0, 16, &mut out[(r * n + s) * len..(r * n + s + 1) * len]);
        }
    }
    out
}

#[test]
fn cast_ipe_matches_cpu_reference() {
    let Some(ctx) = context_or_skip("cast_ipe_matches_cpu_reference") else {
        return;
    };
    let kernel = CastIpeKernel::new(&ctx).unwrap();
    let rays = test_rays(12);
    let n = 16usize;
    let mut t = vec![0.0; rays.len() * (n + 1)];
    for (r, ray) in rays.iter().enumerate() {
        let rng = RayRng::new(7, 0, Stream::SampleJitter, r as u32);
        sample_along_rays(ray.near, ray.far, false, Some(rng), &mut t[r * (n + 1)..(r + 1) * (n + 1)]);
    }
    for shape in [RayShape::Cone, RayShape::Cylinder] {
        let gpu = kernel.run(&ctx, &rays, &t, n as u32, shape, 0, 16).unwrap();
        let cpu = cpu_cast_ipe(&rays, &t, n, shape);
        assert_eq!(gpu.len(), cpu.len());
        let bad: Vec<String> = gpu
            .iter()
            .zip(&cpu)
            .enumerate()
            .filter(|(_, (g, c))| g.is_nan() || (*g - *c).abs() > TOL_GPU_IPE_ABS)
            .take(20)
            .map(|(i, (g, c))| format!("feature {i}: gpu {g} cpu {c}"))
            .collect();
        let max = gpu.iter().zip(&cpu).map(|(g, c)| (g - c).abs()).fold(0.0f32, f32::max);
        eprintln!("cast_ipe {shape:?} on {}: max |gpu - cpu| = {max:e}", ctx.adapter.name);
        assert!(bad.is_empty(), "{shape:?}: GPU IPE differs from the CPU (max {max:e}):\n{}", bad.join("\n"));
    }
}

#[test]
fn cast_ipe_rejects_inconsistent_sizes() {
    let Some(ctx) = context_or_skip("cast_ipe_rejects_inconsistent_sizes") else {
        return;
    };
    let kernel = CastIpeKernel::new(&ctx).unwrap();
    let rays = vec![Ray { direction: Vec3::NEG_Z, ..Ray::default() }; 2];
    let err = kernel.run(&ctx, &rays, &[2.0, 3.0, 4.0], 2, RayShape::Cone, 0, 16).unwrap_err();
    assert!(err.to_string().contains("3 t values for 2 rays"), "{err}");
}

/// GPU vs CPU, MLP outputs and gradients: products summed in another order (tiles of 16 versus
/// the CPU GEMM's blocking), f32 throughout.
const TOL_GPU_MLP_REL: f32 = 2e-4;
const TOL_GPU_MLP_ABS: f32 = 2e-5;

fn compare(what: &str, gpu: &[f32], cpu: &[f32], rel: f32, abs: f32) -> Vec<String> {
    assert_eq!(gpu.len(), cpu.len(), "{what}: lengths");
    let bad: Vec<String> = gpu
        .iter()
        .zip(cpu)
        .enumerate()
        .filter(|(_, (g, c))| g.is_nan() || (*g - *c).abs() > abs + rel * c.abs())
        .map(|(i, (g, c))| format!("{what}[{i}]: gpu {g:e} cpu {c:e}"))
        .collect();
    bad
}

#[test]
fn mlp_forward_and_backward_match_cpu_reference() {
    use mipnerf_core::mlp::{MlpCache, MlpConfig, MlpShape};
    use mipnerf_gpu::mlp::{GpuMlp, MlpBuffers};
    use rand::{Rng, SeedableRng, rngs::SmallRng};
    let Some(ctx) = context_or_skip("mlp_forward_and_backward_match_cpu_reference") else { return };
    let gpu = GpuMlp::new(&ctx).unwrap();
    let mut bad = Vec::new();
    // Two shapes: a skip concatenation inside the trunk and one before the heads; 1 and 2 colour layers.
    for (ci, cfg) in [
        MlpConfig {
            net_depth: 4,
            net_width: 32,
            skip_layer: 2,
            net_depth_condition: 1,
            net_width_condition: 16,
            x_dim: 24,
            view_dim: 15,
        },
        MlpConfig {
            net_depth: 2,
            net_width: 20,
            skip_layer: 1,
            net_depth_condition: 2,
            net_width_condition: 12,
            x_dim: 30,
            view_dim: 9,
        },
    ]
    .into_iter()
    .enumerate()
    {
        let shape = MlpShape::new(cfg, 0).unwrap();
        let mut rng = SmallRng::seed_from_u64(ci as u64);
        let mut params = vec![0.0; shape.num_params];
        shape.init_glorot(&mut params, 7);
        for l in &shape.layers {
            for b in &mut params[l.bias..l.bias + l.fan_out] {
                *b = rng.random_range(-0.2..0.2);
            }
        }
        let (n_rays, spr) = (5, 7);
        let n = n_rays * spr;
        let x: Vec<f32> = (0..n * cfg.x_dim).map(|_| rng.random_range(-1.0..1.0)).collect();
        let view: Vec<f32> = (0..n_rays * cfg.view_dim).map(|_| rng.random_range(-1.0..1.0)).collect();
        let d_rgb: Vec<f32> = (0..n * 3).map(|_| rng.random_range(-1.0..1.0)).collect();
        let d_density: Vec<f32> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
        // CPU reference.
        let mut cache = MlpCache::default();
        shape.forward(&params, &x, &view, n_rays, spr, &mut cache);
        let mut cpu_grads = vec![0.0; shape.num_params];
        let (cpu_rgb, cpu_density) = (cache.raw_rgb.clone(), cache.raw_density.clone());
        shape.backward(&params, &x, &view, spr, &mut cache, &d_rgb, &d_density, &mut cpu_grads);
        // GPU.
        let bufs = MlpBuffers::new(&ctx, &shape, n_rays, spr);
        ctx.queue.write_buffer(&bufs.x, 0, bytemuck::cast_slice(&x));
        ctx.queue.write_buffer(&bufs.view, 0, bytemuck::cast_slice(&view));
        let p = ctx.storage_buffer("params", &params, true);
        let g = ctx.storage_buffer("grads", &vec![0.0f32; shape.num_params], true);
        let dr = ctx.storage_buffer("d rgb", &d_rgb, false);
        let dd = ctx.storage_buffer("d density", &d_density, false);
        let mut enc = ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("mlp test") });
        gpu.forward(&ctx, &mut enc, &shape, &p, &bufs);
        gpu.backward(&ctx, &mut enc, &shape, &p, &bufs, &dr, &dd, &g);
        ctx.queue.submit([enc.finish()]);
        let rgb = ctx.read_f32(&bufs.raw_rgb, n * 3).unwrap();
        let density = ctx.read_f32(&bufs.raw_density, n).unwrap();
        let grads = ctx.read_f32(&g, shape.num_params).unwrap();
        bad.extend(compare(&format!("shape {ci} raw rgb"), &rgb, &cpu_rgb, TOL_GPU_MLP_REL, TOL_GPU_MLP_ABS));
        bad.extend(compare(
            &format!("shape {ci} raw density"),
            &density,
            &cpu_density,
            TOL_GPU_MLP_REL,
            TOL_GPU_MLP_ABS,
        ));
        bad.extend(compare(&format!("shape {ci} grads"), &grads, &cpu_grads, TOL_GPU_MLP_REL, TOL_GPU_MLP_ABS));
    }
    assert!(
        bad.is_empty(),
        "{} values differ:\n{}",
        bad.len(),
        bad.iter().take(40).cloned().collect::<Vec<_>>().join("\n")
    );
}
