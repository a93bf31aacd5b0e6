//! The bf16 matrix product (AMX tiles) against an f64 product, under the bound that bf16's 8-bit
//! significand and f32 accumulation over `k` terms allow.
#![allow(clippy::unwrap_used, missing_docs)]

use mipnerf_core::bf16::{Bf16Support, bf16_product_relative_bound, matmul_bf16, matmul_bf16_emulated, round_to_bf16};
use mipnerf_core::linalg::{Layout, matmul};

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

type Product = fn(&mut [f32], &[f32], Layout, &[f32], Layout, usize, usize, usize, bool);

/// Checks `product` on `m x k x n` for all four layouts, overwriting and accumulating, against the
/// exact product of the **f32** operands in f64; the error of each element must stay under
/// `bf16_product_relative_bound(k) * sum |a| |b|` (plus the accumulated start value's rounding).
/// Returns the largest ratio of error to bound seen; reports every mismatch in one message.
fn check(product: Product, m: usize, k: usize, n: usize) -> f64 {
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
                product(&mut c, &a, la, &b, lb, m, k, n, accumulate);
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

/// Shapes of the MLP (full tiles) and ragged ones (every edge of the 32 x 32 blocks and the
/// 32-wide k steps), and one below the bf16 threshold (runs in f32).
const SHAPES: [(usize, usize, usize); 6] =
    [(64, 128, 128), (2048, 64, 32), (37, 45, 53), (129, 96, 17), (16, 300, 40), (8, 20, 3)];

#[test]
fn emulated_bf16_product_stays_within_the_bf16_bound_of_the_f64_product() {
    for (m, k, n) in SHAPES {
        let worst = check(matmul_bf16_emulated, m, k, n);
        // The bound is not vacuous: the rounding of the operands is seen.
        if k >= 32 && m >= 16 && n >= 16 {
            assert!(worst > 0.01, "{m}x{k}x{n}: error only {worst:.3} of the bound: were the operands rounded?");
        }
    }
}

#[test]
fn amx_bf16_product_stays_within_the_bf16_bound_and_matches_the_emulation() {
    match Bf16Support::detect() {
        Bf16Support::Unavailable(why) => {
            // The refusal must say what is missing; the kernel itself cannot run here.
            assert!(why.contains("amx") || why.contains("AMX"), "unhelpful reason: {why}");
            eprintln!("AMX kernel not run on this CPU: {why}");
        }
        Bf16Support::Amx => {
            for (m, k, n) in SHAPES {
                check(matmul_bf16, m, k, n);
                // Same rounded operands: the two differ only in the order of the f32 sums.
                let a = values(m * k, 3);
                let b = values(k * n, 4);
                let (mut got, mut want) = (vec![f32::NAN; m * n], vec![0.0; m * n]);
                matmul_bf16(&mut got, &a, Layout::Normal, &b, Layout::Normal, m, k, n, false);
                matmul_bf16_emulated(&mut want, &a, Layout::Normal, &b, Layout::Normal, m, k, n, false);
                let ra: Vec<f32> = a.iter().map(|&x| round_to_bf16(x).abs()).collect();
                let rb: Vec<f32> = b.iter().map(|&x| round_to_bf16(x).abs()).collect();
                let mut abs = vec![0.0; m * n];
                matmul(&mut abs, &ra, Layout::Normal, &rb, Layout::Normal, m, k, n, false);
                for (idx, (g, w)) in got.iter().zip(&want).enumerate() {
                    let tol = 2.0 * k as f32 * f32::EPSILON * abs[idx];
                    assert!((g - w).abs() <= tol, "{m}x{k}x{n} [{idx}]: AMX {g} vs emulated {w}");
                }
            }
        }
    }
}
