//! `mipnerf figure`: the paper's figure 1 for evaluated runs.

use std::path::PathBuf;

use anyhow::Result;

use crate::figure;

/// The flags of `mipnerf figure`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// An evaluated run directory (repeat: e.g. NeRF, then Mip-NeRF).
    #[arg(long = "run", value_name = "RUN_DIR", required = true)]
    pub runs: Vec<PathBuf>,
    /// A column title per --run [default: the run directories' names].
    #[arg(long = "label")]
    pub labels: Vec<String>,
    /// The test view (its index at each scale).
    #[arg(long, default_value_t = 0)]
    pub view: usize,
    /// Cell width in pixels, 32 to 1024 (the height in the images' aspect ratio).
    #[arg(long, default_value_t = 192, value_parser = clap::value_parser!(u32).range(32..=1024))]
    pub cell: u32,
    /// Zoom window X,Y,SIDE as fractions of the image [default: where the first run's error
    /// exceeds the last run's the most at the coarsest scale].
    #[arg(long, value_name = "X,Y,SIDE", value_delimiter = ',', num_args = 3)]
    pub crop: Option<Vec<f64>>,
    /// The PNG to write.
    #[arg(long, value_name = "FILE.png")]
    pub out: PathBuf,
    /// Replace --out even when mipnerf did not write it; without it such a file is refused.
    #[arg(long)]
    pub overwrite: bool,
}

/// Draws the figure and prints each run's PSNR per scale.
///
/// # Errors
/// As [`figure::figure`].
pub fn run(a: Args) -> Result<()> {
    let Args { runs, labels, view, cell, crop, out, overwrite } = a;
    let crop = crop.map(|c| (c[0], c[1], c[2]));
    let args = figure::FigureArgs { runs, labels, view, cell, crop, out, overwrite };
    figure::figure(&args).map(|s| {
        for (label, psnr) in s.runs {
            let p: Vec<String> = psnr.iter().map(|p| format!("{p:.2}")).collect();
            println!("{label}: test PSNR per scale (full to coarsest) {}", p.join(" / "));
        }
        println!("wrote {}", args.out.display());
    })
}
