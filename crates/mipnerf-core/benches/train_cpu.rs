//! CPU training throughput: `cargo bench -p mipnerf-core --bench train_cpu`.
//!
//! Prints the machine's sgemm rate, then for the `paper` preset (1024 rays x (128 + 128) samples)
//! and the small shape (4 x 128 trunk, skip after layer 2, 1024 rays x (64 + 64) samples) the
//! training samples per second (forward, backward and Adam), the GFLOP/s of the MLP's matrix
//! products, and the fraction of the machine's bound (sgemm rate / MLP FLOP per sample).
#![allow(missing_docs)]

use mipnerf_core::bench::{sgemm_gflops, train_throughput};
use mipnerf_core::model::{Model, Preset};

fn main() {
    // `cargo bench` passes --bench; under `cargo test --all-targets` (no --bench) the benchmark
    // only proves it runs, at a small size.
    let quick = std::env::args().any(|a| a == "--quick") || !std::env::args().any(|a| a == "--bench");
    let threads = rayon::current_num_threads();
    let sgemm = sgemm_gflops(16_384, 256, 256, if quick { 2 } else { 7 });
    println!("threads: {threads}; sgemm 16384x256x256: {sgemm:.1} GFLOP/s");
    println!("| shape | rays x samples | params | s/step | samples/s | MLP GFLOP/s | bound samples/s | of bound |");
    println!("|---|---|---|---|---|---|---|---|");
    let (warm, steps) = if quick { (0, 1) } else { (1, 3) };
    for (name, cfg) in [("paper", Preset::Paper.config()), ("small (4x128, skip 2, 64+64)", Preset::Small.config())] {
        let flops = Model::new(cfg.clone()).map(|m| m.mlps()[0].flops_per_sample()).unwrap_or(f64::NAN);
        let r = train_throughput(name, cfg, if quick { 128 } else { 1024 }, warm, steps);
        let bound = sgemm * 1e9 / flops;
        println!(
            "| {} | {} x {} | {} | {:.3} | {:.0} | {:.1} | {:.0} | {:.0}% |",
            r.name,
            r.rays,
            r.samples_per_ray,
            r.params,
            r.seconds_per_step,
            r.samples_per_second,
            r.mlp_gflops,
            bound,
            100.0 * r.samples_per_second / bound
        );
    }
}
