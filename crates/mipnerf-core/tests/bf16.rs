//! The bf16 matrix products (AMX tiles, AVX-512 BF16) against an f64 product, under the bound
//! that bf16's 8-bit significand and f32 accumulation over `k` terms allow, and against the
//! emulation; the model and a run in bf16 against f32. A kernel this CPU lacks is reported as
//! skipped (`mipnerf_core::test_support`), never passed in silence.
#![allow(clippy::unwrap_used, missing_docs)]

use mipnerf_core::bf16::{
    Bf16Kernel, Bf16Matrix, Bf16Support, Operand, Reads, bf16_product_relative_bound, matmul_bf16,
    matmul_bf16_emulated, round_to_bf16,
};
use mipnerf_core::linalg::{Layout, Product, matmul};
use mipnerf_core::model::{GradWith, TrainBatch};
use mipnerf_core::test_support::skipped_for_cpu_feature;

/// Deterministic values spread over [-2, 2] with a few exact zeros, away from subnormals.
fn values(len: usize, seed: u64) -> Vec<f32> {
    let mut s = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
    (0..len)
        .map(|i| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            if i % 97 == 0 { 0.0 } else { ((s >> 40) as f32 / (1u64 << 24) as f32) * 4.0 - 2.0 }
        })
        .collect()
}

fn at(x: &[f32], l: Layout, rows: usize, cols: usize, r: usize, c: usize) -> f64 {
    f64::from(if l == Layout::Normal { x[r * cols + c] } else { x[c * rows + r] })
}

type ProductFn<'a> = &'a dyn Fn(&mut [f32], &[f32], Layout, &[f32], Layout, Product);

/// Checks `product` on `m x k x n` for all four layouts, overwriting and accumulating, against the
/// exact product of the **f32** operands in f64; the error of each element must stay under
/// `bf16_product_relative_bound(k) * sum |a| |b|` (plus the accumulated start value's rounding).
/// Returns the largest ratio of error to bound seen; reports every mismatch in one message.
fn check(product: ProductFn<'_>, m: usize, k: usize, n: usize) -> f64 {
    let a = values(m * k, (m * 31 + k) as u64);
    let b = values(k * n, (n * 17 + k) as u64);
    let bound = bf16_product_relative_bound(k);
    let mut worst = 0.0f64;
    let mut bad = Vec::new();
    for la in [Layout::Normal, Layout::Transposed] {
        for lb in [Layout::Normal, Layout::Transposed] {
            for accumulate in [false, true] {
                let start = values(m * n, 5);
                let mut c = start.clone();
                product(&mut c, &a, la, &b, lb, Product { m, k, n, accumulate });
                for i in 0..m {
                    for j in 0..n {
                        let (mut exact, mut abs) = (0.0f64, 0.0f64);
                        for p in 0..k {
                            let t = at(&a, la, m, k, i, p) * at(&b, lb, k, n, p, j);
                            exact += t;
                            abs += t.abs();
                        }
                        let c0 = if accumulate { f64::from(start[i * n + j]) } else { 0.0 };
                        let err = (f64::from(c[i * n + j]) - (exact + c0)).abs();
                        // One more f32 rounding where the start value is added.
                        let limit = bound * abs + 2.0 * f32::EPSILON as f64 * (abs + c0.abs());
                        worst = worst.max(err / limit);
                        if err > limit && bad.len() < 10 {
                            bad.push(format!("{la:?}/{lb:?} acc={accumulate} [{i},{j}]: err {err:.3e} > {limit:.3e}"));
                        }
                    }
                }
            }
        }
    }
    assert!(bad.is_empty(), "{m}x{k}x{n}: {} elements over the bound:\n{}", bad.len(), bad.join("\n"));
    worst
}

/// Shapes of the MLP (full tiles) and ragged ones (every edge of the 32 x 32 blocks, the AVX-512
/// kernel's 8 x 32 steps and the 32-wide k steps), a weight gradient's long k (more than one of
/// the AVX-512 kernel's 512-value passes, the last one short), and one below the bf16 threshold
/// (runs in f32).
const SHAPES: [(usize, usize, usize); 8] = [
    (64, 128, 128),
    (2048, 64, 32),
    (37, 45, 53),
    (129, 96, 17),
    (16, 300, 40),
    (21, 1100, 35),
    (67, 64, 100),
    (8, 20, 3),
];

#[test]
fn emulated_bf16_product_stays_within_the_bf16_bound_of_the_f64_product() {
    for (m, k, n) in SHAPES {
        let worst = check(&matmul_bf16_emulated, m, k, n);
        // The bound is not vacuous: the rounding of the operands is seen.
        if k >= 32 && m >= 16 && n >= 16 {
            assert!(worst > 0.01, "{m}x{k}x{n}: error only {worst:.3} of the bound: were the operands rounded?");
        }
    }
}

/// Sizes whose products overflow `usize` panic before any product (as `linalg::matmul`'s do).
#[test]
fn the_emulation_panics_on_sizes_whose_product_overflows() {
    let caught = std::panic::catch_unwind(|| {
        matmul_bf16_emulated(
            &mut [],
            &[],
            Layout::Normal,
            &[],
            Layout::Normal,
            Product { m: 1 << 60, k: 1 << 4, n: 16, accumulate: false },
        )
    });
    assert!(caught.is_err(), "the bf16 emulation checks its sizes too");
}

/// Checks one kernel: under the bound for every shape, layout and accumulation, and within the
/// reordering of the f32 sums of the emulation (same rounded operands).
fn check_kernel(kernel: Bf16Kernel) {
    for (m, k, n) in SHAPES {
        let product = |c: &mut [f32], a: &[f32], la, b: &[f32], lb, p| {
            matmul_bf16(c, Operand::f32(a, la), Operand::f32(b, lb), p, Some(kernel));
        };
        check(&product, m, k, n);
        // Same rounded operands: the two differ only in the order of the f32 sums. Both of
        // `a`'s layouts (the AVX-512 kernel reads a transposed `a` from another packing).
        let a = values(m * k, 3);
        let b = values(k * n, 4);
        for la in [Layout::Normal, Layout::Transposed] {
            let (mut got, mut want) = (vec![f32::NAN; m * n], vec![0.0; m * n]);
            matmul_bf16(
                &mut got,
                Operand::f32(&a, la),
                Operand::f32(&b, Layout::Normal),
                Product { m, k, n, accumulate: false },
                Some(kernel),
            );
            matmul_bf16_emulated(&mut want, &a, la, &b, Layout::Normal, Product { m, k, n, accumulate: false });
            let ra: Vec<f32> = a.iter().map(|&x| round_to_bf16(x).abs()).collect();
            let rb: Vec<f32> = b.iter().map(|&x| round_to_bf16(x).abs()).collect();
            let mut abs = vec![0.0; m * n];
            matmul(&mut abs, &ra, la, &rb, Layout::Normal, Product { m, k, n, accumulate: false });
            for (idx, (g, w)) in got.iter().zip(&want).enumerate() {
                let tol = 2.0 * k as f32 * f32::EPSILON * abs[idx];
                assert!((g - w).abs() <= tol, "{} {la:?} {m}x{k}x{n} [{idx}]: {g} vs emulated {w}", kernel.name());
            }
        }
    }
}

#[test]
fn amx_bf16_product_stays_within_the_bf16_bound_and_matches_the_emulation() {
    match Bf16Kernel::Amx.check() {
        Ok(()) => check_kernel(Bf16Kernel::Amx),
        Err(why) => {
            // The refusal must say what is missing.
            assert!(why.contains("amx") || why.contains("AMX"), "unhelpful reason: {why}");
            skipped_for_cpu_feature("amx_bf16_product_stays_within_the_bf16_bound", "amx_bf16", why);
        }
    }
}

#[test]
fn avx512_bf16_product_stays_within_the_bf16_bound_and_matches_the_emulation() {
    match Bf16Kernel::Avx512.check() {
        Ok(()) => check_kernel(Bf16Kernel::Avx512),
        Err(why) => {
            assert!(why.contains("avx512"), "unhelpful reason: {why}");
            skipped_for_cpu_feature("avx512_bf16_product_stays_within_the_bf16_bound", "avx512_bf16", why);
        }
    }
}

/// Where the CPU has both kernels, they compute the same products from the same packed operands:
/// equal up to the order of the f32 sums.
#[test]
fn amx_and_avx512_kernels_agree() {
    for kernel in Bf16Kernel::ALL {
        if let Err(why) = kernel.check() {
            let feature = if kernel == Bf16Kernel::Amx { "amx_bf16" } else { "avx512_bf16" };
            skipped_for_cpu_feature("amx_and_avx512_kernels_agree", feature, why);
            return;
        }
    }
    let (m, k, n) = (256, 256, 256);
    let (a, b) = (values(m * k, 8), values(k * n, 9));
    let run = |kernel| {
        let mut c = vec![f32::NAN; m * n];
        matmul_bf16(
            &mut c,
            Operand::f32(&a, Layout::Transposed),
            Operand::f32(&b, Layout::Normal),
            Product { m, k, n, accumulate: false },
            Some(kernel),
        );
        c
    };
    let (amx, avx) = (run(Bf16Kernel::Amx), run(Bf16Kernel::Avx512));
    let ra: Vec<f32> = a.iter().map(|&x| round_to_bf16(x).abs()).collect();
    let rb: Vec<f32> = b.iter().map(|&x| round_to_bf16(x).abs()).collect();
    let mut abs = vec![0.0; m * n];
    matmul(&mut abs, &ra, Layout::Transposed, &rb, Layout::Normal, Product { m, k, n, accumulate: false });
    for (idx, (x, y)) in amx.iter().zip(&avx).enumerate() {
        assert!((x - y).abs() <= 2.0 * k as f32 * f32::EPSILON * abs[idx], "[{idx}]: AMX {x} vs AVX-512 {y}");
    }
}

/// A matrix packed once ([`Bf16Matrix`]) and read by a product in each role gives that
/// product's bits exactly, as packing inside the product does, on every kernel this CPU has:
/// the forward product's and the input gradient's left operand, the weight gradient's
/// transposed left operand and right operand, in every combination packed in one pass, on
/// MLP-sized and ragged shapes, overwriting and accumulating.
#[test]
fn operands_packed_once_give_the_bits_of_operands_packed_by_each_product() {
    let mut ran = false;
    for kernel in Bf16Kernel::ALL {
        if let Err(why) = kernel.check() {
            let feature = if kernel == Bf16Kernel::Amx { "amx_bf16" } else { "avx512_bf16" };
            skipped_for_cpu_feature(
                "operands_packed_once_give_the_bits_of_operands_packed_by_each_product",
                feature,
                why,
            );
            continue;
        }
        ran = true;
        let all_reads =
            (0..8).map(|bits| Reads { left: bits & 1 != 0, left_transposed: bits & 2 != 0, right: bits & 4 != 0 });
        for (rows, cols, other) in [(256, 128, 64), (37, 45, 53), (129, 96, 17), (1100, 35, 21), (16, 16, 16)] {
            let x = values(rows * cols, (rows + cols) as u64);
            for reads in all_reads.clone() {
                // A reused matrix, packed before at another shape and in other roles.
                let mut packed = Bf16Matrix::default();
                packed.pack_for(
                    kernel,
                    &values(50 * 70, 1),
                    50,
                    70,
                    Reads { left: true, left_transposed: true, right: true },
                );
                packed.pack_for(kernel, &x, rows, cols, reads);
                assert_eq!((packed.rows(), packed.cols()), (rows, cols));
                // Each role this packing serves: (a, b, m, k, n), `x` packed in one of them.
                let w = values(cols * other, 7);
                let w_rows = values(other * cols, 8);
                let g = values(rows * other, 9);
                let mut roles: Vec<(&str, Operand<'_>, Operand<'_>, usize, usize, usize)> = Vec::new();
                let with = |values, layout| Operand { values, layout, packed: Some(&packed) };
                if reads.left {
                    roles.push(("left", with(&x, Layout::Normal), Operand::f32(&w, Layout::Normal), rows, cols, other));
                    let wt = Operand::f32(&w_rows, Layout::Transposed);
                    roles.push(("left, kernel transposed", with(&x, Layout::Normal), wt, rows, cols, other));
                }
                if reads.left_transposed {
                    let right = Operand::f32(&g, Layout::Normal);
                    roles.push(("left transposed", with(&x, Layout::Transposed), right, cols, rows, other));
                }
                if reads.right {
                    let left = Operand::f32(&g, Layout::Transposed);
                    roles.push(("right", left, with(&x, Layout::Normal), other, rows, cols));
                }
                for (role, a, b, m, k, n) in roles {
                    for accumulate in [false, true] {
                        let start = values(m * n, 11);
                        let (mut got, mut want) = (start.clone(), start.clone());
                        matmul_bf16(&mut got, a, b, Product { m, k, n, accumulate }, Some(kernel));
                        matmul_bf16(
                            &mut want,
                            Operand::f32(a.values, a.layout),
                            Operand::f32(b.values, b.layout),
                            Product { m, k, n, accumulate },
                            Some(kernel),
                        );
                        let same = got.iter().zip(&want).all(|(g, w)| g.to_bits() == w.to_bits());
                        assert!(
                            same,
                            "{} {role} {reads:?} {rows}x{cols} acc={accumulate}: not the same bits",
                            kernel.name()
                        );
                    }
                }
            }
        }
    }
    if !ran {
        return;
    }
    // A packing read in a role it was not packed for is a caller's error, refused.
    let kernel = Bf16Support::detect().kernel().unwrap();
    let x = values(64 * 32, 2);
    let mut packed = Bf16Matrix::default();
    packed.pack_for(kernel, &x, 64, 32, Reads { left: true, ..Reads::default() });
    let g = values(64 * 32, 3);
    let caught = std::panic::catch_unwind(|| {
        let mut c = vec![0.0; 32 * 32];
        let a = Operand { values: &x, layout: Layout::Transposed, packed: Some(&packed) };
        matmul_bf16(
            &mut c,
            a,
            Operand::f32(&g, Layout::Normal),
            Product { m: 32, k: 64, n: 32, accumulate: false },
            Some(kernel),
        );
    });
    assert!(caught.is_err(), "a matrix packed only as a left operand is refused as a transposed one");
}

/// Where the CPU has no bf16 kernel, `matmul_bf16` is not reached: the model refuses bf16.
/// Where it has one, `matmul_bf16` runs the kernel `detect` chose.
#[test]
fn matmul_bf16_runs_the_detected_kernel() {
    let Some(kernel) = Bf16Support::detect().kernel() else {
        let mut m = Model::new(Preset::Small.config()).unwrap();
        let err = m.set_precision(Precision::Bf16).unwrap_err().to_string();
        assert!(err.contains("amx") && err.contains("avx512"), "the refusal names both features: {err}");
        skipped_for_cpu_feature("matmul_bf16_runs_the_detected_kernel", "avx512_bf16", &err);
        return;
    };
    let (m, k, n) = (40, 64, 48);
    let (a, b) = (values(m * k, 1), values(k * n, 2));
    let (mut got, mut want) = (vec![0.0; m * n], vec![0.0; m * n]);
    matmul_bf16(
        &mut got,
        Operand::f32(&a, Layout::Normal),
        Operand::f32(&b, Layout::Normal),
        Product { m, k, n, accumulate: false },
        None,
    );
    matmul_bf16(
        &mut want,
        Operand::f32(&a, Layout::Normal),
        Operand::f32(&b, Layout::Normal),
        Product { m, k, n, accumulate: false },
        Some(kernel),
    );
    assert_eq!(got, want, "matmul_bf16 is {}'s product", kernel.name());
}

mod common;
use common::scene::ball_scene;
use mipnerf_core::bf16::Precision;
use mipnerf_core::model::{Mode, Model, ModelConfig, Preset};
use mipnerf_core::schedule::LrSchedule;
use mipnerf_core::train::{OptimConfig, Trainer};

/// The whole model's loss in bf16 against f32, relative: half of bf16's unit roundoff (2^-9).
/// The loss averages thousands of pixels whose colour errors are independent, so it moves far
/// less than one operand's rounding (seen: 5.6e-4 on the small model).
const TOL_MODEL_LOSS_REL: f64 = 2e-3;
/// Each layer's kernel gradient in bf16 against f32: `|g_bf16 - g_f32| / |g_f32|` (L2 norms),
/// at most 5 bf16 unit roundoffs (5 x 2^-8): the gradient of a layer passes through the
/// rounded operands of the forward products below it and the backward products above it
/// (seen: 2e-3 to 7.6e-3, the first layer the worst).
const TOL_MODEL_GRAD_REL: f64 = 5.0 / 256.0;

fn norm(v: &[f32]) -> f64 {
    v.iter().map(|&x| f64::from(x) * f64::from(x)).sum::<f64>().sqrt()
}

#[test]
fn bf16_model_loss_and_gradients_follow_the_f32_model() {
    if let Bf16Support::Unavailable(why) = Bf16Support::detect() {
        skipped_for_cpu_feature("bf16_model_loss_and_gradients_follow_the_f32_model", "avx512_bf16", why);
        return;
    }
    let (rays, colours) = ball_scene(4, 16);
    let (rays, colours) = (&rays[..512], &colours[..512]);
    let f32_model = Model::new(Preset::Small.config()).unwrap();
    let mut bf16_model = f32_model.clone();
    bf16_model.set_precision(Precision::Bf16).unwrap();
    assert_eq!(bf16_model.precision(), Precision::Bf16);
    // Parameters after a few f32 steps, so that every layer carries signal.
    let optim = OptimConfig {
        lr: LrSchedule {
            lr_init: 5e-3,
            lr_final: 5e-3,
            max_steps: 10,
            lr_delay_steps: 0,
            lr_delay_mult: 1.0,
            decay_steps: None,
        },
        ..OptimConfig::default()
    };
    let mut warm = Trainer::new(f32_model.clone(), optim, 3);
    for _ in 0..10 {
        warm.train_step(rays, colours);
    }
    let params = warm.params;
    let mode = Mode::Train { seed: 1, step: 11 };
    let run = |m: &Model| {
        let mut g = vec![0.0; m.num_params()];
        let stats = m.loss_and_grad(&params, TrainBatch { rays, targets: colours }, mode, &mut g, GradWith::default());
        (stats, g)
    };
    let ((s32, g32), (s16, g16)) = (run(&f32_model), run(&bf16_model));
    let loss_rel = (f64::from(s16.loss) - f64::from(s32.loss)).abs() / f64::from(s32.loss);
    let mut report = vec![format!("loss {} vs {} (rel {loss_rel:.2e})", s16.loss, s32.loss)];
    let mut bad = Vec::new();
    if loss_rel > TOL_MODEL_LOSS_REL {
        bad.push(report[0].clone());
    }
    let mut saw_rounding = false;
    for l in &f32_model.mlps()[0].layers {
        let (a, b) = (l.kernel(&g16), l.kernel(&g32));
        let diff: Vec<f32> = a.iter().zip(b).map(|(x, y)| x - y).collect();
        let rel = norm(&diff) / norm(b).max(1e-30);
        saw_rounding |= rel > 1e-4;
        let line = format!("{} ({}x{}): gradient rel {rel:.2e}", l.name, l.fan_in, l.fan_out);
        if rel > TOL_MODEL_GRAD_REL {
            bad.push(line.clone());
        }
        report.push(line);
    }
    eprintln!("{}", report.join("\n"));
    assert!(bad.is_empty(), "bf16 model off the f32 model:\n{}", bad.join("\n"));
    assert!(saw_rounding, "bf16 gradients equal the f32 ones: was bf16 used?");
}

/// Over 120 steps from one seed, the bf16 run's loss (means of 20 steps) stays within this
/// relative band of the f32 run's (seen: at most 3.5% with 64 + 64 samples; the runs drift apart
/// as their parameters do, by rounding, not by a bias).
const TOL_RUN_LOSS_BAND: f64 = 0.10;

#[test]
fn a_bf16_run_follows_the_f32_run_from_one_seed() {
    if let Bf16Support::Unavailable(why) = Bf16Support::detect() {
        skipped_for_cpu_feature("a_bf16_run_follows_the_f32_run_from_one_seed", "avx512_bf16", why);
        return;
    }
    let (rays, colours) = ball_scene(8, 16);
    let steps = 120u64;
    let optim = common::optim_decaying(5e-3, 5e-4, steps);
    let curve = |precision: Precision| {
        // The small preset's MLP (its products' shapes), with 32 + 32 samples so that the two
        // runs take half a minute rather than a minute.
        let mut model = Model::new(ModelConfig { num_samples: 32, ..Preset::Small.config() }).unwrap();
        model.set_precision(precision).unwrap();
        let mut t = Trainer::new(model, optim.clone(), 1);
        let mut losses = Vec::new();
        for s in 0..steps as usize {
            let first = (s * 256) % (rays.len() - 256);
            losses.push(f64::from(t.train_step(&rays[first..first + 256], &colours[first..first + 256]).stats.loss));
        }
        losses.chunks(20).map(|c| c.iter().sum::<f64>() / c.len() as f64).collect::<Vec<f64>>()
    };
    let (a, b) = (curve(Precision::F32), curve(Precision::Bf16));
    eprintln!("f32  {a:.5?}\nbf16 {b:.5?}");
    for (i, (x, y)) in a.iter().zip(&b).enumerate() {
        assert!((x - y).abs() <= TOL_RUN_LOSS_BAND * x, "steps {}..{}: f32 {x} vs bf16 {y}", 20 * i, 20 * i + 20);
    }
    assert!(a[a.len() - 1] * 5.0 < a[0] && b[b.len() - 1] * 5.0 < b[0], "the losses did not fall: {a:?} {b:?}");
}

/// The MLP at bf16 gives the same bits whether each activation and gradient is packed once for
/// all its products (the default, with the forward pass packing for the backward pass when it
/// is told one follows, or not) or every product packs its own operands: the outputs and every
/// parameter's gradient, on the paper's shape and on a ragged one (37 samples per ray, so that
/// the 32-row blocks of the packing cross rays, and a batch that is not whole blocks).
#[test]
fn the_mlp_packing_once_gives_the_bits_of_packing_in_each_product() {
    use mipnerf_core::mlp::{MlpCache, MlpConfig, MlpShape};
    if let Bf16Support::Unavailable(why) = Bf16Support::detect() {
        skipped_for_cpu_feature("the_mlp_packing_once_gives_the_bits_of_packing_in_each_product", "avx512_bf16", why);
        return;
    }
    let ragged =
        MlpConfig { net_depth: 3, net_width: 48, skip_layer: 2, net_width_condition: 40, ..MlpConfig::default() };
    for (config, rays, samples) in [(MlpConfig::default(), 2, 64), (ragged, 3, 37)] {
        let mut shape = MlpShape::new(config, 0).unwrap();
        shape.precision = Precision::Bf16;
        let mut params = vec![0.0f32; shape.num_params];
        shape.init_glorot(&mut params, 5);
        let n = rays * samples;
        let x = values(n * config.x_dim, 21);
        let view = values(rays * config.view_dim, 22);
        let d_rgb: Vec<f32> = values(n * 3, 23).iter().map(|v| v * 1e-2).collect();
        let d_density: Vec<f32> = values(n, 24).iter().map(|v| v * 1e-2).collect();
        let run = |training: bool, each: bool| {
            let mut cache = MlpCache::default();
            cache.set_training(training);
            cache.set_pack_in_each_product(each);
            let mut grads = vec![0.0f32; shape.num_params];
            // Twice through one cache: buffers reused from the pass before.
            for _ in 0..2 {
                grads.fill(0.0);
                shape.forward(&params, &x, &view, rays, samples, &mut cache);
                shape.backward(
                    &params,
                    mipnerf_core::mlp::MlpInputs { x: &x, view: &view, samples_per_ray: samples },
                    &mut cache,
                    mipnerf_core::mlp::OutputGradients { rgb: &d_rgb, density: &d_density },
                    &mut grads,
                );
            }
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<u32>>();
            (bits(&cache.raw_rgb), bits(&cache.raw_density), bits(&grads))
        };
        let want = run(true, true);
        assert!(want.2.iter().any(|&g| g != 0), "the gradient is not all zero");
        for (training, each) in [(true, false), (false, false), (false, true)] {
            assert!(run(training, each) == want, "{config:?}: training {training}, each product {each}: other bits");
        }
    }
}

/// A product whose packed operands outgrow one L2 cache runs k in chunks on AMX (the weight
/// gradient over the small and paper presets' 8,192-row chunks), each block of `c` stored after a
/// chunk and loaded again for the next: the same bits as the products over two halves of k, each
/// small enough to run whole, the second added to the first. Ragged sizes, so the edge blocks
/// go through the scratch block between chunks too.
#[test]
fn amx_products_over_long_k_give_the_bits_of_their_halves_added() {
    if let Err(why) = Bf16Kernel::Amx.check() {
        skipped_for_cpu_feature("amx_products_over_long_k_give_the_bits_of_their_halves_added", "amx_bf16", why);
        return;
    }
    // 2 x 9024 x (64 + 64) bytes of packed operands: past the 2 MiB under which k runs whole;
    // each half (4096, 4904 of k) stays under it.
    let (m, k, n, half) = (40, 9000, 50, 4096);
    let (a, b) = (values(m * k, 31), values(k * n, 32));
    let kernel = Bf16Kernel::Amx;
    let mut whole = vec![0.0f32; m * n];
    matmul_bf16(
        &mut whole,
        Operand::f32(&a, Layout::Normal),
        Operand::f32(&b, Layout::Normal),
        Product { m, k, n, accumulate: false },
        Some(kernel),
    );
    let columns = |from: usize, to: usize| -> Vec<f32> {
        (0..m).flat_map(|r| a[r * k + from..r * k + to].iter().copied()).collect()
    };
    let (a1, a2) = (columns(0, half), columns(half, k));
    let mut halves = vec![0.0f32; m * n];
    matmul_bf16(
        &mut halves,
        Operand::f32(&a1, Layout::Normal),
        Operand::f32(&b[..half * n], Layout::Normal),
        Product { m, k: half, n, accumulate: false },
        Some(kernel),
    );
    matmul_bf16(
        &mut halves,
        Operand::f32(&a2, Layout::Normal),
        Operand::f32(&b[half * n..], Layout::Normal),
        Product { m, k: k - half, n, accumulate: true },
        Some(kernel),
    );
    let differ = whole.iter().zip(&halves).filter(|(x, y)| x.to_bits() != y.to_bits()).count();
    assert_eq!(differ, 0, "{differ} of {} values differ between k in chunks and k in two halves", m * n);
    // And the product is the product: within the bf16 bound of the emulation's.
    let mut emulated = vec![0.0f32; m * n];
    matmul_bf16_emulated(&mut emulated, &a, Layout::Normal, &b, Layout::Normal, Product { m, k, n, accumulate: false });
    let scale = emulated.iter().fold(0.0f32, |s, v| s.max(v.abs()));
    let worst = whole.iter().zip(&emulated).fold(0.0f32, |s, (x, y)| s.max((x - y).abs()));
    // f32 sums of 9,000 terms in another order: far inside a thousandth of the largest value.
    const TOL_LONG_K_REL_TO_LARGEST: f32 = 1e-3;
    let bound = TOL_LONG_K_REL_TO_LARGEST * scale;
    assert!(worst <= bound, "k in chunks differs from the emulation by {worst} (largest value {scale})");
}
