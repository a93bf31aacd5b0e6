//! Picks and opens the backend of `--backend cpu|gpu|auto`, saying which it chose and why.

use std::sync::Arc;

use anyhow::{Context, Result};
use mipnerf_core::backend::{BackendError, CpuBackend, TrainState};
use mipnerf_core::data::Dataset;
use mipnerf_core::model::Model;
use mipnerf_core::train::OptimConfig;
use mipnerf_gpu::{AdapterChoice, GpuBackend, GpuContext, GpuError};

use crate::config::Backend;

/// What a backend is opened for.
pub struct Setup<'a> {
    /// The model.
    pub model: Model,
    /// Optimisation settings.
    pub optim: OptimConfig,
    /// Run seed.
    pub seed: u32,
    /// Parameters, moments and step to start from.
    pub state: TrainState,
    /// Training data and rays per batch (none for rendering).
    pub data: Option<(&'a Arc<Dataset>, usize)>,
}

fn open_gpu(ctx: GpuContext, s: &Setup<'_>) -> Result<GpuBackend, GpuError> {
    let b = GpuBackend::new(ctx, s.model.clone(), s.optim.clone(), s.seed, s.state.clone())?;
    match s.data {
        Some((ds, batch)) => b.with_data(ds, batch),
        None => Ok(b),
    }
}

fn open_cpu(s: Setup<'_>) -> Result<Box<dyn mipnerf_core::backend::Backend>> {
    let data = s.data.map(|(ds, batch)| (Arc::clone(ds), batch));
    let mut b = CpuBackend::new(s.model, s.optim, s.seed, s.state).map_err(|e: BackendError| anyhow::anyhow!(e))?;
    if let Some((ds, batch)) = data {
        b = b.with_data(ds, batch);
    }
    Ok(Box::new(b))
}

/// Opens the backend `choice` for `setup` and prints which one runs. `auto` takes a hardware
/// GPU when there is one and the GPU path supports the configuration, else the CPU, and says why.
///
/// # Errors
/// `gpu` without a usable adapter, or with a configuration or data the GPU path does not support.
pub fn open(choice: Backend, setup: Setup<'_>) -> Result<Box<dyn mipnerf_core::backend::Backend>> {
    let b: Box<dyn mipnerf_core::backend::Backend> = match choice {
        Backend::Cpu => open_cpu(setup)?,
        Backend::Gpu => {
            let ctx = GpuContext::new(AdapterChoice::Any).context("--backend gpu")?;
            Box::new(open_gpu(ctx, &setup).context("--backend gpu")?)
        }
        Backend::Auto => match GpuContext::new(AdapterChoice::HardwareOnly) {
            Ok(ctx) => {
                let name = ctx.adapter.name.clone();
                match open_gpu(ctx, &setup) {
                    Ok(g) => Box::new(g),
                    Err(e) => {
                        eprintln!("backend auto: {name} cannot run this: {e}; using the CPU");
                        open_cpu(setup)?
                    }
                }
            }
            Err(_) => {
                eprintln!("backend auto: no hardware GPU found; using the CPU");
                open_cpu(setup)?
            }
        },
    };
    eprintln!("backend: {}", b.describe());
    Ok(b)
}
