//! One file per `mipnerf` command, as ripgrep lays its flags out: each holds the command's flags
//! (a clap `Args` struct, whose documentation is the command's help) and its `run`, which calls
//! the modules below the commands (`crate::eval`, `crate::render`, `crate::run`, ...). `main.rs`
//! only dispatches.

use clap::ValueEnum;
use mipnerf_core::dataset::Split;

pub mod bench;
pub mod check;
pub mod colmap;
pub mod compare;
pub mod convert;
pub mod demo;
pub mod eval;
pub mod experiment;
pub mod export;
pub mod fetch_lpips_weights;
pub mod figure;
pub mod info;
pub mod render;
pub mod train;
pub mod view;

/// `--split` values.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum SplitArg {
    /// Training views.
    Train,
    /// Validation views.
    Val,
    /// Test views.
    Test,
}

impl From<SplitArg> for Split {
    fn from(s: SplitArg) -> Self {
        match s {
            SplitArg::Train => Split::Train,
            SplitArg::Val => Split::Val,
            SplitArg::Test => Split::Test,
        }
    }
}
