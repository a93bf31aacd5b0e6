//! Volume rendering's kernel (`render.wgsl`) against `stages::render_rays` and its backward pass.
//! How every kernel test runs and compares: `tests/common/mod.rs`.
#![allow(clippy::unwrap_used, missing_docs)]

mod common;
use common::*;

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
