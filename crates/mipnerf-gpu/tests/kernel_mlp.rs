//! The MLP's kernels (the matrix products, the fused small MLP) against `MlpShape`'s passes and f64 products.
//! How every kernel test runs and compares: `tests/common/mod.rs`.
#![allow(clippy::unwrap_used, missing_docs)]

mod common;
use common::*;

/// GPU vs CPU, MLP outputs and gradients: products summed in another order (the GPU's tiles and
/// splits versus the CPU GEMM's blocking), f32 throughout. WGSL rounds `+` and `*` correctly on
/// every vendor; only the summation order and fused multiply-adds differ, so this holds on
/// hardware as on lavapipe.
const TOL_GPU_MLP_REL: f32 = 2e-4;
const TOL_GPU_MLP_ABS: f32 = 2e-5;

/// The inputs of one MLP pass: parameters, point features, view directions and their encoding
/// (what the product kernels read; the fused ones encode the directions), and the gradients of
/// the raw outputs.
struct MlpCase {
    params: Vec<f32>,
    x: Vec<f32>,
    view_dirs: Vec<f32>,
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
        let deg_view = (cfg.view_dim - 3) / 6;
        assert_eq!(cfg.view_dim, 3 + 6 * deg_view, "a view encoding of degrees 0..{deg_view}");
        let dirs: Vec<glam::Vec3> = (0..n_rays)
            .map(|_| glam::Vec3::from_array([0; 3].map(|_| rng.random_range(-1.0f32..1.0))).normalize_or(glam::Vec3::Z))
            .collect();
        let mut view = vec![0.0; n_rays * cfg.view_dim];
        for (d, out) in dirs.iter().zip(view.chunks_exact_mut(cfg.view_dim)) {
            mipnerf_core::mip::pos_enc(*d, 0, deg_view as u32, true, out);
        }
        Self {
            params,
            x: (0..n * cfg.x_dim).map(|_| rng.random_range(-1.0..1.0)).collect(),
            view_dirs: dirs.iter().flat_map(|d| d.to_array()).collect(),
            view,
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
    let view_dirs = ctx.storage_buffer("view directions", &c.view_dirs, false);
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
    gpu.forward(&mut rec, shape, &p, &bufs, &view_dirs);
    let pg = mipnerf_gpu::mlp::ParamBuffers { params: &p, grads: &g };
    gpu.backward(&mut rec, shape, pg, &bufs, &dr, &view_dirs)?;
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
