//! `mipnerf info`: the version, every GPU adapter found, what `--backend auto` would choose, and
//! the CPU's threads and bf16 kernel with what `--precision auto` would choose.

use mipnerf_core::bf16::Bf16Support;

/// Prints the version, the adapters and the automatic choices.
pub fn run() {
    println!("mipnerf {}", env!("CARGO_PKG_VERSION"));
    let adapters = mipnerf_gpu::list_adapters();
    if adapters.is_empty() {
        println!("GPU adapters: none found (install a Vulkan driver, e.g. scripts/ensure-vulkan.sh)");
    } else {
        println!("GPU adapters ({}):", adapters.len());
        for (i, a) in adapters.iter().enumerate() {
            println!("  [{i}] {} | backend {} | type {} | driver {}", a.name, a.backend, a.device_type, a.driver);
        }
        println!("(choose one with --adapter INDEX or --adapter NAME, or the WGPU_ADAPTER_NAME environment variable)");
    }
    println!("--backend auto would use: {}", auto_choice(&adapters));
    // The CPU backend's threads and bf16 kernel, and what auto (the fast preset's precision)
    // takes: measured here as `train` measures it.
    let threads = rayon::current_num_threads();
    println!("CPU: {threads} thread{}; {}", if threads == 1 { "" } else { "s" }, Bf16Support::detect().describe());
    println!("--precision auto (the fast preset's) would use: {}", Bf16Support::auto().choice());
}

fn auto_choice(adapters: &[mipnerf_gpu::AdapterSummary]) -> String {
    use mipnerf_gpu::AdapterChoice;
    // An adapter named by WGPU_ADAPTER_NAME is the one auto tries, software or not.
    if let Some(named) = AdapterChoice::explicit(None) {
        let found = adapters.iter().enumerate().find(|(i, a)| named.takes(*i, a));
        return match found {
            Some((_, a)) => format!("gpu ({}, {}: named by {})", a.name, a.backend, AdapterChoice::ENV),
            None => format!("cpu ({} names no adapter here)", AdapterChoice::ENV),
        };
    }
    match adapters.iter().find(|a| !a.is_software) {
        Some(a) => format!("gpu ({}, {})", a.name, a.backend),
        None => "cpu (no hardware GPU found; software adapters are slower than the CPU path)".to_string(),
    }
}
