//! The bf16 kernel's rate over time, on every core at once: `cargo bench -p mipnerf-core --bench
//! bf16_rate -- --bench [--seconds S]`.
//!
//! One thread per core runs the fast preset's forward product (a training chunk of 1024 rows
//! through a 128-wide layer, both operands packed beforehand) back to back for `S` seconds (10 by
//! default) and prints its rate in each tenth of a second. On a shared machine (a cloud VM) a
//! core's rate can move between levels within seconds, independently of the other cores
//! (`docs/results/bf16-rate/`); this says whether a benchmark ran in a slow phase, and why timings
//! are only compared between runs made at the same time.
#![allow(missing_docs)]

use std::time::{Duration, Instant};

use mipnerf_core::bench::product_operands;
use mipnerf_core::bf16::{Bf16Kernel, Bf16Matrix, Bf16Support, Operand, Reads, matmul_bf16};
use mipnerf_core::linalg::{Layout, Product};

/// The product: one chunk of the fast preset (64 rays x 16 samples) through a 128-wide layer.
const M: usize = 1024;
const W: usize = 128;
/// The length of one window of the timeline.
const WINDOW: Duration = Duration::from_millis(100);

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let quick = !args.iter().any(|a| a == "--bench");
    let seconds: f64 = args
        .iter()
        .position(|a| a == "--seconds")
        .and_then(|i| args.get(i + 1)?.parse().ok())
        .unwrap_or(if quick { 0.2 } else { 10.0 });
    let support = Bf16Support::detect();
    println!("{}", support.describe());
    let Some(kernel) = support.kernel() else {
        println!("no bf16 kernel on this CPU: nothing to measure");
        return;
    };
    let threads = std::thread::available_parallelism().map_or(1, usize::from);
    println!(
        "{} GFLOP/s of the forward product {M} x {W} x {W} (operands packed beforehand), every {} ms for {seconds} s, one thread per core ({threads}) at once:",
        kernel.name(),
        WINDOW.as_millis()
    );
    let timelines: Vec<Vec<f64>> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..threads).map(|_| s.spawn(move || timeline(kernel, seconds))).collect();
        handles.into_iter().map(|h| h.join().unwrap_or_default()).collect()
    });
    println!("| thread | windows | min | median | max | windows under half the max |");
    println!("|---|---|---|---|---|---|");
    for (t, rates) in timelines.iter().enumerate() {
        let mut sorted = rates.clone();
        sorted.sort_by(f64::total_cmp);
        let (Some(&min), Some(&max)) = (sorted.first(), sorted.last()) else { continue };
        let slow = rates.iter().filter(|&&r| r < max / 2.0).count();
        println!("| {t} | {} | {min:.0} | {:.0} | {max:.0} | {slow} |", rates.len(), sorted[sorted.len() / 2]);
    }
    println!("\nThe timeline, one column per thread (GFLOP/s per window):");
    let longest = timelines.iter().map(Vec::len).max().unwrap_or(0);
    for w in 0..longest {
        let cells: Vec<String> =
            timelines.iter().map(|rates| rates.get(w).map_or_else(String::new, |r| format!("{r:.0}"))).collect();
        println!("{:5.1} s | {}", w as f64 * WINDOW.as_secs_f64(), cells.join(" | "));
    }
}

/// The rate of back-to-back products on this thread in each [`WINDOW`] of `seconds`.
fn timeline(kernel: Bf16Kernel, seconds: f64) -> Vec<f64> {
    let (x, weights) = product_operands(M, W, W);
    let (mut x_packed, mut w_packed) = (Bf16Matrix::default(), Bf16Matrix::default());
    x_packed.pack_for(kernel, &x, M, W, Reads { left: true, ..Reads::default() });
    w_packed.pack_for(kernel, &weights, W, W, Reads { right: true, ..Reads::default() });
    let a = Operand { values: &x, layout: Layout::Normal, packed: Some(&x_packed) };
    let b = Operand { values: &weights, layout: Layout::Normal, packed: Some(&w_packed) };
    // The output on a cache line, as the MLP's buffers are.
    let mut raw = vec![0.0f32; M * W + 16];
    let on_line = (64 - raw.as_ptr() as usize % 64) % 64 / 4;
    let c = &mut raw[on_line..on_line + M * W];
    let flops = 2.0 * (M * W * W) as f64;
    let end = Instant::now() + Duration::from_secs_f64(seconds);
    let mut rates = Vec::new();
    while Instant::now() < end {
        let (start, mut products) = (Instant::now(), 0u32);
        while start.elapsed() < WINDOW {
            matmul_bf16(c, a, b, Product { m: M, k: W, n: W, accumulate: false }, Some(kernel));
            products += 1;
        }
        rates.push(flops * f64::from(products) / start.elapsed().as_secs_f64() / 1e9);
    }
    rates
}
