//! `mipnerf experiment`: run an experiment folder and rebuild its table.

use std::path::PathBuf;

use anyhow::Result;

use crate::config::Backend;
use crate::lpips::LpipsWeights;
use crate::session::Session;

/// The flags of `mipnerf experiment`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The experiment folder, e.g. experiments/multiscale-lego.
    pub dir: PathBuf,
    /// The dataset every row trains on (as experiment.toml describes).
    #[arg(long, value_name = "DIR", required_unless_present = "table_only")]
    pub data: Option<PathBuf>,
    /// Where the rows' run directories go (ROW/ inside it).
    #[arg(long, value_name = "DIR", required_unless_present = "table_only")]
    pub out: Option<PathBuf>,
    /// Only these rows (repeatable) [default: every row].
    #[arg(long, value_name = "ROW")]
    pub only: Vec<String>,
    /// Only rebuild the table from the rows' JSON files.
    #[arg(long)]
    pub table_only: bool,
    /// Evaluate on this backend rather than the one each row trained on: a run trained on a
    /// machine's GPU, copied to one without it (or without the LPIPS weights), is evaluated
    /// here on the CPU. The row's JSON keeps the training backend and names this one.
    #[arg(long, value_enum, value_name = "BACKEND")]
    pub eval_backend: Option<Backend>,
    #[command(flatten)]
    pub lpips: LpipsWeights,
}

/// Trains, evaluates and tabulates the rows.
///
/// # Errors
/// As [`crate::experiment::experiment`].
pub fn run(a: Args, session: &Session) -> Result<()> {
    let Args { dir, data, out, only, table_only, eval_backend, lpips } = a;
    let args = crate::experiment::ExperimentArgs { dir, data, out, only, table_only, eval_backend, lpips };
    crate::experiment::experiment(&args, session)
}
