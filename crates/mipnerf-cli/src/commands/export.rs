//! `mipnerf export`: a trained run's geometry as PLY.

use std::path::PathBuf;

use anyhow::Result;

use crate::export;
use crate::session::Session;

/// The flags of `mipnerf export`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The run directory.
    #[arg(long, value_name = "RUN_DIR")]
    pub run: PathBuf,
    /// Write the mesh here (binary PLY: positions, normals, colours, triangles).
    #[arg(long, value_name = "FILE.ply")]
    pub mesh: Option<PathBuf>,
    /// Write the points here (binary PLY: positions, colours).
    #[arg(long, value_name = "FILE.ply")]
    pub points: Option<PathBuf>,
    /// Grid cells along each side of the box the density is sampled in.
    #[arg(long, default_value_t = export::DEFAULT_RESOLUTION)]
    pub resolution: usize,
    /// The density (opacity per world unit) the mesh's surface follows.
    #[arg(long, default_value_t = export::DEFAULT_THRESHOLD)]
    pub threshold: f32,
    /// Half the side of the box around the origin [default: the run's occupancy grid's, else
    /// from the cameras].
    #[arg(long, value_name = "B")]
    pub bound: Option<f32>,
    /// Training rays (random pixels of the training views) the points come from.
    #[arg(long, default_value_t = export::DEFAULT_POINTS)]
    pub count: usize,
    /// The opacity a ray must reach for its expected depth to become a point.
    #[arg(long, default_value_t = export::DEFAULT_MIN_OPACITY)]
    pub min_opacity: f32,
    /// Replace files that exist.
    #[arg(long)]
    pub overwrite: bool,
}

/// Writes the mesh and/or the points.
///
/// # Errors
/// As [`export::export`].
pub fn run(a: Args, session: &Session) -> Result<()> {
    let Args { run, mesh, points, resolution, threshold, bound, count, min_opacity, overwrite } = a;
    let args = export::ExportArgs { run, mesh, points, resolution, threshold, bound, count, min_opacity, overwrite };
    export::export(&args, session)
}
