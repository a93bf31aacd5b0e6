//! Occupancy-guided sampling's kernel (`occupancy.wgsl`) and the guided model against the CPU's.
//! How every kernel test runs and compares: `tests/common/mod.rs`.
#![allow(clippy::unwrap_used, missing_docs)]

mod common;
use common::*;

/// A grid over [-1.5, 1.5]³ of `r` cells per axis with two separate blobs occupied (so that
/// rays through both have two spans or more), a slab carved, and the warm-up over.
fn two_blob_grid(r: usize) -> mipnerf_core::occupancy::OccupancyGrid {
    use mipnerf_core::occupancy::{CARVED, OccupancyConfig, OccupancyGrid};
    let config = OccupancyConfig { resolution: r, bound: 1.5, ..OccupancyConfig::default() };
    let empty = OccupancyGrid::new(config).unwrap();
    let opacity: Vec<f32> = (0..r * r * r)
        .map(|i| {
            let c = empty.cell_center(i);
            if c.z > 1.2 {
                CARVED
            } else if c.distance(Vec3::new(-0.6, 0.0, 0.0)) < 0.45 || c.distance(Vec3::new(0.6, 0.3, -0.2)) < 0.35 {
                1.0
            } else {
                0.0
            }
        })
        .collect();
    OccupancyGrid::from_state(config, opacity, true).unwrap()
}

/// The CPU's occupied spans of `ray` under `grid`.
fn spans_of(grid: &mipnerf_core::occupancy::OccupancyGrid, ray: &Ray) -> Vec<[f32; 2]> {
    let mut v = Vec::new();
    grid.ray_segments(ray, &mut v);
    v
}

/// `test_rays(n_side)` looking at the origin, repeated with each cone radius scaled by each of
/// `scales`.
fn rays_scaled(n_side: u32, scales: &[f32]) -> Vec<Ray> {
    let rays = test_rays(n_side);
    scales.iter().flat_map(|&k| rays.iter().map(move |r| Ray { radius: r.radius * k, ..*r })).collect()
}

#[test]
fn occupancy_guided_edges_match_cpu_reference() {
    let Some(ctx) = context_or_skip("occupancy_guided_edges_match_cpu_reference") else { return };
    let grid = two_blob_grid(24);
    assert!(!grid.is_full());
    // A 16-pixel camera's cones reach about 2 cells of this grid where they leave it: scaled by
    // 0 (the axis alone), 0.2, 1 and 3, they use every layer (no dilation to the widest).
    guided_edges_match_cpu(&ctx, &grid, &rays_scaled(16, &[0.0, 0.2, 1.0, 3.0]), 24, BOUNDED);
    // With 6 samples the rays with four spans or more join their spans across the narrowest
    // gaps first.
    guided_edges_match_cpu(&ctx, &grid, &rays_scaled(16, &[0.0, 1.0]), 6, BOUNDED);
}

/// The spacings of a bounded scene's sampler.
const BOUNDED: &[Spacing] = &[Spacing::Depth, Spacing::Disparity];

/// An unbounded scene's grid over its contracted space (`OccupancyGrid::contracted_ray_segments`,
/// walked in steps of `s`), its spans shared out in `s`: the test oblique camera moved into the
/// unit ball, its rays out to infinity, under a blob at the centre and a stretch of the far
/// shell (the contracted room), cones from the axis alone to three times a pixel's width.
#[test]
fn occupancy_guided_edges_match_cpu_reference_in_contracted_space() {
    use mipnerf_core::contract::UNBOUNDED_FAR;
    use mipnerf_core::occupancy::{CONTRACTED_BOUND, OccupancyConfig, OccupancyGrid};
    let Some(ctx) = context_or_skip("occupancy_guided_edges_match_cpu_reference_in_contracted_space") else { return };
    let r = 24;
    let config =
        OccupancyConfig { resolution: r, bound: CONTRACTED_BOUND, contracted: true, ..OccupancyConfig::default() };
    let probe = OccupancyGrid::new(config).unwrap();
    let opacity: Vec<f32> = (0..r * r * r)
        .map(|i| {
            let c = probe.cell_center(i);
            let blob = c.length() < 0.35;
            let shell = (1.6..1.9).contains(&c.length()) && c.x > 0.0;
            if blob || shell { 1.0 } else { 0.0 }
        })
        .collect();
    let grid = OccupancyGrid::from_state(config, opacity, true).unwrap();
    let rays: Vec<Ray> = rays_scaled(16, &[0.0, 1.0, 3.0])
        .iter()
        .map(|r| Ray { origin: r.origin * (0.9 / r.origin.length()), near: 0.1, far: UNBOUNDED_FAR, ..*r })
        .collect();
    guided_edges_match_cpu(&ctx, &grid, &rays, 16, &[Spacing::Unbounded]);
    guided_edges_match_cpu(&ctx, &grid, &rays, 4, &[Spacing::Unbounded]);
}

#[test]
fn occupancy_guided_edges_match_cpu_reference_in_ndc() {
    use mipnerf_core::dataset::Split;
    use mipnerf_core::occupancy::{OccupancyConfig, OccupancyGrid, ndc_bound};
    use mipnerf_data::LoadOptions;
    let Some(ctx) = context_or_skip("occupancy_guided_edges_match_cpu_reference_in_ndc") else { return };
    // The forward-facing fixture's rays in NDC space, under a grid over the NDC cube with the
    // near leaves (a slab in depth with holes) and part of the far wall occupied.
    let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/llff_fern_tiny");
    let ds =
        mipnerf_data::load(&dir, Split::Train, &LoadOptions { llff_factor: 64, ..LoadOptions::default() }).unwrap();
    assert!(ds.ndc.is_some());
    let bound = ndc_bound(&ds).unwrap();
    let config = OccupancyConfig { resolution: 32, bound, ..OccupancyConfig::default() };
    let probe = OccupancyGrid::new(config).unwrap();
    let opacity: Vec<f32> = (0..32 * 32 * 32)
        .map(|i| {
            let c = probe.cell_center(i);
            let leaves = (-0.3..0.1).contains(&c.z) && ((c.x * 7.0).sin() * (c.y * 5.0).cos()) > 0.2;
            if leaves || (c.z > 0.8 && c.x < 0.3) { 1.0 } else { 0.0 }
        })
        .collect();
    let grid = OccupancyGrid::from_state(config, opacity, true).unwrap();
    let rays: Vec<Ray> = (0..ds.views().len()).step_by(4).flat_map(|v| ds.view_rays(v)).collect();
    guided_edges_match_cpu(&ctx, &grid, &rays, 16, BOUNDED);
}

/// The occupancy kernel's coarse edges for `rays` under `grid` with `s` samples against the
/// CPU's (`stages::sample_occupied_intervals`), for each of `spacings`, in training and in
/// evaluation: the rays must include some that meet no occupied cell, some with one span and
/// some with several. Unbounded edges are compared in `s` (TOL_GPU_SAMPLE_S_ABS).
fn guided_edges_match_cpu(
    ctx: &mipnerf_gpu::GpuContext,
    grid: &mipnerf_core::occupancy::OccupancyGrid,
    rays: &[Ray],
    s: usize,
    spacings: &[Spacing],
) {
    use mipnerf_core::contract::ray_distance_to_s;
    use mipnerf_gpu::kernels::occupancy::{DeviceGrid, GuidedRays, OccupancyKernel};
    use mipnerf_gpu::model::RayBatch;
    let kernel = OccupancyKernel::new(ctx).unwrap();
    let nr = rays.len();
    let (seed, step) = (5u32, 9u32);
    // Scattered batch indices, as the rays an occupancy grid lets through have.
    let ids: Vec<u32> = (0..nr as u32).map(|r| 40 + 3 * r).collect();
    // The CPU's spans: the test must see rays with none, one, and several.
    let per_ray: Vec<Vec<[f32; 2]>> = rays.iter().map(|r| spans_of(grid, r)).collect();
    let count = |f: &dyn Fn(usize) -> bool| per_ray.iter().filter(|v| f(v.len())).count();
    let (none, one, several) = (count(&|n| n == 0), count(&|n| n == 1), count(&|n| n >= 2));
    eprintln!("{nr} rays: {none} meet no occupied cell, {one} one span, {several} several");
    assert!(none > 0 && one > 0 && several > 0, "the rays must cover every case: {none} / {one} / {several}");
    // The CPU's spans of `rays` as `stages::sample_occupied_intervals` takes them.
    let spans_of_rays = |rays: &[Ray]| {
        let per_ray: Vec<Vec<[f32; 2]>> = rays.iter().map(|r| spans_of(grid, r)).collect();
        let starts: Vec<u32> = std::iter::once(0)
            .chain(per_ray.iter().scan(0u32, |end, v| {
                *end += v.len() as u32;
                Some(*end)
            }))
            .collect();
        (starts, per_ray.concat())
    };
    // A hardware GPU walks the grid with its own rounding (division within 2.5 ulp, fused
    // multiply-adds, the crossings summed over up to a side of the grid): where a ray passes
    // within that of a cell's edge between an empty and an occupied cell, its spans, and so all
    // its edges, may be the CPU's for a ray a few ulps away. Such a ray is admitted when the
    // CPU's own walk jumps there too under the perturbed rays (measured on an NVIDIA H100:
    // edges 6e-2 apart in contracted space, where lavapipe gives the CPU's).
    let moved =
        hardware_perturbations(ctx, 16, HARDWARE_WALK_REL, |n| rays.iter().map(|r| n.ray(r)).collect::<Vec<Ray>>());
    let targets = vec![[0.0f32; 3]; nr];
    let batch = RayBatch::upload(ctx, rays, &targets, 1, false).unwrap();
    let on_device = DeviceGrid::new(ctx, grid).unwrap();
    let mut bad = Vec::new();
    let cases = spacings.iter().flat_map(|&spacing| [(spacing, false), (spacing, true)]);
    for (spacing, randomized) in cases {
        let mode = mode_of(randomized, seed, step);
        let how = stages::Sample { n_samples: s, spacing, mode };
        let unbounded = spacing == Spacing::Unbounded;
        let in_s = |t: Vec<f32>| if unbounded { t.into_iter().map(ray_distance_to_s).collect() } else { t };
        let cpu = |rays: &[Ray]| -> Outputs {
            let mut t = vec![0.0f32; nr * (s + 1)];
            let (starts, spans) = spans_of_rays(rays);
            stages::sample_occupied_intervals(rays, (&starts, &spans), how, &ids, &mut t);
            vec![("edges", in_s(t))]
        };
        let on_gpu = |_: &[Ray]| -> Result<Outputs, GpuError> {
            let t_out = ctx.storage_buffer("t coarse", &vec![f32::NAN; nr * (s + 1)], true);
            let mut rec = Recorder::new(ctx, "occupancy test");
            let b_ids = ctx.storage_buffer("ray ids", &ids, false);
            let rays = GuidedRays { rays: &batch.rays, bounds: &batch.bounds, ray_ids: &b_ids };
            kernel.sample(&mut rec, nr, how, &on_device, rays, &t_out)?;
            let _ = rec.submit();
            Ok(vec![("edges", in_s(ctx.read_f32(&t_out, nr * (s + 1))?))])
        };
        let label = format!("{spacing:?} randomized {randomized}");
        let tol = |_: &str| {
            if unbounded { Tolerance::abs(TOL_GPU_SAMPLE_S_ABS) } else { Tolerance::new(1e-6, TOL_GPU_SAMPLE_REL) }
        };
        bad.extend(check_kernel_conditioned(&label, cpu, on_gpu, (rays, &moved, SPREAD_FACTOR), tol).into_mismatches());
    }
    assert_none(&bad);
}

/// The relative size of the ray changes that stand for a hardware GPU's rounding in a grid walk:
/// 2^-17, 64 ulps, the walk adding up to a side of the grid's crossings (`HARDWARE_ROUNDING_REL`
/// for one computed value).
const HARDWARE_WALK_REL: f32 = 1.0 / 131_072.0;

#[test]
fn occupancy_guided_model_matches_cpu_reference() {
    use mipnerf_core::model::{GradScratch, Model, ModelConfig, Preset};
    use mipnerf_core::occupancy::{OccupancyConfig, OccupancyGrid};
    use mipnerf_gpu::model::{GpuModel, KernelSet};
    let Some(ctx) = context_or_skip("occupancy_guided_model_matches_cpu_reference") else { return };
    let rays = rays_scaled(8, &[0.3, 1.0]);
    let targets: Vec<[f32; 3]> = (0..rays.len()).map(|i| [(i % 7) as f32 / 7.0, 0.4, (i % 3) as f32 / 3.0]).collect();
    let grid = two_blob_grid(16);
    let model = Model::new(ModelConfig { num_samples: 16, ..Preset::Tiny.config() }).unwrap();
    // Random backgrounds too: the empty rays' loss is against their own pixels' colours.
    let random = Model::new(ModelConfig { random_bkgd: true, ..model.config().clone() }).unwrap();
    let params = model.init_params(11);
    let active = rays.iter().filter(|r| !spans_of(&grid, r).is_empty()).count();
    assert!(0 < active && active < rays.len(), "{active} of {} rays meet occupied cells", rays.len());
    let mut bad = Vec::new();
    for set in [KernelSet::Software, KernelSet::Hardware] {
        let gpu = GpuModel::with_kernel_set(&ctx, set).unwrap();
        for (model, mode) in [
            (&model, Mode::Train { seed: 3, step: 7 }),
            (&model, Mode::Eval),
            (&random, Mode::Train { seed: 3, step: 7 }),
        ] {
            let mut cpu_grads = vec![0.0; model.num_params()];
            let mut scratch = GradScratch::default();
            let cpu = model.loss_and_grad(
                &params,
                TrainBatch { rays: &rays, targets: &targets },
                mode,
                &mut cpu_grads,
                GradWith { scratch: Some(&mut scratch), grid: Some(&grid) },
            );
            let scale = cpu_grads.iter().fold(0.0f32, |m, g| m.max(g.abs()));
            let tag = format!("{set:?} {mode:?} random background {}", model.config().random_bkgd);
            let check = check_kernel(
                &tag,
                |_: &()| vec![("losses", cpu.losses.clone()), ("grads", cpu_grads.clone())],
                |_| {
                    let before = ctx.counters().model_rays;
                    let (stats, grads) = gpu.loss_and_grad(
                        &ctx,
                        model,
                        &params,
                        TrainBatch { rays: &rays, targets: &targets },
                        mode,
                        Some(&grid),
                    )?;
                    // Only the rays that meet an occupied cell ran through the model, as on the CPU.
                    assert_eq!(ctx.counters().model_rays - before, active as u64, "{set:?} {mode:?}: rays run");
                    Ok::<_, GpuError>(vec![("losses", stats.losses), ("grads", grads)])
                },
                &(),
                model_tolerance(scale),
            );
            bad.extend(check.into_mismatches());
        }
        // A full grid (the warm-up's) records exactly the paper's sampler: bit for bit.
        let full =
            OccupancyGrid::new(OccupancyConfig { resolution: 16, bound: 1.5, ..OccupancyConfig::default() }).unwrap();
        assert!(full.is_full());
        let mode = Mode::Train { seed: 3, step: 7 };
        let plain = gpu
            .loss_and_grad(&ctx, &model, &params, TrainBatch { rays: &rays, targets: &targets }, mode, None)
            .unwrap();
        let guided = gpu
            .loss_and_grad(&ctx, &model, &params, TrainBatch { rays: &rays, targets: &targets }, mode, Some(&full))
            .unwrap();
        assert_eq!(plain.1, guided.1, "{set:?}: a full grid changes the GPU's gradient");
        assert_eq!(plain.0.losses, guided.0.losses, "{set:?}: a full grid changes the GPU's losses");
    }
    assert_none(&bad);
}
