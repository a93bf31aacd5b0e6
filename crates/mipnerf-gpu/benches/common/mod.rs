//! What the device benches share: their options and their adapter.

use mipnerf_gpu::{AdapterChoice, GpuContext};

/// The value after `name` on the command line, or `default`.
pub fn arg(name: &str, default: usize) -> usize {
    let args: Vec<String> = std::env::args().collect();
    args.iter().position(|a| a == name).and_then(|i| args.get(i + 1)).and_then(|v| v.parse().ok()).unwrap_or(default)
}

/// The best adapter found, or `None` (said on stdout: a machine without one has nothing to
/// measure).
pub fn context() -> Option<GpuContext> {
    match GpuContext::new(AdapterChoice::Any) {
        Ok(c) => Some(c),
        Err(e) => {
            println!("no GPU adapter, nothing to measure: {e}");
            None
        }
    }
}

/// Whether the full measurement runs: under `cargo bench` (`--bench`), not under
/// `cargo test --all-targets`, which only proves that the bench runs, at a small size.
pub fn full() -> bool {
    std::env::args().any(|a| a == "--bench")
}
