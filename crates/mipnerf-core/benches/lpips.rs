//! LPIPS throughput: `cargo bench -p mipnerf-core --bench lpips`.
//!
//! Times LPIPS-VGG (and AlexNet) of an 800x800 pair and reports the effective GFLOP/s of the two
//! backbone passes beside the machine's sgemm rate. Reads the weights from ../shared/models/lpips
//! or $MIPNERF_LPIPS_WEIGHTS, and says so and stops when neither has them.
#![allow(missing_docs)]

use std::path::PathBuf;
use std::time::Instant;

use mipnerf_core::bench::sgemm_gflops;
use mipnerf_core::lpips::{Lpips, Net, backbone_flops};

fn main() {
    // `cargo bench` passes --bench; under `cargo test --all-targets` the benchmark only proves it
    // runs, at a small size.
    let quick = !std::env::args().any(|a| a == "--bench");
    let dir = std::env::var_os("MIPNERF_LPIPS_WEIGHTS")
        .map_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/models/lpips"), PathBuf::from);
    let side = if quick { 64 } else { 800 };
    let sgemm = sgemm_gflops(16_384, 256, 256, if quick { 1 } else { 5 });
    println!("threads: {}; sgemm 16384x256x256: {sgemm:.1} GFLOP/s", rayon::current_num_threads());
    println!("| net | pair | seconds | backbone GFLOP | effective GFLOP/s | of sgemm |");
    println!("|---|---|---|---|---|---|");
    for net in [Net::Vgg16, Net::Alex] {
        let path = dir.join(net.file_name());
        let l = match Lpips::load(&path, net) {
            Ok(l) => l,
            Err(e) => {
                println!("no LPIPS weights: {e}; get them with scripts/fetch-lpips-weights.sh");
                return;
            }
        };
        let a: Vec<f32> = (0..side * side * 3).map(|i| ((i * 7919) % 1000) as f32 / 1000.0).collect();
        let b: Vec<f32> = a.iter().map(|x| (x * 0.9 + 0.05).min(1.0)).collect();
        let reps = if quick { 1 } else { 3 };
        let mut best = f64::INFINITY;
        let mut d = 0.0;
        for _ in 0..reps {
            let t = Instant::now();
            d = l.distance(&a, &b, side, side).unwrap_or(f64::NAN);
            best = best.min(t.elapsed().as_secs_f64());
        }
        assert!(d.is_finite() && d > 0.0, "LPIPS of the benchmark pair: {d}");
        let gflop = 2.0 * backbone_flops(net, side, side) / 1e9;
        println!(
            "| {} | {side}x{side} | {best:.2} | {gflop:.1} | {:.1} | {:.0}% |",
            net.name(),
            gflop / best,
            100.0 * gflop / best / sgemm
        );
    }
}
