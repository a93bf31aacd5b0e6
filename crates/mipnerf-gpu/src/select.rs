//! One way to open either backend, for apps and the CLI alike: [`open_backend`] takes a
//! [`BackendChoice`] (`Cpu`, `Gpu` or `Auto`) and a [`BackendSetup`] and returns the backend as a
//! `Box<dyn Backend>` with the reason for the choice, or one [`OpenError`].

use std::sync::Arc;

use mipnerf_core::backend::{Backend, BackendError, CpuBackend, TrainState};
use mipnerf_core::dataset::Dataset;
use mipnerf_core::model::Model;
use mipnerf_core::train::OptimConfig;

use crate::{AdapterChoice, GpuBackend, GpuContext, GpuError};

/// Where to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BackendChoice {
    /// The CPU reference path (multithreaded).
    Cpu,
    /// Any GPU adapter, software ones (lavapipe) included.
    Gpu,
    /// A hardware GPU when there is one and it runs the configuration, else the CPU.
    Auto,
}

/// What a backend is opened for.
#[derive(Clone, Debug)]
pub struct BackendSetup {
    /// The model.
    pub model: Model,
    /// Optimisation settings.
    pub optim: OptimConfig,
    /// Run seed.
    pub seed: u32,
    /// Parameters, moments and step to start from.
    pub state: TrainState,
    /// Training data and rays per batch (`None`: rendering only).
    pub data: Option<(Arc<Dataset>, usize)>,
    /// Rays per rendering chunk, the memory a render holds at once (`None`: the backend's
    /// default, on a GPU sized to the device). Images agree whatever the chunk, on the CPU up to
    /// rounding (see `CpuBackend::with_render_chunk`).
    pub render_chunk: Option<usize>,
    /// Which GPU adapter, and how much of its memory (ignored by the CPU).
    pub device: DeviceOptions,
}

/// The GPU a backend opens and what it may take of it.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct DeviceOptions {
    /// The adapter (`--adapter`); `None`: the one named by `WGPU_ADAPTER_NAME` if set, else the
    /// best one the backend choice allows.
    pub adapter: Option<AdapterChoice>,
    /// Device bytes the batch buffers may take (`--gpu-memory`); `None`: sized from the
    /// device's limits ([`GpuContext::memory_budget`]).
    pub memory_budget: Option<u64>,
}

/// A backend could not be opened.
#[derive(Debug, thiserror::Error)]
pub enum OpenError {
    /// The GPU path failed: no adapter, a device error, or a configuration it does not run.
    #[error(transparent)]
    Gpu(#[from] GpuError),
    /// The CPU path refused the setup.
    #[error(transparent)]
    Cpu(#[from] BackendError),
}

/// An opened backend and, for [`BackendChoice::Auto`], why it is the one.
pub struct OpenedBackend {
    /// The backend.
    pub backend: Box<dyn Backend>,
    /// Why `Auto` fell back to the CPU (`None` when it did not, or for `Cpu` and `Gpu`).
    pub fallback: Option<String>,
}

fn open_gpu(ctx: GpuContext, s: &BackendSetup) -> Result<GpuBackend, GpuError> {
    let ctx = ctx.with_memory_budget(s.device.memory_budget);
    let mut b = GpuBackend::new(ctx, s.model.clone(), s.optim.clone(), s.seed, s.state.clone())?;
    if let Some(rays) = s.render_chunk {
        b = b.with_render_chunk(rays);
    }
    match &s.data {
        Some((ds, batch)) => b.with_data(ds, *batch),
        None => Ok(b),
    }
}

fn open_cpu(s: BackendSetup) -> Result<Box<dyn Backend>, OpenError> {
    let mut b = CpuBackend::new(s.model, s.optim, s.seed, s.state)?;
    if let Some(rays) = s.render_chunk {
        b = b.with_render_chunk(rays);
    }
    if let Some((ds, batch)) = s.data {
        b = b.with_data(ds, batch);
    }
    Ok(Box::new(b))
}

/// Opens the backend `choice` for `setup`. `Auto` takes a hardware GPU when there is one and the
/// GPU path runs the configuration, else the CPU, and says why in [`OpenedBackend::fallback`]
/// (naming every adapter it passed over and why). An adapter named in `setup.device` (or by
/// `WGPU_ADAPTER_NAME`) is the one `Gpu` and `Auto` try, software or not.
///
/// # Errors
/// `Gpu` without a usable adapter or with a configuration or data the GPU path does not run; a
/// setup the CPU path refuses.
pub fn open_backend(choice: BackendChoice, setup: BackendSetup) -> Result<OpenedBackend, OpenError> {
    let named = setup.device.adapter.clone().or_else(|| AdapterChoice::explicit(None));
    let (backend, fallback): (Box<dyn Backend>, Option<String>) = match choice {
        BackendChoice::Cpu => (open_cpu(setup)?, None),
        BackendChoice::Gpu => {
            (Box::new(open_gpu(GpuContext::new(named.unwrap_or(AdapterChoice::Any))?, &setup)?), None)
        }
        BackendChoice::Auto => match GpuContext::new(named.unwrap_or(AdapterChoice::HardwareOnly)) {
            Ok(ctx) => {
                let name = ctx.adapter().name.clone();
                match open_gpu(ctx, &setup) {
                    Ok(g) => (Box::new(g), None),
                    Err(e) => (open_cpu(setup)?, Some(format!("{name} cannot run this: {e}"))),
                }
            }
            Err(GpuError::NoAdapter { wanted, passed_over }) => {
                let seen = if passed_over.is_empty() {
                    "wgpu saw no adapter".to_string()
                } else {
                    format!("passed over {}", passed_over.join("; "))
                };
                (open_cpu(setup)?, Some(format!("no GPU adapter found for {wanted} ({seen})")))
            }
            Err(e) => (open_cpu(setup)?, Some(format!("the GPU could not be opened: {e}"))),
        },
    };
    Ok(OpenedBackend { backend, fallback })
}
