//! `mipnerf fetch-lpips-weights`: install the LPIPS weights.

use std::path::PathBuf;

use anyhow::Result;

/// The flags of `mipnerf fetch-lpips-weights`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Where to install them [default: $MIPNERF_LPIPS_WEIGHTS, else the per-user cache
    /// directory, where eval and compare look].
    #[arg(long, value_name = "DIR")]
    pub dir: Option<PathBuf>,
}

/// Downloads, converts, checks and installs the weights.
///
/// # Errors
/// As [`crate::lpips::fetch`].
pub fn run(a: Args) -> Result<()> {
    crate::lpips::fetch(a.dir)
}
