//! `mipnerf eval`: render a split of a trained run and score it.

use std::path::PathBuf;

use anyhow::Result;

use super::SplitArg;
use crate::backend::RenderOnArgs;
use crate::lpips::LpipsWeights;
use crate::scores::Metrics;
use crate::session::Session;

/// The flags of `mipnerf eval`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The run directory.
    #[arg(long, value_name = "RUN_DIR")]
    pub run: PathBuf,
    /// Which split: the test split writes RUN_DIR/eval/, the others RUN_DIR/eval_train/ and
    /// RUN_DIR/eval_val/.
    #[arg(long, value_enum, default_value_t = SplitArg::Test)]
    pub split: SplitArg,
    #[command(flatten)]
    pub on: RenderOnArgs,
    #[command(flatten)]
    pub lpips: LpipsWeights,
}

/// Evaluates and prints the scores.
///
/// # Errors
/// As [`crate::eval::eval`].
pub fn run(a: Args, session: &Session) -> Result<()> {
    let device = a.on.device.options();
    let split = a.split.into();
    let on = crate::run::RunOn { backend: a.on.backend, precision: a.on.precision, device: &device };
    crate::eval::eval(&a.run, split, on, &a.lpips, session).map(|m| {
        println!("wrote {}", crate::run_dir::RunDir::new(&a.run).eval_metrics_of(split).display());
        print_scores(&m);
    })
}

/// Prints each scale's scores and the average error.
pub fn print_scores(m: &Metrics) {
    for s in &m.per_scale {
        let lp = s.lpips.map_or("LPIPS n/a".to_string(), |l| format!("LPIPS {l:.4}"));
        println!(
            "  scale {} ({} images): PSNR {:.2} dB, SSIM {:.4}, {lp}, avg error {:.4}",
            s.scale, s.images, s.psnr, s.ssim, s.avg_error
        );
    }
    let terms = if m.lpips_net.is_some() { "the paper's" } else { "two-term variant, without LPIPS" };
    println!("  average error over the scales ({terms}): {:.4}", m.avg_error);
}
