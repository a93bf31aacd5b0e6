//! The bf16 packing of the MLP's matrices on one thread, in nanoseconds per f32 value read:
//! `cargo bench -p mipnerf-core --bench packing -- --bench`.
//!
//! Each matrix is rounded to bf16 once and packed in the layouts its products read
//! ([`Bf16Matrix`], [`Reads`]): a layer's activation as the next layer's left operand and,
//! transposed, its weight gradient's; a gradient `dz` as the input gradient's left operand and
//! the weight gradient's right one. Training packs them in blocks of [`PACK_BLOCK_ROWS`] rows right
//! after the pass that writes them, so the block is in the L1 cache: the first rows of the table
//! pack such a block again and again. The others pack one chunk of the fast preset (64 rays x 16
//! samples) whole, from the L2 cache.
//!
//! The roles run in turn, round after round, and each cell is the fastest round: the cost of the
//! code, with the machine's drift (a shared machine) left out as far as it can be.
#![allow(missing_docs)]

use mipnerf_core::bench::product_operands;
use mipnerf_core::bf16::{Bf16Kernel, Bf16Matrix, PACK_BLOCK_ROWS, Reads};

fn main() {
    let quick = std::env::args().any(|a| a == "--quick") || !std::env::args().any(|a| a == "--bench");
    let rounds = if quick { 2 } else { 40 };
    let roles = [
        ("activation (left, left transposed)", Reads { left: true, left_transposed: true, ..Reads::default() }),
        ("gradient dz (left, right)", Reads { left: true, right: true, ..Reads::default() }),
        ("weight (right)", Reads { right: true, ..Reads::default() }),
    ];
    for kernel in Bf16Kernel::ALL {
        if let Err(why) = kernel.check() {
            println!("{}: not measured ({why})\n", kernel.name());
            continue;
        }
        println!("{}: ns per value, fastest of {rounds} rounds, one thread", kernel.name());
        println!("| rows x width | {} |", roles.iter().map(|(name, _)| *name).collect::<Vec<_>>().join(" | "));
        println!("|---|{}", "---|".repeat(roles.len()));
        for rows in [PACK_BLOCK_ROWS, 1024] {
            for width in [96, 128, 256] {
                let (x, _) = product_operands(rows, width, 1);
                let mut packed: Vec<Bf16Matrix> = roles.iter().map(|_| Bf16Matrix::default()).collect();
                // About 2 million values a round: long enough for the clock, short against drift.
                let reps = (2_000_000 / (rows * width)).max(4);
                let mut fastest = [f64::MAX; 3];
                for _ in 0..rounds {
                    for ((_, reads), (matrix, best)) in roles.iter().zip(packed.iter_mut().zip(&mut fastest)) {
                        let t = std::time::Instant::now();
                        for _ in 0..reps {
                            matrix.pack_for(kernel, std::hint::black_box(&x), rows, width, *reads);
                        }
                        *best = best.min(t.elapsed().as_secs_f64() / reps as f64);
                    }
                }
                let cells: Vec<String> =
                    fastest.iter().map(|s| format!("{:.3}", s * 1e9 / (rows * width) as f64)).collect();
                println!("| {rows} x {width} | {} |", cells.join(" | "));
            }
        }
        println!();
    }
}
