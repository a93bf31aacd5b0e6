//! `mipnerf compare`: PSNR, SSIM and LPIPS of two images.

use std::path::PathBuf;

use anyhow::Result;

use crate::lpips::LpipsWeights;

/// The flags of `mipnerf compare`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The reference image.
    pub a: PathBuf,
    /// The image compared with it.
    pub b: PathBuf,
    /// Print one JSON object (psnr, mse, ssim, lpips, lpips_net) instead of lines; psnr is null for
    /// identical images (mse 0), lpips and lpips_net when LPIPS was not computed.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub lpips: LpipsWeights,
    /// Fail (exit 1) when the LPIPS weights are not installed, instead of printing PSNR and
    /// SSIM alone.
    #[arg(long, conflicts_with = "no_lpips")]
    pub require_lpips: bool,
}

/// Compares the two images and prints the scores.
///
/// # Errors
/// As [`crate::eval::compare`].
pub fn run(a: Args) -> Result<()> {
    crate::eval::compare(&a.a, &a.b, a.json, &a.lpips, a.require_lpips)
}
