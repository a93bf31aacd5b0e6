//! A trained run, opened: its configuration, dataset, model and checkpoint ([`crate::run_dir`]
//! names its files; [`crate::training`] writes them).

use std::path::Path;

use anyhow::{Context, Result, bail};
use mipnerf_core::backend::TrainState;
use mipnerf_core::bf16::Precision;
use mipnerf_core::checkpoint::{self, Checkpoint};
use mipnerf_core::dataset::{Dataset, Split};
use mipnerf_core::model::Model;
use mipnerf_data::LoadOptions;

use crate::backend;
use crate::config::{Backend, PrecisionArg, TrainSettings};
use crate::session::Session;

use crate::run_dir::RunDir;

/// Loads `split` of the run's dataset with the run's settings.
///
/// # Errors
/// The dataset's errors, with the path.
pub fn load_split(s: &TrainSettings, split: Split) -> Result<Dataset> {
    let dir = s.data.as_ref().context("no dataset: pass --data DIR")?;
    if !dir.exists() {
        return Err(moved_dataset(dir));
    }
    let opts = LoadOptions {
        white_bkgd: s.white_bkgd,
        masks: s.masks.clone(),
        half_res: s.half_res.unwrap_or(false),
        llff_factor: s.llff_factor.unwrap_or(4),
        // (An unbounded scene is spherified, as `TrainSettings::resolved` says.)
        llff_spherify: s.spherify.unwrap_or(s.unbounded == Some(true)),
        spherify_radius: s.spherify_radius.map(f64::from),
        centers: s.centers(),
        unbounded: s.unbounded.unwrap_or(false),
    };
    Ok(mipnerf_data::load(dir, split, &opts)?)
}

/// The error for a run whose dataset folder `dir` is gone: where the run names it, and how to
/// point it at the dataset's new place.
#[must_use]
pub fn moved_dataset(dir: &Path) -> anyhow::Error {
    anyhow::anyhow!(
        "{}: no such dataset folder (a trained run reads the one its config.toml names as `data`: if the \
         dataset has moved, set `data` there to where it is now)",
        dir.display()
    )
}

/// Reads a run's resolved configuration.
///
/// # Errors
/// A missing or invalid `config.toml`.
pub fn read_config(run: &Path) -> Result<TrainSettings> {
    let path = RunDir::new(run).config();
    if !path.is_file() {
        bail!("{}: no such file; is {} a run directory made by `mipnerf train`?", path.display(), run.display());
    }
    let s = TrainSettings::from_file(&path)?;
    // A run saved before `precision` existed ran in f32.
    Ok(TrainSettings { precision: s.precision.or(Some(PrecisionArg::F32)), ..s })
}

/// Where a command runs a trained model: `--backend`, `--precision` (`None`: the run's own) and
/// the device options.
#[derive(Clone, Copy, Debug)]
pub struct RunOn<'a> {
    /// `--backend`.
    pub backend: Backend,
    /// `--precision`, or the run's.
    pub precision: Option<PrecisionArg>,
    /// The adapter and its limits.
    pub device: &'a mipnerf_gpu::DeviceOptions,
}

/// A backend holding a run's trained parameters, for rendering.
///
/// # Errors
/// A missing or mismatched checkpoint, or the backend's errors.
pub fn open_trained(
    run: &Path,
    s: &TrainSettings,
    on: RunOn<'_>,
    session: &Session,
) -> Result<(Box<dyn mipnerf_core::backend::Backend>, u64, Precision)> {
    let RunOn { backend: choice, precision, device } = on;
    let (model, ck) = load_trained(run, s, session)?;
    let step = ck.step;
    let setup = mipnerf_gpu::BackendSetup {
        model,
        optim: s.optim_config()?,
        seed: s.seed.unwrap_or(0),
        state: TrainState::from_checkpoint(ck),
        data: None,
        render_chunk: None,
        device: device.clone(),
    };
    let (be, ran) = backend::open(choice, setup, precision_for(s.precision, precision), session)?;
    Ok((be, step, ran))
}

/// The precision to open a saved run with: the flag when given, else the run's own, where bf16
/// means auto (bf16 where the backend and CPU run it faster than f32, f32 elsewhere, said in the
/// header; the two renders of one model agree within 0.1 dB in `tests/cli.rs`).
#[must_use]
pub fn precision_for(saved: Option<PrecisionArg>, flag: Option<PrecisionArg>) -> PrecisionArg {
    flag.unwrap_or(match saved {
        Some(PrecisionArg::Bf16) => PrecisionArg::Auto,
        Some(p) => p,
        None => PrecisionArg::F32,
    })
}

/// The `--precision` value of a precision that ran.
#[must_use]
pub fn precision_arg(p: Precision) -> PrecisionArg {
    match p {
        Precision::F32 => PrecisionArg::F32,
        Precision::Bf16 => PrecisionArg::Bf16,
    }
}

/// The model and trained parameters of a run.
///
/// # Errors
/// A missing or mismatched checkpoint.
pub fn load_trained(run: &Path, s: &TrainSettings, session: &Session) -> Result<(Model, Checkpoint)> {
    let model = Model::new(s.model_config()?)?;
    let ck = load_checkpoint(&RunDir::new(run).checkpoint(), &model, session)?;
    Ok((model, ck))
}

/// Reads a checkpoint, verifying its checksum; a file without one (written before checksums
/// existed, or edited) is refused unless `--allow-unverified` (`session.allow_unverified`), then
/// read as it is, which is said once per session and file.
///
/// # Errors
/// A missing, damaged, unverifiable or mismatched checkpoint.
pub fn load_checkpoint(path: &Path, model: &Model, session: &Session) -> Result<Checkpoint> {
    let (ck, integrity) = checkpoint::load_checked(path, model)?;
    if integrity == checkpoint::Integrity::Unchecked {
        if !session.allow_unverified {
            bail!(
                "{} has no checksum, so whether it is intact cannot be verified (it was written before checksums \
                 existed, or edited); pass --allow-unverified to read it anyway (the next save adds a checksum)",
                path.display()
            );
        }
        session.say_once(format!(
            "note: {} has no checksum and was read unverified (--allow-unverified; the next save adds one)",
            path.display()
        ));
    }
    Ok(ck)
}

/// The training time a run directory records ([`TRAIN_SECONDS`]): `None` where the file is
/// absent (a run from before it was written).
///
/// # Errors
/// The file cannot be read, or does not hold one finite, non-negative number of seconds (a
/// resumed run would otherwise start its time budget again and overwrite the record).
pub fn train_seconds(run: &Path) -> Result<Option<f64>> {
    let path = RunDir::new(run).train_seconds();
    let text = match mipnerf_core::io::read_regular_text(&path, mipnerf_core::io::cap::SETTINGS) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        r => r.with_context(|| format!("reading {}", path.display()))?,
    };
    match text.trim().parse::<f64>() {
        Ok(t) if t.is_finite() && t >= 0.0 => Ok(Some(t)),
        _ => bail!(
            "{}: damaged: expected the run's training time in seconds (one number), found {:?}; \
             write the seconds it has trained, or 0, to go on",
            path.display(),
            text.chars().take(40).collect::<String>()
        ),
    }
}

/// Whether two paths name the same file or folder (resolved through links, `..` and the working
/// directory; compared as absolute paths when one does not exist).
#[must_use]
pub fn same_path(a: &Path, b: &Path) -> bool {
    let resolve = |p: &Path| std::fs::canonicalize(p).or_else(|_| std::path::absolute(p)).unwrap_or(p.to_path_buf());
    resolve(a) == resolve(b)
}
