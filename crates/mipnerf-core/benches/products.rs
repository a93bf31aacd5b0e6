//! The MLP's three matrix products on one thread, f32 (gemm) against each bf16 kernel this CPU
//! has: `cargo bench -p mipnerf-core --bench products`.
//!
//! Shapes of one chunk of the training step (`CHUNK_RAYS` rays x 128 samples = 8192 rows) through
//! a 128-wide (small preset) and a 256-wide (paper) layer: the forward product `x · W`
//! (8192 x w · w x w), the input gradient `dz · Wᵀ` and the weight gradient `xᵀ · dz`
//! (w x 8192 · 8192 x w); each bf16 product rounds and packs its operands. The output starts on a
//! cache line, as the MLP's buffers do. A second table times the bf16 kernels alone on the forward
//! product and the weight gradient, on operands packed beforehand, with the output on a cache line
//! and 16 bytes past one (where `malloc` puts a large block).
#![allow(missing_docs)]

use mipnerf_core::bench::{ProductFn, product_gflops, product_operands, timed_gflops};

use mipnerf_core::bf16::{Bf16Kernel, Bf16Matrix, Operand, Reads, matmul_bf16};
use mipnerf_core::linalg::{Layout, Product, matmul};

fn main() {
    let quick = std::env::args().any(|a| a == "--quick") || !std::env::args().any(|a| a == "--bench");
    let (rows, reps) = if quick { (256, 1) } else { (8192, 9) };
    let mut kernels: Vec<(&str, Box<ProductFn>)> = vec![("f32 (gemm)", Box::new(matmul))];
    for kernel in Bf16Kernel::ALL {
        match kernel.check() {
            Ok(()) => kernels.push((
                kernel.name(),
                Box::new(move |c: &mut [f32], a: &[f32], la, b: &[f32], lb, p| {
                    matmul_bf16(c, Operand::f32(a, la), Operand::f32(b, lb), p, Some(kernel));
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
                .map(|(_, p)| {
                    let shape = Product { m, k, n, accumulate: false };
                    format!("{:.1}", product_gflops(p.as_ref(), (la, lb), shape, reps, 0))
                })
                .collect();
            println!("| {name} | {m} x {k} x {n} | {} |", rates.join(" | "));
        }
    }
    println!(
        "\nThe bf16 kernels alone (operands packed beforehand, as training packs each activation once), GFLOP/s on one thread, median of {reps}, the output on a cache line / 16 bytes past one:"
    );
    println!(
        "| product | m x k x n | {} |",
        kernels[1..].iter().map(|(name, _)| *name).collect::<Vec<_>>().join(" | ")
    );
    println!("|---|---|{}", "---|".repeat(kernels.len() - 1));
    for (weight_gradient, samples, w) in [
        (false, rows / 8, 128),
        (false, rows, 128),
        (false, rows / 8, 256),
        (false, rows, 256),
        (true, rows, 128),
        (true, rows, 256),
    ] {
        let rates: Vec<String> = Bf16Kernel::ALL
            .into_iter()
            .filter(|kernel| kernel.check().is_ok())
            .map(|kernel| {
                let rate = |past| packed_gflops(kernel, weight_gradient, samples, w, reps, past);
                format!("{:.1} / {:.1}", rate(0), rate(16))
            })
            .collect();
        let (name, (m, k)) =
            if weight_gradient { ("weight gradient xᵀ·dz", (w, samples)) } else { ("forward x·W", (samples, w)) };
        println!("| {name} | {m} x {k} x {w} | {} |", rates.join(" | "));
    }
}

/// GFLOP/s of `kernel` with both operands packed before the clock starts, `c` starting
/// `c_past_line` bytes past a 64-byte line ([`timed_gflops`]): the forward product
/// `x (samples x w) · W (w x w)`, or with `weight_gradient` the weight gradient
/// `xᵀ · dz` of `x` and `dz` (`samples x w` each).
fn packed_gflops(
    kernel: Bf16Kernel,
    weight_gradient: bool,
    samples: usize,
    w: usize,
    reps: usize,
    c_past_line: usize,
) -> f64 {
    // `right` is `dz` (samples x w) or `W` (w x w).
    let (x, right) = product_operands(samples, w, if weight_gradient { samples } else { w });
    let (mut x_packed, mut right_packed) = (Bf16Matrix::default(), Bf16Matrix::default());
    let x_reads = if weight_gradient {
        Reads { left_transposed: true, ..Reads::default() }
    } else {
        Reads { left: true, ..Reads::default() }
    };
    let right_rows = if weight_gradient { samples } else { w };
    x_packed.pack_for(kernel, &x, samples, w, x_reads);
    right_packed.pack_for(kernel, &right, right_rows, w, Reads { right: true, ..Reads::default() });
    let layout = if weight_gradient { Layout::Transposed } else { Layout::Normal };
    let a = Operand { values: &x, layout, packed: Some(&x_packed) };
    let b = Operand { values: &right, layout: Layout::Normal, packed: Some(&right_packed) };
    let (m, k) = if weight_gradient { (w, samples) } else { (samples, w) };
    timed_gflops(m, k, w, reps, c_past_line, |c| {
        matmul_bf16(c, a, b, Product { m, k, n: w, accumulate: false }, Some(kernel))
    })
}
