//! `--backend cpu|gpu|auto`: the library's [`mipnerf_gpu::open_backend`], saying which backend
//! runs and why.

use crate::session::Session;
use anyhow::{Context, Result};
use mipnerf_gpu::{AdapterChoice, BackendChoice, BackendSetup, DeviceOptions, open_backend};

use mipnerf_core::bf16::{AutoPrecision, Bf16Support, Precision};

use crate::config::{Backend, PrecisionArg};

/// Opens the backend `choice` for `setup` with its MLP products in `precision`, and prints which
/// backend and precision run (and, for `auto`, why it fell back to the CPU or to f32). Returns
/// the backend and the precision that runs.
///
/// # Errors
/// `gpu` without a usable adapter, or with a configuration or data the GPU path does not support;
/// `--precision bf16` where it cannot run (a device backend, or a CPU with neither AMX-BF16 nor AVX-512 BF16).
pub fn open(
    choice: Backend,
    setup: BackendSetup,
    precision: PrecisionArg,
    session: &Session,
) -> Result<(Box<dyn mipnerf_core::backend::Backend>, Precision)> {
    let c = match choice {
        Backend::Cpu => BackendChoice::Cpu,
        Backend::Gpu => BackendChoice::Gpu,
        Backend::Auto => BackendChoice::Auto,
    };
    let opened =
        open_backend(c, setup).with_context(|| format!("--backend {}", format!("{choice:?}").to_lowercase()))?;
    if let Some(why) = &opened.fallback {
        session.say_once(crate::hints::in_flags(&format!("backend auto: {why}; using the CPU")));
    }
    let mut be = opened.backend;
    let ran = match precision {
        PrecisionArg::F32 => Precision::F32,
        PrecisionArg::Bf16 => {
            be.set_precision(Precision::Bf16)
                .with_context(|| format!("--precision bf16 on {} (use --precision f32 or auto)", be.describe()))?;
            Precision::Bf16
        }
        PrecisionArg::Auto => match Bf16Support::auto() {
            chosen @ AutoPrecision::F32(_) => {
                eprintln!("{}", chosen.describe());
                Precision::F32
            }
            chosen @ AutoPrecision::Bf16(_) => match be.set_precision(Precision::Bf16) {
                Ok(()) => {
                    eprintln!("{}", chosen.describe());
                    Precision::Bf16
                }
                Err(e) => {
                    eprintln!("precision auto: f32 ({e})");
                    Precision::F32
                }
            },
        },
    };
    session.say_once(format!("backend: {}", be.describe()));
    Ok((be, ran))
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

/// Where a trained run renders (`eval`, `render`): the backend, its GPU flags and the MLP's
/// precision.
#[derive(clap::Args, Clone, Debug)]
pub struct RenderOnArgs {
    /// Where to render: cpu, gpu (any adapter, software included), or auto (a hardware GPU if
    /// present, else the CPU).
    #[arg(long, value_enum, default_value_t = Backend::Auto)]
    pub backend: Backend,
    #[command(flatten)]
    pub device: DeviceArgs,
    /// Precision of the MLP's matrix products: f32, bf16 (AMX or AVX-512 BF16, CPU backend) or auto
    /// [default: the precision the run trained with].
    #[arg(long, value_enum)]
    pub precision: Option<PrecisionArg>,
}

impl DeviceArgs {
    /// The [`DeviceOptions`] these flags ask for.
    #[must_use]
    pub fn options(&self) -> DeviceOptions {
        DeviceOptions {
            adapter: AdapterChoice::explicit(self.adapter.as_deref()),
            memory_budget: self.gpu_memory.map(|mib| mib << 20),
        }
    }
}
