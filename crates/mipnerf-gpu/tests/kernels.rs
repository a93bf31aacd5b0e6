//! Each kernel run on a real adapter (lavapipe in CI) and compared with its CPU reference in
//! `mipnerf_core::stages` (or the MLP's `MlpShape::forward`/`backward`, or the whole `Model`)
//! through one check, `mipnerf_core::compare::check_kernel`.
#![allow(clippy::unwrap_used, missing_docs)]

use glam::Vec3;
use mipnerf_core::bf16::Precision;
use mipnerf_core::compare::{Outputs, Tolerance, assert_none, check_kernel, check_kernel_conditioned, mismatches};
use mipnerf_core::contract::UNBOUNDED_FAR;
use mipnerf_core::data::demo;
use mipnerf_core::mip::{self, ipe_len};
use mipnerf_core::model::{GradWith, TrainBatch};
use mipnerf_core::model::{Mode, PointEncoding};
use mipnerf_core::sampling::Spacing;
use mipnerf_core::{PixelCenters, Ray, RayShape, stages};
use mipnerf_gpu::GpuError;
use mipnerf_gpu::kernels::Recorder;
use mipnerf_gpu::kernels::cast_ipe::CastIpeKernel;
use mipnerf_gpu::test_support::{
    HARDWARE_ROUNDING_REL, context_or_skip, contexts_of_each_atomics, hardware_perturbations,
};

/// How far past the CPU reference's own spread under perturbed inputs a hardware GPU may land
/// (`check_kernel_conditioned`): twice it, the perturbations being a sample.
const SPREAD_FACTOR: f32 = 2.0;

/// GPU vs CPU, IPE features. Both sides compute the frustum moments in f32 in the same order; the
/// difference comes from the GPU's `sin`/`exp` and fused multiply-adds. Features are bounded by 1,
/// so an absolute tolerance is the meaningful one. lavapipe measures < 5e-6.
const TOL_GPU_IPE_ABS: f32 = 2e-5;

/// WGSL's bound on the absolute error of `sin` on [-pi, pi] (the spec's accuracy table), which a
/// hardware driver may use (real GPUs do far better: NVIDIA's approximate sine is within 2^-20.9
/// there). The kernels reduce every argument to [-pi, pi] first, without relying on fused
/// multiply-adds, so this is the whole of a vendor's latitude on a sine feature.
const WGSL_SIN_ABS: f32 = 1.0 / 2048.0;

/// The tolerance of a feature computed with one `sin` on `ctx`: what lavapipe measures plus, on
/// a hardware adapter, the spec's bound.
fn sin_feature_tolerance(ctx: &mipnerf_gpu::GpuContext) -> f32 {
    if ctx.adapter().is_software { TOL_GPU_IPE_ABS } else { TOL_GPU_IPE_ABS + WGSL_SIN_ABS }
}

/// The rays of the demo's oblique camera at `n_side` x `n_side` pixels, bounds 2 to 6.
fn test_rays(n_side: u32) -> Vec<Ray> {
    demo::oblique_camera(n_side).generate_rays(PixelCenters::Centered, 2.0, 6.0, 1.0)
}

/// A mode that draws random numbers (training, `seed` and `step`) when `randomized`, else
/// evaluation.
fn mode_of(randomized: bool, seed: u32, step: u32) -> Mode {
    if randomized { Mode::Train { seed, step } } else { Mode::Eval }
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
    let ids: Vec<u32> = (0..rays.len() as u32).collect();
    let mode = Mode::Train { seed: 7, step: 0 };
    stages::sample_intervals(&rays, n, Spacing::Depth, mode, &ids, &mut t);
    // An unbounded scene: the same camera moved into the unit ball, edges out to infinity, so
    // that each ray has Gaussians inside the ball (unchanged) and outside it (contracted).
    let inside: Vec<Ray> = rays
        .iter()
        .map(|r| Ray { origin: r.origin * (0.9 / r.origin.length()), near: 0.1, far: UNBOUNDED_FAR, ..*r })
        .collect();
    let mut t_inside = vec![0.0; rays.len() * (n + 1)];
    stages::sample_intervals(&inside, n, Spacing::Unbounded, mode, &ids, &mut t_inside);
    let degrees = (0, 16);
    let mut bad = Vec::new();
    // Unbounded scenes cast cones only (`Model::new` refuses cylinders there).
    for (shape, unbounded) in [(RayShape::Cone, false), (RayShape::Cylinder, false), (RayShape::Cone, true)] {
        let input = if unbounded { (&inside[..], &t_inside[..]) } else { (&rays[..], &t[..]) };
        let (min_deg, max_deg) = degrees;
        let stage =
            stages::CastIpe { n_samples: n, shape, unbounded, encoding: PointEncoding::Integrated, min_deg, max_deg };
        let check = check_kernel(
            &format!("cast_ipe {shape:?} unbounded {unbounded} on {}", ctx.adapter().name),
            |(rays, t): &(&[Ray], &[f32])| {
                let mut x = vec![0.0; rays.len() * n * ipe_len(degrees.0, degrees.1)];
                stages::cast_and_encode(rays, t, stage, Precision::F32, &mut x);
                vec![("features", x)]
            },
            |(rays, t)| kernel.run(&ctx, rays, t, stage).map(|x| vec![("features", x)]),
            &input,
            |_| Tolerance::abs(sin_feature_tolerance(&ctx)),
        );
        bad.extend(check.into_mismatches());
    }
    assert_none(&bad);
}

#[test]
fn cast_ipe_rejects_inconsistent_sizes() {
    let Some(ctx) = context_or_skip("cast_ipe_rejects_inconsistent_sizes") else {
        return;
    };
    let kernel = CastIpeKernel::new(&ctx).unwrap();
    let rays = vec![Ray { direction: Vec3::NEG_Z, ..Ray::default() }; 2];
    let stage = mipnerf_core::stages::CastIpe {
        n_samples: 2,
        shape: RayShape::Cone,
        unbounded: false,
        encoding: PointEncoding::Integrated,
        min_deg: 0,
        max_deg: 16,
    };
    let err = kernel.run(&ctx, &rays, &[2.0, 3.0, 4.0], stage).unwrap_err();
    assert!(err.to_string().contains("3 t values for 2 rays"), "{err}");
}

/// GPU vs CPU, MLP outputs and gradients: products summed in another order (the GPU's tiles and
/// splits versus the CPU GEMM's blocking), f32 throughout. WGSL rounds `+` and `*` correctly on
/// every vendor; only the summation order and fused multiply-adds differ, so this holds on
/// hardware as on lavapipe.
const TOL_GPU_MLP_REL: f32 = 2e-4;
const TOL_GPU_MLP_ABS: f32 = 2e-5;

/// The inputs of one MLP pass: parameters, point features, view features, and the gradients of
/// the raw outputs.
struct MlpCase {
    params: Vec<f32>,
    x: Vec<f32>,
    view: Vec<f32>,
    d_rgb: Vec<f32>,
    d_density: Vec<f32>,
    n_rays: usize,
    samples_per_ray: usize,
}

impl MlpCase {
    /// Random inputs and output gradients for `params` of a shape with `cfg`.
    fn random(
        params: Vec<f32>,
        cfg: &mipnerf_core::mlp::MlpConfig,
        n_rays: usize,
        spr: usize,
        rng: &mut rand::rngs::SmallRng,
    ) -> Self {
        use rand::Rng;
        let n = n_rays * spr;
        Self {
            params,
            x: (0..n * cfg.x_dim).map(|_| rng.random_range(-1.0..1.0)).collect(),
            view: (0..n_rays * cfg.view_dim).map(|_| rng.random_range(-1.0..1.0)).collect(),
            d_rgb: (0..n * 3).map(|_| rng.random_range(-1.0..1.0)).collect(),
            d_density: (0..n).map(|_| rng.random_range(-1.0..1.0)).collect(),
            n_rays,
            samples_per_ray: spr,
        }
    }
}

/// The CPU MLP's raw outputs and parameter gradients for `c` (and the encodings' gradient with
/// `input_gradient`).
fn mlp_on_cpu(shape: &mipnerf_core::mlp::MlpShape, c: &MlpCase, input_gradient: bool) -> Outputs {
    let mut cache = mipnerf_core::mlp::MlpCache::default();
    shape.forward(&c.params, &c.x, &c.view, c.n_rays, c.samples_per_ray, &mut cache);
    let (rgb, density) = (cache.raw_rgb.clone(), cache.raw_density.clone());
    let mut grads = vec![0.0; c.params.len()];
    shape.backward(
        &c.params,
        mipnerf_core::mlp::MlpInputs { x: &c.x, view: &c.view, samples_per_ray: c.samples_per_ray },
        &mut cache,
        mipnerf_core::mlp::OutputGradients { rgb: &c.d_rgb, density: &c.d_density },
        &mut grads,
    );
    let mut out = vec![("raw rgb", rgb), ("raw density", density), ("grads", grads)];
    if input_gradient {
        let mut d_x = vec![0.0; c.x.len()];
        shape.input_gradient(&c.params, &cache, &mut d_x);
        out.push(("d_x", d_x));
    }
    out
}

/// The same on the device, through [`GpuMlp`](mipnerf_gpu::mlp::GpuMlp) (the product kernels or
/// the fused ones, as the shape decides).
fn mlp_on_gpu(
    ctx: &mipnerf_gpu::GpuContext,
    gpu: &mipnerf_gpu::mlp::GpuMlp,
    shape: &mipnerf_core::mlp::MlpShape,
    c: &MlpCase,
    input_gradient: bool,
) -> Result<Outputs, GpuError> {
    use mipnerf_gpu::mlp::MlpBuffers;
    let n = c.n_rays * c.samples_per_ray;
    let mut bufs = MlpBuffers::new(ctx, shape, c.n_rays, c.samples_per_ray);
    if input_gradient {
        bufs = bufs.with_input_gradient(ctx, shape.config.x_dim);
    }
    ctx.queue().write_buffer(&bufs.x, 0, bytemuck::cast_slice(&c.x));
    ctx.queue().write_buffer(&bufs.view, 0, bytemuck::cast_slice(&c.view));
    let p = ctx.storage_buffer("params", &c.params, true);
    let g = ctx.storage_buffer("grads", &vec![0.0f32; c.params.len()], true);
    let dr = ctx.storage_buffer("d rgb", &c.d_rgb, false);
    // The density gradient goes where rendering writes it: column 0 of the heads' gradient
    // (the other columns stay NaN: the backward pass must write them first).
    let (dd, stride) = bufs.d_raw_density();
    let mut strided = vec![f32::NAN; n * stride];
    for (k, v) in c.d_density.iter().enumerate() {
        strided[k * stride] = *v;
    }
    ctx.queue().write_buffer(dd, 0, bytemuck::cast_slice(&strided));
    let mut rec = Recorder::new(ctx, "mlp test");
    gpu.forward(&mut rec, shape, &p, &bufs);
    gpu.backward(&mut rec, shape, &p, &bufs, &dr, &g)?;
    let _ = rec.submit();
    let (heads, stride) = bufs.raw_density();
    let density = ctx.read_f32(heads, n * stride)?.iter().step_by(stride).copied().collect();
    let mut out = vec![
        ("raw rgb", ctx.read_f32(&bufs.raw_rgb, n * 3)?),
        ("raw density", density),
        ("grads", ctx.read_f32(&g, c.params.len())?),
    ];
    if let Some(d_x) = &bufs.d_x {
        out.push(("d_x", ctx.read_f32(d_x, n * shape.config.x_dim)?));
    }
    Ok(out)
}

/// The fused small MLP (`fused_mlp.wgsl`: shapes with no skip connection, at most 64 wide)
/// against the CPU MLP, the encodings' gradient included: the Tri-Mip recipe's shape, and a
/// deeper, narrower one whose colour branch has two layers and whose 1,073 samples (37 x 29)
/// make the weight gradients add three runs of samples, the last one short.
#[test]
fn fused_mlp_forward_and_backward_match_cpu_reference() {
    use mipnerf_core::mlp::{MlpConfig, MlpShape};
    use mipnerf_gpu::mlp::{GpuMlp, MlpBuffers};
    use rand::{Rng, SeedableRng, rngs::SmallRng};
    let recipe = MlpConfig {
        net_depth: 2,
        net_width: 64,
        skip_layer: 0,
        net_depth_condition: 1,
        net_width_condition: 64,
        x_dim: 48,
        view_dim: 27,
    };
    let deeper = MlpConfig {
        net_depth: 3,
        net_width: 20,
        skip_layer: 0,
        net_depth_condition: 2,
        net_width_condition: 12,
        x_dim: 30,
        view_dim: 9,
    };
    let mut bad = Vec::new();
    for (atomics, ctx) in contexts_of_each_atomics("fused_mlp_forward_and_backward_match_cpu_reference") {
        let gpu = GpuMlp::new(&ctx).unwrap();
        for (ci, (cfg, n_rays, spr, base)) in [(recipe, 16, 16, 0), (deeper, 37, 29, 1000)].into_iter().enumerate() {
            // A shape at an offset in the parameters, as a field's MLP after the planes.
            let shape = MlpShape::new(cfg, base).unwrap();
            assert!(MlpBuffers::runs_fused(&shape), "shape {ci} runs fused");
            let mut rng = SmallRng::seed_from_u64(ci as u64);
            let mut params = vec![0.0; base + shape.num_params];
            shape.init_glorot(&mut params, 7);
            for l in &shape.layers {
                for b in &mut params[l.bias..l.bias + l.fan_out] {
                    *b = rng.random_range(-0.2..0.2);
                }
            }
            let case = MlpCase::random(params, &cfg, n_rays, spr, &mut rng);
            let cpu = |c: &MlpCase| mlp_on_cpu(&shape, c, true);
            let on_gpu = |c: &MlpCase| mlp_on_gpu(&ctx, &gpu, &shape, c, true);
            let tol = |_: &str| Tolerance::new(TOL_GPU_MLP_ABS, TOL_GPU_MLP_REL);
            let label = format!("fused shape {ci}, {atomics:?}");
            bad.extend(check_kernel(&label, cpu, on_gpu, &case, tol).into_mismatches());
        }
    }
    assert_none(&bad);
}

/// Fails with every mismatch `compare` reported (the first 40 listed).
#[test]
fn mlp_forward_and_backward_match_cpu_reference() {
    use mipnerf_core::mlp::{MlpConfig, MlpShape};
    use mipnerf_gpu::kernels::matmul::{MatmulKernel, MatmulVariant};
    use mipnerf_gpu::mlp::GpuMlp;
    use rand::{Rng, SeedableRng, rngs::SmallRng};
    let Some(ctx) = context_or_skip("mlp_forward_and_backward_match_cpu_reference") else { return };
    let mut bad = Vec::new();
    // Both matrix-product kernels, whatever the adapter would pick.
    for variant in [MatmulVariant::Tiled, MatmulVariant::Blocked] {
        let gpu = GpuMlp::with_variant(&ctx, variant).unwrap();
        // Two shapes: a skip concatenation inside the trunk and one before the heads; 1 and 2
        // colour layers. The first again with enough samples (2257) that the weight gradients
        // split over k (several partial products, the last one short).
        let inside = MlpConfig {
            net_depth: 4,
            net_width: 32,
            skip_layer: 2,
            net_depth_condition: 1,
            net_width_condition: 16,
            x_dim: 24,
            view_dim: 15,
        };
        let before_heads = MlpConfig {
            net_depth: 2,
            net_width: 20,
            skip_layer: 1,
            net_depth_condition: 2,
            net_width_condition: 12,
            x_dim: 30,
            view_dim: 9,
        };
        for (ci, cfg) in [inside, before_heads, inside].into_iter().enumerate() {
            let shape = MlpShape::new(cfg, 0).unwrap();
            let mut rng = SmallRng::seed_from_u64(ci as u64);
            let mut params = vec![0.0; shape.num_params];
            shape.init_glorot(&mut params, 7);
            for l in &shape.layers {
                for b in &mut params[l.bias..l.bias + l.fan_out] {
                    *b = rng.random_range(-0.2..0.2);
                }
            }
            let (n_rays, spr) = if ci == 2 { (37, 61) } else { (5, 7) };
            let n = n_rays * spr;
            if ci == 2 {
                let plan = MatmulKernel::with_variant(&ctx, variant)
                    .unwrap()
                    .split_plan((cfg.net_width, n, cfg.net_width), usize::MAX);
                assert!(plan.splits > 1 && n % plan.k_chunk != 0, "{variant:?}: {plan:?} does not exercise the split");
            }
            let case = MlpCase::random(params, &cfg, n_rays, spr, &mut rng);
            let cpu = |c: &MlpCase| mlp_on_cpu(&shape, c, false);
            let on_gpu = |c: &MlpCase| mlp_on_gpu(&ctx, &gpu, &shape, c, false);
            let tol = |_: &str| Tolerance::new(TOL_GPU_MLP_ABS, TOL_GPU_MLP_REL);
            bad.extend(check_kernel(&format!("{variant:?} shape {ci}"), cpu, on_gpu, &case, tol).into_mismatches());
        }
    }
    assert_none(&bad);
}

/// GPU vs CPU, rendering and its gradients: sums over samples in the same order (grouped by
/// block in the wide variant), but GPU `exp`/`log` differ from libm. WGSL bounds `exp(x)` to
/// 3 + 2|x| ulp and `log` to 3 ulp (2^-21 absolute near 1); the arguments here stay below ~20, so
/// a driver at the bound is within ~50 ulp (6e-6 relative), inside this tolerance.
const TOL_GPU_RENDER_REL: f32 = 1e-4;
const TOL_GPU_RENDER_ABS: f32 = 1e-6;

/// The inputs of `render.wgsl`: the MLP's raw outputs, the edges, the rays (direction and
/// `lossmult`), their batch indices and backgrounds, and each ray's target colour.
struct RenderCase {
    raw_rgb: Vec<f32>,
    raw_density: Vec<f32>,
    t: Vec<f32>,
    rays: Vec<Ray>,
    ids: Vec<u32>,
    backgrounds: Vec<[f32; 3]>,
    targets: Vec<[f32; 3]>,
}

#[test]
fn render_forward_loss_and_backward_match_cpu_reference() {
    use mipnerf_core::model::{ModelConfig, pixel_loss_gradient};
    use mipnerf_core::render::{self, DensityActivation, RenderedRay};
    use mipnerf_gpu::kernels::render::{
        BACKGROUND_BLACK, BACKGROUND_RANDOM, BACKGROUND_WHITE, RenderInputs, RenderKernel, RenderParams, RenderVariant,
    };
    use rand::{Rng, SeedableRng, rngs::SmallRng};
    let Some(ctx) = context_or_skip("render_forward_loss_and_backward_match_cpu_reference") else { return };
    let mut bad = Vec::new();
    // Both entry points, whatever the adapter would pick; 12 samples (fewer than the wide
    // kernel's 32 lanes: empty blocks) and 75 (blocks of 3, the last lanes short or empty).
    // Backgrounds: white, black, and (training) each ray's random colour from the stream that
    // `rng::random_background` draws with the ray's batch index: scattered indices, as the rays an
    // occupancy grid lets through have.
    let (seed, step) = (77u32, 5u32);
    for (variant, (ci, (act, bg, area, samples))) in
        [RenderVariant::PerRay, RenderVariant::Wide].into_iter().flat_map(|v| {
            [
                (DensityActivation::Softplus, BACKGROUND_WHITE, true, 12),
                (DensityActivation::Relu, BACKGROUND_BLACK, false, 75),
                (DensityActivation::Softplus, BACKGROUND_RANDOM, true, 40),
            ]
            .into_iter()
            .enumerate()
            .map(move |c| (v, c))
        })
    {
        let kernel = RenderKernel::with_variant(&ctx, variant).unwrap();
        let cfg = ModelConfig {
            num_samples: samples,
            density_activation: act,
            density_bias: if act == DensityActivation::Softplus { -1.0 } else { 0.0 },
            white_bkgd: bg == BACKGROUND_WHITE,
            random_bkgd: bg == BACKGROUND_RANDOM,
            area_loss: area,
            ..ModelConfig::default()
        };
        let (nr, s) = (9usize, cfg.num_samples);
        let n = nr * s;
        let mut rng = SmallRng::seed_from_u64(ci as u64 + 10);
        let ids: Vec<u32> = (0..nr as u32).map(|r| 1000 + 3 * r).collect();
        let mut t = Vec::new();
        for _ in 0..nr {
            let mut edges: Vec<f32> = (0..=s).map(|_| rng.random_range(2.0..6.0)).collect();
            edges.sort_by(f32::total_cmp);
            t.extend(edges);
        }
        let case = RenderCase {
            // Raw densities away from ReLU's kink.
            raw_density: (0..n)
                .map(|_| rng.random_range(0.2..4.0) * if rng.random::<bool>() { 1.0 } else { -1.0 })
                .collect(),
            raw_rgb: (0..n * 3).map(|_| rng.random_range(-3.0..3.0)).collect(),
            t,
            rays: (0..nr)
                .map(|_| Ray {
                    origin: Vec3::new(0.0, -4.0, 0.5),
                    radius: 0.001,
                    direction: Vec3::new(rng.random_range(-0.3..0.3), 1.0, rng.random_range(-0.3..0.3)),
                    lossmult: [1.0, 4.0, 16.0][rng.random_range(0..3)],
                    ..Ray::default()
                })
                .collect(),
            backgrounds: ids
                .iter()
                .map(|&id| match bg {
                    BACKGROUND_RANDOM => mipnerf_core::rng::random_background(seed, step, id),
                    _ => render::background(cfg.white_bkgd),
                })
                .collect(),
            ids,
            targets: (0..nr).map(|_| [rng.random(), rng.random(), rng.random()]).collect(),
        };
        let lossmult = |ray: &Ray| if area { ray.lossmult } else { 1.0 };
        let norm = 3.0 * case.rays.iter().map(lossmult).sum::<f32>();
        let level_weight = 0.1;
        let cpu = |c: &RenderCase| -> Outputs {
            let mut samples = stages::RenderedSamples::default();
            let mut per_ray = vec![RenderedRay::default(); nr];
            let raw = stages::RawOutputs { rgb: &c.raw_rgb, density: &c.raw_density };
            let level = stages::LevelRays { t: &c.t, rays: &c.rays, backgrounds: &c.backgrounds };
            stages::render_rays(&cfg, raw, level, &mut samples, &mut per_ray);
            // Per ray: colour, distance, opacity, the area-weighted and the plain squared error.
            let mut out = Vec::new();
            let mut d_ray_rgb = Vec::new();
            for ((o, target), ray) in per_ray.iter().zip(&c.targets).zip(&c.rays) {
                let se: f32 = (0..3).map(|k| (o.rgb[k] - target[k]) * (o.rgb[k] - target[k])).sum();
                out.extend([o.rgb[0], o.rgb[1], o.rgb[2], o.distance, o.acc, lossmult(ray) * se, se, 0.0]);
                d_ray_rgb.push(pixel_loss_gradient(o.rgb, *target, lossmult(ray), level_weight, norm));
            }
            let (mut d_rgb, mut d_density) = (vec![0.0; n * 3], vec![0.0; n]);
            let d_raw = stages::RawGradients { rgb: &mut d_rgb[..], density: &mut d_density[..] };
            stages::render_rays_backward(&cfg, raw, level, &samples, &d_ray_rgb, d_raw);
            vec![("weights", samples.weights), ("ray outputs", out), ("d raw rgb", d_rgb), ("d raw density", d_density)]
        };
        // GPU, outputs poisoned with NaN.
        let on_gpu = |c: &RenderCase| -> Result<Outputs, GpuError> {
            let mut params = RenderParams::new(&cfg, nr, level_weight, true);
            if bg == BACKGROUND_RANDOM {
                params = params.with_random_background(seed, step);
            }
            let input = RenderInputs {
                raw_rgb: &c.raw_rgb,
                raw_density: &c.raw_density,
                t: &c.t,
                rays: &c.rays,
                ids: &c.ids,
                targets: &c.targets,
                norm,
            };
            let o = kernel.run(&ctx, params, &input)?;
            Ok(vec![
                ("weights", o.weights),
                ("ray outputs", o.ray_out),
                ("d raw rgb", o.d_raw_rgb),
                ("d raw density", o.d_raw_density),
            ])
        };
        let tol = |_: &str| Tolerance::new(TOL_GPU_RENDER_ABS, TOL_GPU_RENDER_REL);
        bad.extend(check_kernel(&format!("{variant:?} case {ci}"), cpu, on_gpu, &case, tol).into_mismatches());
    }
    assert_none(&bad);
}

#[test]
fn adam_and_gradient_clipping_match_cpu_reference() {
    use mipnerf_core::train::{AdamConfig, AdamState, FieldAdam};
    use mipnerf_gpu::kernels::adam::{AdamBuffers, AdamKernel, AdamStep};
    use rand::{Rng, SeedableRng, rngs::SmallRng};
    let Some(ctx) = context_or_skip("adam_and_gradient_clipping_match_cpu_reference") else { return };
    let kernel = AdamKernel::new(&ctx).unwrap();
    // More than one workgroup of the norm's first pass (256), not a multiple of it.
    let n = 1000;
    let (cfg, lr) = (AdamConfig::default(), 1e-3);
    let mut bad = Vec::new();
    // (max_val, max_norm): off; by value (some entries clipped); by norm (the norm of 1000 entries
    // of about 0.06 is about 1.8, so it is scaled); both. Then a field's own first 300
    // parameters at 10 times the rate with a tiny epsilon (the Tri-Mip planes' split), with and
    // without clipping by norm.
    let planes = Some((300, FieldAdam { lr_mult: 10.0, eps: 1e-15 }));
    let cases = [
        (0.0, 0.0, None),
        (0.05, 0.0, None),
        (0.0, 0.5, None),
        (0.08, 1.0, None),
        (0.0, 0.0, planes),
        (0.0, 0.5, planes),
    ];
    for (max_val, max_norm, split) in cases {
        // The starting parameters and three steps' gradients.
        let mut rng = SmallRng::seed_from_u64(3);
        let params: Vec<f32> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
        let steps: Vec<Vec<f32>> = (0..3).map(|_| (0..n).map(|_| rng.random_range(-0.1..0.1)).collect()).collect();
        let cpu = |(params, steps): &(Vec<f32>, Vec<Vec<f32>>)| -> Outputs {
            let (mut params, mut state, mut norms) = (params.clone(), AdamState::new(n), Vec::new());
            for grads in steps {
                let norm = stages::adam_step(
                    &cfg,
                    lr,
                    (max_val, max_norm),
                    split,
                    &mut state,
                    &mut params,
                    &mut grads.clone(),
                );
                norms.push(norm);
            }
            let norms = if max_norm > 0.0 { norms } else { Vec::new() };
            vec![("params", params), ("m", state.m), ("v", state.v), ("gradient norm", norms)]
        };
        let on_gpu = |(params, steps): &(Vec<f32>, Vec<Vec<f32>>)| -> Result<Outputs, GpuError> {
            let b = AdamBuffers::new(&ctx, params, &vec![0.0; n], &vec![0.0; n]);
            let mut norms = Vec::new();
            for (t, grads) in (1..).zip(steps) {
                ctx.queue().write_buffer(&b.grads, 0, bytemuck::cast_slice(grads));
                let mut rec = Recorder::new(&ctx, "adam test");
                kernel.encode(&mut rec, &AdamStep { cfg, t, lr, max_val, max_norm, split }, &b)?;
                let _ = rec.submit();
                if max_norm > 0.0 {
                    norms.push(ctx.read_f32(&b.stats, 1)?[0]);
                }
            }
            Ok(vec![
                ("params", ctx.read_f32(&b.params, n)?),
                ("m", ctx.read_f32(&b.m, n)?),
                ("v", ctx.read_f32(&b.v, n)?),
                ("gradient norm", norms),
            ])
        };
        let tol = |name: &str| match name {
            "params" => Tolerance::new(1e-7, 1e-6),
            "m" => Tolerance::new(1e-9, 1e-6),
            "v" => Tolerance::new(1e-12, 1e-5),
            _ => Tolerance::new(0.0, 1e-5),
        };
        let label = format!("max_val {max_val} max_norm {max_norm} split {split:?}");
        bad.extend(check_kernel(&label, cpu, on_gpu, &(params, steps), tol).into_mismatches());
    }
    assert_none(&bad);
}

/// GPU vs CPU interval edges: the same f32 operations; WGSL bounds division to 2.5 ulp (the only
/// operation here that is not correctly rounded), on every vendor.
const TOL_GPU_SAMPLE_REL: f32 = 2e-6;

/// GPU vs CPU fine edges of the wide resampling (32 invocations per ray), absolute, in scene
/// units: its CDF sums the weights by block, so CDF entries differ from the CPU's sequential sums
/// by a few ulp of 1 (~2e-7); an edge moves by that times its coarse interval over the CDF step,
/// which the near-zero weights here make small. Measured up to 4.2e-5 on edges of 0.5 to 8.
const TOL_GPU_RESAMPLE_WIDE_ABS: f32 = 1e-4;

/// GPU vs CPU edges of an unbounded scene, compared in the normalised distance `s` they are
/// drawn in (`contract::ray_distance_to_s`), absolutely: `s` lies in `[0, 1)`, and an ulp of `s`
/// near 1 (6e-8) is a relative change of `t` as large as `t · 1.2e-7` (6% at `t = 1e6`), so `t`
/// itself is the wrong scale. The mapping's division (2.5 ulp in WGSL) and the stratification's
/// own rounding stay within a few ulp of 1.
const TOL_GPU_SAMPLE_S_ABS: f32 = 1e-6;

/// The same for the fine edges of the wide resampling, whose CDF is summed by block (see
/// [`TOL_GPU_RESAMPLE_WIDE_ABS`]): measured up to 4.5e-6 in `s` on lavapipe.
const TOL_GPU_RESAMPLE_WIDE_S_ABS: f32 = 2e-5;

#[test]
fn sampling_and_resampling_match_cpu_reference() {
    use mipnerf_core::contract::ray_distance_to_s;
    use mipnerf_core::sampling::RESAMPLE_PADDING;
    use mipnerf_gpu::kernels::sample::{ResampleVariant, SampleKernels, SampleParams};
    use rand::{Rng, SeedableRng, rngs::SmallRng};
    let Some(ctx) = context_or_skip("sampling_and_resampling_match_cpu_reference") else { return };
    let mut bad = Vec::new();
    // Both resampling entry points, whatever the adapter would pick; 24 samples (fewer than the
    // wide kernel's 32 lanes) and 75 (blocks of 3, the last lanes short or empty).
    for (variant, s) in [
        (ResampleVariant::PerRay, 24usize),
        (ResampleVariant::Wide, 24),
        (ResampleVariant::PerRay, 75),
        (ResampleVariant::Wide, 75),
    ] {
        let k = SampleKernels::with_variant(&ctx, variant).unwrap();
        // Scattered batch indices, as the rays an occupancy grid lets through have.
        let (nr, seed, step) = (37usize, 5u32, 9u32);
        let ids: Vec<u32> = (0..nr as u32).map(|r| 100 + 3 * r).collect();
        let mut rng = SmallRng::seed_from_u64(s as u64);
        let bounded: Vec<Ray> = (0..nr)
            .map(|_| {
                let near = rng.random_range(0.5..3.0);
                Ray { near, far: near + rng.random_range(0.5..5.0), ..Ray::default() }
            })
            .collect();
        // Unbounded scenes: nears inside and outside the unit distance, every far at infinity's
        // stand-in.
        let unbounded: Vec<Ray> =
            (0..nr).map(|r| Ray { near: 0.05 + 0.07 * r as f32, far: UNBOUNDED_FAR, ..Ray::default() }).collect();
        // Weights with zeros and spikes.
        let weights: Vec<f32> =
            (0..nr * s).map(|i| if i % 7 == 0 { 0.0 } else { rng.random_range(0.0..1.0f32).powi(4) }).collect();
        let spacings = [Spacing::Depth, Spacing::Disparity, Spacing::Unbounded];
        for (spacing, randomized) in spacings.into_iter().flat_map(|sp| [(sp, false), (sp, true)]) {
            let mode = mode_of(randomized, seed, step);
            let rays = if spacing == Spacing::Unbounded { &unbounded } else { &bounded };
            // Unbounded edges are compared in s (TOL_GPU_SAMPLE_S_ABS).
            let compared = |name: &'static str, t: Vec<f32>| -> (&'static str, Vec<f32>) {
                if spacing == Spacing::Unbounded {
                    (name, t.into_iter().map(ray_distance_to_s).collect())
                } else {
                    (name, t)
                }
            };
            let cpu = |(rays, w): &(Vec<Ray>, Vec<f32>)| -> Outputs {
                let (mut coarse, mut fine) = (vec![0.0; nr * (s + 1)], vec![0.0; nr * (s + 1)]);
                stages::sample_intervals(rays, s, spacing, mode, &ids, &mut coarse);
                stages::resample_intervals(
                    &coarse,
                    w,
                    stages::Resample { n_samples: s, spacing, padding: RESAMPLE_PADDING, level: 1, mode },
                    &ids,
                    &mut fine,
                );
                vec![compared("coarse", coarse), compared("fine", fine)]
            };
            // GPU, outputs poisoned.
            let on_gpu = |(rays, w): &(Vec<Ray>, Vec<f32>)| -> Result<Outputs, GpuError> {
                let params = SampleParams {
                    n_rays: nr as u32,
                    n_samples: s as u32,
                    spacing: spacing.code(),
                    randomized: u32::from(randomized),
                    seed,
                    step,
                    level: 1,
                    resample_padding: RESAMPLE_PADDING,
                    ..SampleParams::default()
                };
                let bounds: Vec<f32> = rays.iter().flat_map(|r| [r.near, r.far]).collect();
                let b_bounds = ctx.storage_buffer("bounds", &bounds, false);
                let b_w = ctx.storage_buffer("weights", w, false);
                let b_t = ctx.storage_buffer("t coarse", &vec![f32::NAN; nr * (s + 1)], true);
                let b_f = ctx.storage_buffer("t fine", &vec![f32::NAN; nr * (s + 1)], true);
                let b_ids = ctx.storage_buffer("ray ids", &ids, false);
                let mut rec = Recorder::new(&ctx, "sample test");
                k.stratified(&mut rec, params, &b_bounds, &b_ids, &b_t)?;
                k.resample(&mut rec, params, &b_t, &b_w, &b_ids, &b_f)?;
                let _ = rec.submit();
                Ok(vec![
                    compared("coarse", ctx.read_f32(&b_t, nr * (s + 1))?),
                    compared("fine", ctx.read_f32(&b_f, nr * (s + 1))?),
                ])
            };
            let tol = |name: &str| match (name, variant) {
                ("fine", ResampleVariant::Wide) if spacing == Spacing::Unbounded => {
                    Tolerance::abs(TOL_GPU_RESAMPLE_WIDE_S_ABS)
                }
                _ if spacing == Spacing::Unbounded => Tolerance::abs(TOL_GPU_SAMPLE_S_ABS),
                ("coarse", _) => Tolerance::new(0.0, TOL_GPU_SAMPLE_REL),
                (_, ResampleVariant::PerRay) => Tolerance::new(1e-6, TOL_GPU_SAMPLE_REL),
                (_, ResampleVariant::Wide) => Tolerance::new(TOL_GPU_RESAMPLE_WIDE_ABS, TOL_GPU_SAMPLE_REL),
            };
            let label = format!("{variant:?} {s} samples {spacing:?} randomized {randomized}");
            // The inverse CDF divides by the density of the blurred weights, small between the
            // spikes: there an edge moves by 1e-5 when the weights and bounds move by a few ulps
            // (measured on an NVIDIA H100), as far as a hardware GPU's other rounding moves it.
            let inputs = (rays.clone(), weights.clone());
            let moved = hardware_perturbations(&ctx, 8, HARDWARE_ROUNDING_REL, |n| {
                let rays = rays
                    .iter()
                    .map(|r| Ray {
                        near: n.value(r.near),
                        far: if r.far == UNBOUNDED_FAR { r.far } else { n.value(r.far) },
                        ..*r
                    })
                    .collect();
                (rays, weights.iter().map(|&w| n.value(w)).collect())
            });
            bad.extend(
                check_kernel_conditioned(&label, cpu, on_gpu, (&inputs, &moved, SPREAD_FACTOR), tol).into_mismatches(),
            );
        }
    }
    assert_none(&bad);
}

#[test]
fn view_direction_encoding_matches_cpu_reference() {
    use mipnerf_gpu::kernels::view_enc::ViewEncKernel;
    let Some(ctx) = context_or_skip("view_direction_encoding_matches_cpu_reference") else { return };
    let k = ViewEncKernel::new(&ctx).unwrap();
    let rays = test_rays(9);
    let mut bad = Vec::new();
    // The paper's 4 degrees, and 12 (arguments up to 2^11 = 2048, as NeRF's positions reach):
    // the argument reduction holds far from [-pi, pi] without fused multiply-adds, on every vendor.
    for deg in [4u32, 12] {
        let len = rays.len() * mip::pos_enc_len(0, deg, true);
        let cpu = |rays: &[Ray]| -> Outputs {
            let mut out = vec![0.0; len];
            stages::encode_view_directions(rays, deg, &mut out);
            vec![("encoding", out)]
        };
        let on_gpu = |rays: &[Ray]| -> Result<Outputs, GpuError> {
            let dirs: Vec<f32> = rays.iter().flat_map(|r| r.viewdir.to_array()).collect();
            let b_in = ctx.storage_buffer("viewdirs", &dirs, false);
            let b_out = ctx.storage_buffer("view enc", &vec![f32::NAN; len], true);
            let mut rec = Recorder::new(&ctx, "view enc test");
            k.encode(&mut rec, rays.len(), deg, &b_in, &b_out)?;
            let _ = rec.submit();
            Ok(vec![("encoding", ctx.read_f32(&b_out, len)?)])
        };
        let tol = |_: &str| Tolerance::abs(sin_feature_tolerance(&ctx));
        let label = format!("view encoding, {deg} degrees, on {}", ctx.adapter().name);
        bad.extend(check_kernel(&label, cpu, on_gpu, &rays[..], tol).into_mismatches());
    }
    assert_none(&bad);
}

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

/// GPU vs CPU, the whole model step: the IPE differs by ~1e-6 between the two, and that flows
/// through the MLP, rendering and every gradient. On a hardware adapter this assumes `sin` within
/// about 2^-20 on [-pi, pi], which NVIDIA, AMD, Intel and Apple drivers deliver; a driver using
/// WGSL's full 2^-11 latitude passes the IPE test (which allows it) and fails this one, as it
/// should: its training would not follow the CPU's.
const TOL_GPU_MODEL_REL: f32 = 2e-3;
const TOL_GPU_MODEL_ABS: f32 = 2e-6;

/// The tolerance of a whole model's outputs: losses and MSE as they are, gradients relative to
/// their overall scale (`grad_scale`, the CPU's largest).
fn model_tolerance(grad_scale: f32) -> impl Fn(&str) -> Tolerance {
    move |name| match name {
        "grads" => Tolerance::new(TOL_GPU_MODEL_REL * grad_scale, TOL_GPU_MODEL_REL),
        _ => Tolerance::new(TOL_GPU_MODEL_ABS, TOL_GPU_MODEL_REL),
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
                    let spec = mipnerf_core::data::RaySpec {
                        centers: PixelCenters::Centered,
                        bounds: (2.0, 6.0),
                        lossmult: 1.0,
                        ndc: None,
                    };
                    mipnerf_core::data::push_camera_rays(&cam, x, y, spec, k, &mut out);
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

/// One matrix product on the device against f64 on the host: every output must lie within the
/// worst-case bound of f32 summation, `k u sum_i |a_i b_i|` (Higham's gamma_k, u = 2^-24; it holds
/// for any order and any fusing of the multiply-adds, split or not), plus one rounding of the
/// epilogue. Returns every output outside it.
fn check_product(
    ctx: &mipnerf_gpu::GpuContext,
    kernel: &mipnerf_gpu::kernels::matmul::MatmulKernel,
    (m, k, n): (usize, usize, usize),
    (a_t, b_t): (bool, bool),
    split: bool,
    tag: &str,
) -> Vec<String> {
    use mipnerf_gpu::kernels::matmul::{Epilogue, Operand, Product};
    use rand::{Rng, SeedableRng, rngs::SmallRng};
    let mut rng = SmallRng::seed_from_u64((m * 31 + k * 7 + n) as u64);
    // Offsets inside the buffers, so that they are honoured too.
    let (a_off, b_off, bias_off) = (3usize, 5usize, 5 + k * n + 2);
    let a: Vec<f32> = (0..a_off + m * k).map(|_| rng.random_range(-1.0..1.0)).collect();
    let b: Vec<f32> = (0..bias_off + n).map(|_| rng.random_range(-1.0..1.0)).collect();
    let c0: Vec<f32> = (0..m * n).map(|_| rng.random_range(-1.0..1.0)).collect();
    let mask: Vec<f32> = (0..m * n).map(|_| rng.random_range(-1.0..1.0)).collect();
    let at = |r: usize, kk: usize| if a_t { a[a_off + kk * m + r] } else { a[a_off + r * k + kk] };
    let bt = |kk: usize, c: usize| if b_t { b[b_off + c * k + kk] } else { b[b_off + kk * n + c] };
    let buf_a = ctx.storage_buffer("test a", &a, false);
    let buf_b = ctx.storage_buffer("test b", &b, false);
    let buf_mask = ctx.storage_buffer("test mask", &mask, false);
    let mut bad = Vec::new();
    // Three epilogues: accumulate + bias + ReLU; overwrite + ReLU-backward mask; overwrite + a
    // per-group row (groups of 3 rows) + bias.
    for (e, accumulate) in [(0, true), (1, false), (2, false)] {
        let buf_c = ctx.storage_buffer("test c", &c0, true);
        let scratch_len = 64 * m * n;
        let scratch = ctx.storage_buffer("test scratch", &vec![f32::NAN; scratch_len], false);
        let opa = if a_t { Operand::t(&buf_a, a_off) } else { Operand::new(&buf_a, a_off) };
        let opb = if b_t { Operand::t(&buf_b, b_off) } else { Operand::new(&buf_b, b_off) };
        let epi = match e {
            0 => Epilogue { accumulate, bias: Some(bias_off), relu: true, ..Epilogue::default() },
            1 => Epilogue { accumulate, mask: Some((&buf_mask, 0)), ..Epilogue::default() },
            _ => {
                Epilogue { accumulate, bias: Some(bias_off), per_group: Some((&buf_mask, 0, 3)), ..Epilogue::default() }
            }
        };
        let mut rec = Recorder::new(ctx, "product test");
        if split {
            kernel.encode_split(
                &mut rec,
                Product { shape: (m, k, n), a: opa, b: opb, c: Operand::new(&buf_c, 0), epi },
                &scratch,
                scratch_len,
            );
        } else {
            kernel.encode(&mut rec, Product { shape: (m, k, n), a: opa, b: opb, c: Operand::new(&buf_c, 0), epi });
        }
        let _ = rec.submit();
        let got = ctx.read_f32(&buf_c, m * n).unwrap();
        for r in 0..m {
            for c in 0..n {
                let (mut sum, mut abs) = (0.0f64, 0.0f64);
                for kk in 0..k {
                    let p = f64::from(at(r, kk)) * f64::from(bt(kk, c));
                    sum += p;
                    abs += p.abs();
                }
                let mut want = sum;
                if accumulate {
                    want += f64::from(c0[r * n + c]);
                }
                match e {
                    0 => want = (want + f64::from(b[bias_off + c])).max(0.0),
                    1 if mask[r * n + c] <= 0.0 => want = 0.0,
                    1 => {}
                    _ => want += f64::from(mask[(r / 3) * n + c]) + f64::from(b[bias_off + c]),
                }
                let u = f64::from(f32::EPSILON) / 2.0;
                let bound = k as f64 * u * abs + 4.0 * u * (want.abs() + 2.0) + 1e-30;
                let g = f64::from(got[r * n + c]);
                if g.is_nan() || (g - want).abs() > bound {
                    bad.push(format!("{tag} epilogue {e} ({r}, {c}): got {g:e} want {want:e} (bound {bound:e})"));
                }
            }
        }
    }
    bad
}

/// Both product kernels, split over k and not, with either operand stored transposed, at sizes
/// with partial tiles on both sides, several row tiles and an odd k, against f64 under the f32
/// summation bound; and the split plans those sizes get have several partials, the last short.
#[test]
fn matrix_products_split_or_not_match_f64_within_the_summation_bound() {
    use mipnerf_gpu::kernels::matmul::{MatmulKernel, MatmulVariant};
    let Some(ctx) = context_or_skip("matrix_products_split_or_not_match_f64_within_the_summation_bound") else {
        return;
    };
    let mut bad = Vec::new();
    for variant in [MatmulVariant::Tiled, MatmulVariant::Blocked] {
        let kernel = MatmulKernel::with_variant(&ctx, variant).unwrap();
        // A weight gradient's shape (few outputs, long k) and a layer's (many rows).
        let wgrad = (45, 3001, 37);
        let plan = kernel.split_plan(wgrad, 64 * 45 * 37);
        assert!(plan.splits >= 4 && wgrad.1 % plan.k_chunk != 0, "{variant:?}: {plan:?}");
        for (dims, split) in [(wgrad, true), (wgrad, false), ((197, 83, 70), false), ((130, 19, 5), true)] {
            for trans in [(false, false), (true, false), (false, true), (true, true)] {
                let tag = format!("{variant:?} {dims:?} split {split} transposed {trans:?}");
                bad.extend(check_product(&ctx, &kernel, dims, trans, split, &tag));
            }
        }
    }
    assert_none(&bad);
}

/// Hardware limits: the product kernels walk row and column tiles in grid-stride loops, so a
/// dispatch never exceeds the device's workgroups per dimension. Capped at 3 workgroups per
/// dimension, each kernel still covers every tile of a product 7 row tiles tall and 3 column
/// tiles wide; and the hardware kernel runs on lavapipe past the old limit of the 16-row tiles
/// (65535 x 16 rows) against the CPU.
#[test]
fn products_cover_any_size_within_the_dispatch_limit() {
    use mipnerf_gpu::kernels::matmul::{Epilogue, MatmulKernel, MatmulVariant, Operand, Product};
    let Some(ctx) = context_or_skip("products_cover_any_size_within_the_dispatch_limit") else {
        return;
    };
    let mut bad = Vec::new();
    for variant in [MatmulVariant::Tiled, MatmulVariant::Blocked] {
        let kernel = MatmulKernel::with_variant(&ctx, variant).unwrap().with_max_groups_per_dim(3);
        let t = variant.tile();
        let dims = (7 * t - 5, 21, 3 * t - 1);
        bad.extend(check_product(&ctx, &kernel, dims, (false, false), false, &format!("{variant:?} capped")));
        bad.extend(check_product(
            &ctx,
            &kernel,
            (t + 3, 2000, 9),
            (true, false),
            true,
            &format!("{variant:?} capped split"),
        ));
    }
    // 1,100,000 rows: 17,188 row tiles of the 64-row hardware kernel.
    let (m, k, n) = (1_100_000usize, 3usize, 2usize);
    let a: Vec<f32> = (0..m * k).map(|i| ((i % 7) as f32 - 3.0) * 0.25).collect();
    let b = [0.5f32, -1.0, 0.25, 2.0, -0.75, 1.5];
    let kernel = MatmulKernel::with_variant(&ctx, MatmulVariant::Tiled).unwrap();
    let (ba, bb) = (ctx.storage_buffer("big a", &a, false), ctx.storage_buffer("big b", &b, false));
    let bc = ctx.storage_buffer("big c", &vec![f32::NAN; m * n], true);
    let mut rec = Recorder::new(&ctx, "big product");
    kernel.encode(
        &mut rec,
        Product {
            shape: (m, k, n),
            a: Operand::new(&ba, 0),
            b: Operand::new(&bb, 0),
            c: Operand::new(&bc, 0),
            epi: Epilogue::default(),
        },
    );
    let _ = rec.submit();
    let got = ctx.read_f32(&bc, m * n).unwrap();
    // Every product is exact in f32 (quarters times small binary fractions), so the sums are too.
    let want: Vec<f32> = (0..m * n).map(|i| (0..k).map(|kk| a[(i / n) * k + kk] * b[kk * n + i % n]).sum()).collect();
    bad.extend(mismatches("1.1M-row product", &got, &want, Tolerance::EXACT));
    assert_none(&bad);
}

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
    use mipnerf_core::data::{self, LoadOptions, Split};
    use mipnerf_core::occupancy::{OccupancyConfig, OccupancyGrid, ndc_bound};
    let Some(ctx) = context_or_skip("occupancy_guided_edges_match_cpu_reference_in_ndc") else { return };
    // The forward-facing fixture's rays in NDC space, under a grid over the NDC cube with the
    // near leaves (a slab in depth with holes) and part of the far wall occupied.
    let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/llff_fern_tiny");
    let ds = data::load(&dir, Split::Train, &LoadOptions { llff_factor: 64, ..LoadOptions::default() }).unwrap();
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
    use mipnerf_gpu::kernels::occupancy::{DeviceGrid, GuidedRays, OccupancyKernel, OccupancyParams};
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
        let unbounded = spacing == Spacing::Unbounded;
        let in_s = |t: Vec<f32>| if unbounded { t.into_iter().map(ray_distance_to_s).collect() } else { t };
        let cpu = |rays: &[Ray]| -> Outputs {
            let mut t = vec![0.0f32; nr * (s + 1)];
            let (starts, spans) = spans_of_rays(rays);
            stages::sample_occupied_intervals(rays, (&starts, &spans), s, spacing, mode, &ids, &mut t);
            vec![("edges", in_s(t))]
        };
        let on_gpu = |_: &[Ray]| -> Result<Outputs, GpuError> {
            let t_out = ctx.storage_buffer("t coarse", &vec![f32::NAN; nr * (s + 1)], true);
            let params = OccupancyParams {
                n_rays: nr as u32,
                n_samples: s as u32,
                spacing: spacing.code(),
                randomized: u32::from(randomized),
                seed,
                step,
                ..OccupancyParams::default()
            };
            let mut rec = Recorder::new(ctx, "occupancy test");
            let b_ids = ctx.storage_buffer("ray ids", &ids, false);
            let rays = GuidedRays { rays: &batch.rays, bounds: &batch.bounds, ray_ids: &b_ids };
            kernel.sample(&mut rec, params, &on_device, rays, &t_out)?;
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
