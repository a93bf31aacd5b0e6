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
