//! The MLP's three matrix products on one thread, f32 (gemm) against each bf16 kernel this CPU
//! has: `cargo bench -p mipnerf-core --bench products`.
//!
//! Shapes of one chunk of the training step (`CHUNK_RAYS` rays x 128 samples = 8192 rows) through
//! a 128-wide (small preset) and a 256-wide (paper) layer: the forward product `x · W`
//! (8192 x w · w x w), the input gradient `dz · Wᵀ` and the weight gradient `xᵀ · dz`
//! (w x 8192 · 8192 x w).
#![allow(missing_docs)]

use mipnerf_core::bench::{Product, product_gflops};
use mipnerf_core::bf16::{Bf16Kernel, matmul_bf16_on};
use mipnerf_core::linalg::{Layout, matmul};

fn main() {
    let quick = std::env::args().any(|a| a == "--quick") || !std::env::args().any(|a| a == "--bench");
    let (rows, reps) = if quick { (256, 1) } else { (8192, 9) };
    let mut kernels: Vec<(&str, Box<Product>)> = vec![("f32 (gemm)", Box::new(matmul))];
    for kernel in Bf16Kernel::ALL {
        match kernel.check() {
            Ok(()) => kernels.push((
                kernel.name(),
                Box::new(move |c: &mut [f32], a: &[f32], la, b: &[f32], lb, m, k, n, acc| {
                    matmul_bf16_on(kernel, c, a, la, b, lb, m, k, n, acc);
                }),
            )),
            Err(why) => println!("{}: not measured ({why})", kernel.name()),
        }
    }
    println!("GFLOP/s on one thread, median of {reps}:");
    println!("| product | m x k x n | {} |", kernels.iter().map(|(name, _)| *name).collect::<Vec<_>>().join(" | "));
    println!("|---|---|{}", "---|".repeat(kernels.len()));
    for w in [128, 256] {
        let shapes = [
            ("forward x·W", Layout::Normal, Layout::Normal, rows, w, w),
            ("input gradient dz·Wᵀ", Layout::Normal, Layout::Transposed, rows, w, w),
            ("weight gradient xᵀ·dz", Layout::Transposed, Layout::Normal, w, rows, w),
        ];
        for (name, la, lb, m, k, n) in shapes {
            let rates: Vec<String> = kernels
                .iter()
                .map(|(_, p)| format!("{:.1}", product_gflops(p.as_ref(), la, lb, m, k, n, reps)))
                .collect();
            println!("| {name} | {m} x {k} x {n} | {} |", rates.join(" | "));
        }
    }
}
