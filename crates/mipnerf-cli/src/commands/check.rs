//! `mipnerf check`: the GPU against the CPU reference on synthetic data.

use anyhow::Result;

use crate::backend::DeviceArgs;
use crate::check::CheckBackend;

/// The flags of `mipnerf check`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Which backend to check.
    #[arg(long, value_enum, default_value_t = CheckBackend::Gpu)]
    pub backend: CheckBackend,
    #[command(flatten)]
    pub device: DeviceArgs,
}

/// Runs the checks.
///
/// # Errors
/// A kernel or step that disagrees with the CPU, or no device.
pub fn run(a: Args) -> Result<()> {
    crate::check::check(a.backend, &a.device.options())
}
