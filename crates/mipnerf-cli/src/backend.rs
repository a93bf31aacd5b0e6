//! `--backend cpu|gpu|auto`: the library's [`mipnerf_gpu::open_backend`], saying which backend
//! runs and why.

use anyhow::{Context, Result};
use mipnerf_gpu::{BackendChoice, BackendSetup, open_backend};

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
