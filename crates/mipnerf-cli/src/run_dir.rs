//! A run directory's layout: the one place that names its files and folders. Every command that
//! reads or writes a run (train, eval, render, view, experiment, figure) asks [`RunDir`] for the
//! path, so a change of layout is a change here.

use std::path::{Path, PathBuf};

use anyhow::Result;
use mipnerf_core::dataset::Split;

/// The resolved configuration of the run.
pub const CONFIG: &str = "config.toml";
/// The latest checkpoint.
pub const CHECKPOINT: &str = "checkpoint.safetensors";
/// Wall-clock seconds of training up to the checkpoint's step, over every segment of a resumed
/// run; rewritten after each checkpoint.
pub const TRAIN_SECONDS: &str = "train_seconds.txt";
/// Training metrics, one row every `log_every` steps ([`crate::metrics_csv`]).
pub const METRICS_CSV: &str = "metrics.csv";
/// The lock file, held by the `train` that writes the run ([`crate::outputs::lock_folder`]).
pub use mipnerf_core::io::LOCK;
/// The folder `eval` writes for the test split (`eval_train` and `eval_val` for the others, so
/// that evaluating another split never replaces the test scores).
pub const EVAL: &str = "eval";
/// Where `--val-every` writes its latest renders (`scale{j}.png`: the render on the left, the
/// test image on the right).
pub const VAL: &str = "val";
/// Copies of the run at fixed training times (`train --snapshots`).
pub const SNAPSHOTS: &str = "snapshots";

/// A run directory, borrowed: the paths of its files.
#[derive(Clone, Copy, Debug)]
pub struct RunDir<'a>(&'a Path);

impl<'a> RunDir<'a> {
    /// The run directory at `path`.
    #[must_use]
    pub fn new(path: &'a Path) -> Self {
        Self(path)
    }

    /// `config.toml`.
    #[must_use]
    pub fn config(self) -> PathBuf {
        self.0.join(CONFIG)
    }

    /// The latest checkpoint.
    #[must_use]
    pub fn checkpoint(self) -> PathBuf {
        self.0.join(CHECKPOINT)
    }

    /// The training seconds file.
    #[must_use]
    pub fn train_seconds(self) -> PathBuf {
        self.0.join(TRAIN_SECONDS)
    }

    /// `metrics.csv`.
    #[must_use]
    pub fn metrics_csv(self) -> PathBuf {
        self.0.join(METRICS_CSV)
    }

    /// The finished evaluation's folder (of the test split).
    #[must_use]
    pub fn eval(self) -> PathBuf {
        self.eval_of(Split::Test)
    }

    /// The finished evaluation's folder of `split`: `eval/` for the test split, `eval_train/`
    /// and `eval_val/` for the others.
    #[must_use]
    pub fn eval_of(self, split: Split) -> PathBuf {
        match split {
            Split::Test => self.0.join(EVAL),
            other => self.0.join(format!("{EVAL}_{}", other.name())),
        }
    }

    /// The evaluation's folder of `split` while it is written: its finished folder's name with
    /// `.partial` (`eval.partial/`, `eval_train.partial/`, `eval_val.partial/`).
    #[must_use]
    pub fn eval_partial_of(self, split: Split) -> PathBuf {
        self.eval_of(split).with_extension("partial")
    }

    /// The evaluation's scores (of the test split).
    #[must_use]
    pub fn eval_metrics(self) -> PathBuf {
        self.eval_metrics_of(Split::Test)
    }

    /// The evaluation's scores of `split`.
    #[must_use]
    pub fn eval_metrics_of(self, split: Split) -> PathBuf {
        self.eval_of(split).join("metrics.json")
    }

    /// The latest validation renders.
    #[must_use]
    pub fn val(self) -> PathBuf {
        self.0.join(VAL)
    }

    /// The folder of the snapshots.
    #[must_use]
    pub fn snapshots(self) -> PathBuf {
        self.0.join(SNAPSHOTS)
    }

    /// The snapshot taken at `seconds` of training.
    #[must_use]
    pub fn snapshot(self, seconds: u64) -> PathBuf {
        self.snapshots().join(format!("{seconds:05}s"))
    }

    /// Takes the exclusive lock of the run for the life of the returned file, so that two `train`
    /// processes never write one run directory ([`crate::outputs::lock_folder`]). Readers (`eval`,
    /// `render`) take no lock: every file they read is replaced atomically.
    ///
    /// # Errors
    /// Another process holds the lock (the error names it), or the file cannot be made.
    pub fn lock(self) -> Result<std::fs::File> {
        crate::outputs::lock_folder(self.0, "train", "--out")
    }
}
