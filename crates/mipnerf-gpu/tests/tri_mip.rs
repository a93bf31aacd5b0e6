//! The Tri-Mip field's kernels (`shaders/tri_mip.wgsl`) on a real adapter (lavapipe in CI)
//! against their CPU reference (`mipnerf_core::tri_mip` and the model's
//! `encode_intervals` / `encode_intervals_backward`): the pyramid, the samples' encodings over
//! world space, over an unbounded scene's contracted space and at level 0 (tri-plane), their
//! adjoint (against the CPU's and against the encoding's own differences), the planes' total
//! variation, and a whole loss and gradient of a model on the field.
#![allow(clippy::unwrap_used, missing_docs)]

use mipnerf_core::compare::{Tolerance, assert_none, mismatches};
use mipnerf_core::contract::UNBOUNDED_FAR;
use mipnerf_core::demo;
use mipnerf_core::model::{Field, Mode, Model, ModelConfig, Preset};
use mipnerf_core::model::{GradWith, TrainBatch};
use mipnerf_core::sampling::Spacing;
use mipnerf_core::tri_mip::{Pyramid, TriMipConfig, total_variation};
use mipnerf_core::{PixelCenters, Ray, stages};
use mipnerf_gpu::kernels::tri_mip::{PlaneField, TriMipKernel};
use mipnerf_gpu::model::GpuModel;
use mipnerf_gpu::test_support::{context_or_skip, contexts_of_each_atomics};
use rand::{Rng, SeedableRng, rngs::SmallRng};

/// The pyramid: each texel the mean of four, `0.25 · (((a + b) + c) + d)` on both sides, with
/// `+` and `*` correctly rounded on every vendor and nothing to fuse: bit for bit.
const TOL_PYRAMID: Tolerance = Tolerance::abs(0.0);

/// The samples' encodings: the same f32 operations in the same order as the CPU, but the
/// level's `log2` is the device's (WGSL bounds it to 3 ulp, lavapipe's LLVM approximates it),
/// which moves the blend between two levels by a few ulps of the level, and `sqrt` and
/// division are within 2.5 ulp. Features are sums of at most 8 taps of values in [-0.5, 0.5],
/// so an absolute bound is the meaningful one. Measured on lavapipe: see the test's line.
const TOL_ENCODING_ABS: f32 = 2e-5;

/// The planes' gradient: each texel's contributions added by atomic compare-exchange in the
/// device's order, not the CPU's sample order; each contribution is computed as the CPU's. The
/// sums carry a few ulps of their terms' magnitudes. Measured on lavapipe: see the test's line.
const TOL_GRADIENT: Tolerance = Tolerance::new(1e-6, 1e-4);

/// The encoding is linear in the planes, so `Σ d_x · (enc(p + δ) - enc(p))` is `Σ grad · δ`
/// up to the rounding of two encodings (each feature to about 1e-7 of its magnitude); relative
/// to the product's magnitude.
const TOL_ADJOINT_REL: f64 = 1e-4;

/// The total variation: the CPU's loop, row by row, the same operations in the same order.
/// Measured on lavapipe: bit for bit.
const TOL_TV: Tolerance = Tolerance::new(1e-9, 1e-6);

/// A model on 32² planes of 4 features in 4 levels over the cube of half side `half_side`.
fn small_model(pre_filtered: bool, unbounded: bool, half_side: f32) -> Model {
    let mut cfg = Preset::Tiny.config();
    cfg.net_depth = 2;
    cfg.net_width = 32;
    cfg.net_width_condition = 16;
    cfg.num_samples = 16;
    cfg.unbounded = unbounded;
    cfg.field =
        Field::TriMip { planes: TriMipConfig { resolution: 32, features: 4, levels: 4 }, half_side, pre_filtered };
    Model::new(cfg).unwrap()
}

/// Parameters of `model` with planes of a visible size (uniform in [-0.5, 0.5]).
fn visible_params(model: &Model, seed: u64) -> Vec<f32> {
    let mut params = model.init_params(seed);
    let mut rng = SmallRng::seed_from_u64(seed);
    params[..model.field_params()].iter_mut().for_each(|p| *p = rng.random_range(-0.5..0.5));
    params
}

/// The demo's oblique camera at 10 x 10 pixels, 16 stratified intervals a ray over [2, 6];
/// for an unbounded scene, the camera moved inside the unit ball and the edges out to infinity
/// (samples inside the ball and contracted beyond it).
fn rays_and_edges(unbounded: bool) -> (Vec<Ray>, Vec<f32>) {
    let mut rays = demo::oblique_camera(10).generate_rays(PixelCenters::Centered, 2.0, 6.0, 1.0);
    let spacing = if unbounded {
        rays.iter_mut().for_each(|r| {
            *r = Ray { origin: r.origin * (0.9 / r.origin.length()), near: 0.1, far: UNBOUNDED_FAR, ..*r };
        });
        Spacing::Unbounded
    } else {
        Spacing::Depth
    };
    let ids: Vec<u32> = (0..rays.len() as u32).collect();
    let mut t = vec![0.0; rays.len() * 17];
    let how = stages::Sample { n_samples: 16, spacing, mode: Mode::Train { seed: 5, step: 0 } };
    stages::sample_intervals(&rays, how, &ids, &mut t);
    (rays, t)
}

/// The three cases every encoding test runs: pre-filtered over world space, pre-filtered over
/// the contracted space, point-sampled (tri-plane).
fn cases() -> [(&'static str, Model, bool); 3] {
    [
        ("tri-mip", small_model(true, false, 1.5), false),
        ("tri-mip unbounded", small_model(true, true, 2.0), true),
        ("tri-plane", small_model(false, false, 1.5), false),
    ]
}

fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
}

/// Bit for bit, for pyramids built in one dispatch (4 levels), in two even ones (7 levels:
/// 3 + 3) and in two uneven ones (8 levels: 4 + 3).
#[test]
fn the_pyramid_is_the_cpus_box_filters() {
    use mipnerf_gpu::kernels::tri_mip::pyramid_groups;
    let Some(ctx) = context_or_skip("the_pyramid_is_the_cpus_box_filters") else { return };
    let kernel = TriMipKernel::new(&ctx).unwrap();
    let mut bad = Vec::new();
    let shapes = [(32, 4, 4, vec![(1, 3)]), (64, 2, 7, vec![(1, 3), (4, 3)]), (256, 1, 8, vec![(1, 4), (5, 3)])];
    for (resolution, features, levels, groups) in shapes {
        let mut cfg = small_model(true, false, 1.5).config().clone();
        let planes = TriMipConfig { resolution, features, levels };
        cfg.field = Field::TriMip { planes, half_side: 1.5, pre_filtered: true };
        let model = Model::new(cfg).unwrap();
        assert_eq!(pyramid_groups(levels), groups, "the dispatches of {levels} levels");
        let field = PlaneField::of(&model).unwrap();
        let params = visible_params(&model, 1);
        let mut pyramid = Pyramid::zeros(field.planes);
        pyramid.build(&params[..model.field_params()]);
        let want: Vec<f32> = (1..field.planes.levels).flat_map(|l| pyramid.level(l).to_vec()).collect();
        let got = kernel.run_build(&ctx, &field, &params).unwrap();
        bad.extend(mismatches(&format!("pyramid of {levels} levels"), &got, &want, TOL_PYRAMID));
    }
    assert_none(&bad);
}

#[test]
fn the_samples_encodings_are_the_cpus() {
    let Some(ctx) = context_or_skip("the_samples_encodings_are_the_cpus") else { return };
    let kernel = TriMipKernel::new(&ctx).unwrap();
    let mut bad = Vec::new();
    let mut encodings = Vec::new();
    for (name, model, unbounded) in cases() {
        let (rays, t) = rays_and_edges(unbounded);
        let params = visible_params(&model, 2);
        let want = model.encode_intervals(&params, &rays, &t);
        let got = kernel.run_encode(&ctx, &PlaneField::of(&model).unwrap(), &rays, &t, &params).unwrap();
        eprintln!("{name}: encodings differ by {:e} at most", max_abs_diff(&got, &want));
        bad.extend(mismatches(name, &got, &want, Tolerance::abs(TOL_ENCODING_ABS)));
        encodings.push(want);
    }
    assert_none(&bad);
    // The cones' footprints reach coarser levels: pre-filtered reads are not the point reads.
    assert!(max_abs_diff(&encodings[0], &encodings[2]) > 1e-2, "tri-mip read the planes as tri-plane does");
}

#[test]
fn the_planes_gradient_is_the_cpus_and_the_encodings_adjoint() {
    let mut bad = Vec::new();
    for (atomics, ctx) in contexts_of_each_atomics("the_planes_gradient_is_the_cpus_and_the_encodings_adjoint") {
        let kernel = TriMipKernel::new(&ctx).unwrap();
        for (name, model, unbounded) in cases() {
            let name = &format!("{name}, {atomics:?}");
            let field = PlaneField::of(&model).unwrap();
            let (rays, t) = rays_and_edges(unbounded);
            let params = visible_params(&model, 3);
            let mut rng = SmallRng::seed_from_u64(4);
            let n_x = rays.len() * 16 * field.planes.encoding_dim();
            let d_x: Vec<f32> = (0..n_x).map(|_| rng.random_range(-1.0..1.0)).collect();
            let want = model.encode_intervals_backward(&params, &rays, &t, &d_x);
            let got = kernel.run_backward(&ctx, &field, &rays, &t, &d_x).unwrap();
            assert!(want.iter().filter(|g| **g != 0.0).count() > 500, "{name}: the samples reach few texels");
            let worst = got.iter().zip(&want).map(|(g, w)| (g - w).abs() / w.abs().max(1e-3)).fold(0.0, f32::max);
            eprintln!("{name}: gradients differ by {worst:e} (relative, above 1e-3) at most");
            bad.extend(mismatches(name, &got, &want, TOL_GRADIENT));
            // The adjoint identity on the device alone: the encoding's change under a change
            // of the planes, against the gradient's product with that change.
            let delta: Vec<f32> = (0..model.field_params()).map(|_| rng.random_range(-0.01..0.01)).collect();
            let moved: Vec<f32> =
                params.iter().enumerate().map(|(i, p)| p + delta.get(i).copied().unwrap_or(0.0)).collect();
            let (before, after) = (
                kernel.run_encode(&ctx, &field, &rays, &t, &params).unwrap(),
                kernel.run_encode(&ctx, &field, &rays, &t, &moved).unwrap(),
            );
            let through_encoding: f64 =
                d_x.iter().zip(after.iter().zip(&before)).map(|(d, (a, b))| f64::from(*d) * f64::from(a - b)).sum();
            let through_gradient: f64 = got.iter().zip(&delta).map(|(g, d)| f64::from(*g) * f64::from(*d)).sum();
            let rel = (through_encoding - through_gradient).abs() / through_gradient.abs();
            eprintln!("{name}: adjoint identity {through_encoding:.6e} vs {through_gradient:.6e} ({rel:e})");
            assert!(rel < TOL_ADJOINT_REL, "{name}: adjoint identity off by {rel:e}");
        }
    }
    assert_none(&bad);
}

#[test]
fn the_planes_total_variation_is_the_cpus() {
    let Some(ctx) = context_or_skip("the_planes_total_variation_is_the_cpus") else { return };
    let kernel = TriMipKernel::new(&ctx).unwrap();
    let model = small_model(true, false, 1.5);
    let field = PlaneField::of(&model).unwrap();
    let params = visible_params(&model, 6);
    let level0 = &params[..model.field_params()];
    let mut want = vec![0.0; level0.len()];
    let want_loss = total_variation(&field.planes, level0, 0.3, &mut want);
    let (loss, got) = kernel.run_total_variation(&ctx, &field, level0, 0.3).unwrap();
    eprintln!("total variation: {loss:e} on the device, {want_loss:e} on the CPU");
    assert!((loss - want_loss).abs() <= 1e-6 * want_loss, "loss {loss} vs the CPU's {want_loss}");
    assert_none(&mismatches("total variation gradient", &got, &want, TOL_TV));
}

/// A whole loss and gradient: the model's passes on the field (the MLP on the planes'
/// encodings, rendering, the MLP's backward pass into the encodings, the scatter, the
/// push-down and the total variation) against the CPU's. The loss is summed in f64 from the
/// same per-ray errors; the gradients carry the MLP's summation order (as the Mip-NeRF field's
/// do, `TOL_GPU_MLP_REL` in kernel_mlp.rs) and the scatter's, so a gradient that is a sum of
/// terms cancelling to near zero is off by a few ulps of its terms: the absolute bound is a
/// share of the largest gradient of its part (planes or MLP). Measured on lavapipe: 4.2e-6 of
/// the largest at worst. One level: a second one resamples its edges from the first's weights,
/// and on point-sampled random planes (tri-plane, a rough density) an edge near a step of the
/// CDF moves a sample by more than rounding (1.4e-2 of the planes' largest gradient, measured);
/// the two-level passes are compared through whole training runs (`backend.rs`).
const TOL_MODEL_LOSS_REL: f32 = 1e-5;
const TOL_MODEL_GRAD_OF_LARGEST: f32 = 1e-4;
const TOL_MODEL_GRAD_REL: f32 = 2e-3;

#[test]
fn a_models_loss_and_gradient_on_the_planes_are_the_cpus() {
    let mut bad = Vec::new();
    for (atomics, ctx) in contexts_of_each_atomics("a_models_loss_and_gradient_on_the_planes_are_the_cpus") {
        let gpu = GpuModel::new(&ctx).unwrap();
        for (name, model, unbounded) in cases() {
            let name = &format!("{name}, {atomics:?}");
            let mut cfg: ModelConfig = model.config().clone();
            cfg.planes_tv_mult = 0.1;
            cfg.num_levels = 1;
            let model = Model::new(cfg).unwrap();
            let (rays, _) = rays_and_edges(unbounded);
            let params = visible_params(&model, 7);
            let mut rng = SmallRng::seed_from_u64(8);
            let targets: Vec<[f32; 3]> = rays.iter().map(|_| [rng.random(), rng.random(), rng.random()]).collect();
            let mode = Mode::Train { seed: 9, step: 3 };
            let mut want = vec![0.0; model.num_params()];
            let cpu = model.loss_and_grad(
                &params,
                TrainBatch { rays: &rays, targets: &targets },
                mode,
                &mut want,
                GradWith::default(),
            );
            let (stats, got) = gpu
                .loss_and_grad(&ctx, &model, &params, TrainBatch { rays: &rays, targets: &targets }, mode, None)
                .unwrap();
            let rel = (stats.loss - cpu.loss).abs() / cpu.loss;
            eprintln!(
                "{name}: loss {} vs the CPU's {} ({rel:e}); total variation {}",
                stats.loss, cpu.loss, stats.regulariser
            );
            assert!(rel <= TOL_MODEL_LOSS_REL, "{name}: loss {} vs the CPU's {}", stats.loss, cpu.loss);
            assert!((stats.regulariser - cpu.regulariser).abs() <= 1e-6 * cpu.regulariser, "{name}: total variation");
            let fp = model.field_params();
            assert!(want[..fp].iter().filter(|g| **g != 0.0).count() > 500, "{name}: the planes take little gradient");
            for (part, range) in [("planes", 0..fp), ("mlp", fp..want.len())] {
                let (got, want) = (&got[range.clone()], &want[range]);
                let largest = want.iter().fold(0.0f32, |m, g| m.max(g.abs()));
                let worst = got.iter().zip(want).map(|(g, w)| (g - w).abs()).fold(0.0, f32::max) / largest;
                eprintln!("{name} {part}: gradients differ by {worst:e} of the largest ({largest:e}) at most");
                let tol = Tolerance::new(TOL_MODEL_GRAD_OF_LARGEST * largest, TOL_MODEL_GRAD_REL);
                bad.extend(mismatches(&format!("{name} {part}"), got, want, tol));
            }
        }
    }
    assert_none(&bad);
}
