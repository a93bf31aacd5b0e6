//! `--backend cpu|gpu|auto`: the library's [`mipnerf_gpu::open_backend`], saying which backend
//! runs and why.

use std::sync::OnceLock;

use anyhow::{Context, Result};
use mipnerf_gpu::{AdapterChoice, BackendChoice, BackendSetup, DeviceOptions, open_backend};

use crate::config::Backend;

/// Opens the backend `choice` for `setup` and prints which one runs (and, for `auto`, why it
/// fell back to the CPU).
///
/// # Errors
/// `gpu` without a usable adapter, or with a configuration or data the GPU path does not support.
pub fn open(choice: Backend, setup: BackendSetup) -> Result<Box<dyn mipnerf_core::backend::Backend>> {
    let c = match choice {
        Backend::Cpu => BackendChoice::Cpu,
        Backend::Gpu => BackendChoice::Gpu,
        Backend::Auto => BackendChoice::Auto,
    };
    let opened =
        open_backend(c, setup).with_context(|| format!("--backend {}", format!("{choice:?}").to_lowercase()))?;
    if let Some(why) = &opened.fallback {
        eprintln!("backend auto: {why}; using the CPU");
    }
    eprintln!("backend: {}", opened.backend.describe());
    Ok(opened.backend)
}

/// The GPU flags of every command that takes `--backend`.
#[derive(clap::Args, Clone, Debug, Default, PartialEq, Eq)]
pub struct DeviceArgs {
    /// The GPU adapter to use: its index in `mipnerf info`'s list, or part of its name (any case).
    /// Default: the WGPU_ADAPTER_NAME environment variable if set, else the best adapter.
    #[arg(long, value_name = "NAME|INDEX")]
    pub adapter: Option<String>,
    /// Device memory, in MiB, the training batch's buffers may take (the render buffers a
    /// quarter); larger batches run in chunks. Default: sized from the device's limits.
    #[arg(long, value_name = "MIB", value_parser = clap::value_parser!(u64).range(16..=1_048_576))]
    pub gpu_memory: Option<u64>,
}

static DEVICE: OnceLock<DeviceArgs> = OnceLock::new();

/// Records the command's [`DeviceArgs`] for every backend it opens (the first call wins).
pub fn set_device_args(args: &DeviceArgs) {
    let _ = DEVICE.set(args.clone());
}

/// The [`DeviceOptions`] of the command's flags.
#[must_use]
pub fn device_options() -> DeviceOptions {
    let a = DEVICE.get().cloned().unwrap_or_default();
    DeviceOptions {
        adapter: AdapterChoice::explicit(a.adapter.as_deref()),
        memory_budget: a.gpu_memory.map(|mib| mib << 20),
    }
}
