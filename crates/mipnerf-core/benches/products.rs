//! The MLP's three matrix products on one thread, f32 (gemm) against each bf16 kernel this CPU
//! has: `cargo bench -p mipnerf-core --bench products`.
//!
//! Shapes of one chunk of the training step (`CHUNK_RAYS` rays x 128 samples = 8192 rows) through
//! a 128-wide (small preset) and a 256-wide (paper) layer: the forward product `x · W`
//! (8192 x w · w x w), the input gradient `dz · Wᵀ` and the weight gradient `xᵀ · dz`
//! (w x 8192 · 8192 x w); each bf16 product rounds and packs its operands. The output starts on a
//! cache line, as the MLP's buffers do. A second table times the bf16 kernels alone, on operands
//! packed beforehand, with the output on a cache line and 16 bytes past one (where `malloc` puts
//! a large block).
#![allow(missing_docs)]

use mipnerf_core::bench::{Product, product_gflops, product_operands, timed_gflops};

use mipnerf_core::bf16::{Bf16Kernel, Bf16Matrix, Operand, Reads, matmul_bf16_on, matmul_bf16_with_on};
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
                .map(|(_, p)| format!("{:.1}", product_gflops(p.as_ref(), la, lb, m, k, n, reps, 0)))
                .collect();
            println!("| {name} | {m} x {k} x {n} | {} |", rates.join(" | "));
        }
    }
    println!(
        "\nThe bf16 kernels alone (operands packed beforehand, as training packs each activation once), forward x·W, GFLOP/s on one thread, median of {reps}, the output on a cache line / 16 bytes past one:"
    );
    println!("| m x k x n | {} |", kernels[1..].iter().map(|(name, _)| *name).collect::<Vec<_>>().join(" | "));
    println!("|---|{}", "---|".repeat(kernels.len() - 1));
    for (m, w) in [(rows / 8, 128), (rows, 128), (rows / 8, 256), (rows, 256)] {
        let rates: Vec<String> = Bf16Kernel::ALL
            .into_iter()
            .filter(|kernel| kernel.check().is_ok())
            .map(|kernel| {
                format!("{:.1} / {:.1}", packed_gflops(kernel, m, w, reps, 0), packed_gflops(kernel, m, w, reps, 16))
            })
            .collect();
        println!("| {m} x {w} x {w} | {} |", rates.join(" | "));
    }
}

/// GFLOP/s of `kernel` on the forward product `x (m x w) · W (w x w)` with both operands packed
/// before the clock starts, `c` starting `c_past_line` bytes past a 64-byte line ([`timed_gflops`]).
fn packed_gflops(kernel: Bf16Kernel, m: usize, w: usize, reps: usize, c_past_line: usize) -> f64 {
    let (x, weights) = product_operands(m, w, w);
    let (mut x_packed, mut w_packed) = (Bf16Matrix::default(), Bf16Matrix::default());
    x_packed.pack_for(kernel, &x, m, w, Reads { left: true, ..Reads::default() });
    w_packed.pack_for(kernel, &weights, w, w, Reads { right: true, ..Reads::default() });
    let a = Operand { values: &x, layout: Layout::Normal, packed: Some(&x_packed) };
    let b = Operand { values: &weights, layout: Layout::Normal, packed: Some(&w_packed) };
    timed_gflops(m, w, w, reps, c_past_line, |c| matmul_bf16_with_on(kernel, c, a, b, m, w, w, false))
}
