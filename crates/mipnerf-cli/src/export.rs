//! `mipnerf export`: a trained run's geometry as PLY files for 3D tools: a triangle mesh of its
//! density field (marching cubes, vertex colours from the model) and coloured points at the
//! expected depth of its training rays (`mipnerf_core::export`).

use crate::session::Session;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use glam::Vec3;
use mipnerf_core::dataset::{BatchDraw, Split};
use mipnerf_core::export;

use crate::run::{load_split, load_trained, read_config};

/// Grid cells along the longest side of the box by default.
pub const DEFAULT_RESOLUTION: usize = 128;
/// The density (opacity per world unit) the mesh follows by default: a tenth of a world unit of
/// matter at this density is 63% opaque. Chosen on two runs (`experiments/export-threshold/`,
/// `docs/results/export/thresholds.txt`): the demo scene's sphere after 1,500 steps, whose mesh
/// lies within 0.048 / 0.098 / 0.55 of the true sphere at 5 / 10 / 25 (the surface sinks inside
/// as the threshold rises), and lego after 5 minutes, with 19 / 8 / 0 of about 21,000 vertices
/// outside the object (floaters). 10 keeps the surface where it is at the cost of a few floaters.
pub const DEFAULT_THRESHOLD: f32 = 10.0;
/// Training rays the points are taken from by default.
pub const DEFAULT_POINTS: usize = 200_000;
/// The opacity a ray must reach for its expected depth to be a point.
pub const DEFAULT_MIN_OPACITY: f32 = 0.5;

/// What `mipnerf export` was asked for.
#[derive(Clone, Debug)]
pub struct ExportArgs {
    /// The run directory.
    pub run: PathBuf,
    /// Where to write the mesh.
    pub mesh: Option<PathBuf>,
    /// Where to write the points.
    pub points: Option<PathBuf>,
    /// Grid cells along the box's longest side.
    pub resolution: usize,
    /// Density of the surface.
    pub threshold: f32,
    /// Half the side of the box around the origin.
    pub bound: Option<f32>,
    /// Training rays for the points.
    pub count: usize,
    /// Opacity a ray must reach to give a point.
    pub min_opacity: f32,
    /// Replace existing files.
    pub overwrite: bool,
}

/// Exports what `a` asks for, saying what it wrote.
///
/// # Errors
/// Bad values, a run that cannot be read, a forward-facing (NDC) run, existing outputs without
/// `--overwrite`, and I/O errors, each naming the file or flag.
pub fn export(a: &ExportArgs, session: &Session) -> Result<()> {
    if a.mesh.is_none() && a.points.is_none() {
        bail!("nothing to export: pass --mesh FILE.ply and/or --points FILE.ply");
    }
    if !(8..=1024).contains(&a.resolution) {
        bail!("--resolution must be between 8 and 1024 cells, got {}", a.resolution);
    }
    if !(a.threshold.is_finite() && a.threshold > 0.0) {
        bail!("--threshold must be a positive density, got {}", a.threshold);
    }
    if !(1..=10_000_000).contains(&a.count) {
        bail!("--count must be between 1 and 10000000 rays, got {}", a.count);
    }
    if !(a.min_opacity > 0.0 && a.min_opacity <= 1.0) {
        bail!("--min-opacity must be in (0, 1], got {}", a.min_opacity);
    }
    if let Some(b) = a.bound
        && !(b.is_finite() && b > 0.0)
    {
        bail!("--bound must be a positive half side, got {b}");
    }
    for (flag, path) in [("--mesh", &a.mesh), ("--points", &a.points)] {
        if let Some(path) = path {
            check_output(flag, path, a.overwrite)?;
        }
    }
    if let (Some(mesh), Some(points)) = (&a.mesh, &a.points)
        && same_file(mesh, points)
    {
        bail!("--mesh and --points name the same file ({}); give each its own", mesh.display());
    }
    let s = read_config(&a.run)?;
    let (model, ck) = load_trained(&a.run, &s, session)?;
    let ds = load_split(&s, Split::Train)?;
    if ds.ndc.is_some() {
        bail!(
            "{}: a forward-facing scene trains in NDC space, where its geometry is not the world's; \
             train it with --spherify to export a mesh or points",
            a.run.display()
        );
    }
    let bound = match a.bound.or(ck.occupancy.as_ref().map(|g| g.config.bound)) {
        Some(b) => b,
        None => mipnerf_core::occupancy::auto_bound(&ds)
            .with_context(|| format!("{}: no scene bound from the cameras; pass --bound B", a.run.display()))?,
    };
    if let Some(path) = &a.mesh {
        let t = std::time::Instant::now();
        let region = (Vec3::splat(-bound), Vec3::splat(bound));
        let nodes = export::mesh_nodes(region.1 - region.0, a.resolution);
        mipnerf_core::memory::check(
            nodes.saturating_mul(export::MESH_BYTES_PER_NODE),
            &format!("a mesh at --resolution {} ({nodes} grid nodes)", a.resolution),
        )
        .map_err(|e| anyhow::anyhow!("{e}; choose a lower --resolution"))?;
        let sampled = export::sampled_space(&ds, ck.occupancy.as_ref());
        let mesh = export::extract_mesh(&model, &ck.params, region, a.resolution, a.threshold, &sampled);
        if mesh.triangles.is_empty() {
            bail!(
                "no surface at density {} in [-{bound}, {bound}]^3 (step {} of {}); try a lower --threshold or a larger --bound",
                a.threshold,
                ck.step,
                a.run.display()
            );
        }
        export::write_mesh_ply(path, &mesh).with_context(|| format!("writing {}", path.display()))?;
        println!(
            "mesh: {} vertices, {} triangles (marching cubes of the density at {} over [-{bound:.3}, {bound:.3}]^3, {} cells a side, {:.1}s) -> {}",
            mesh.vertices.len(),
            mesh.triangles.len(),
            a.threshold,
            a.resolution,
            t.elapsed().as_secs_f64(),
            path.display()
        );
    }
    if let Some(path) = &a.points {
        if model.rays_per_pixel() != 1 {
            bail!("{}: a supersampled model renders pixels, not rays; export its --mesh instead", a.run.display());
        }
        let t = std::time::Instant::now();
        let (mut rays, mut targets) = (Vec::new(), Vec::new());
        ds.sample_batch(BatchDraw::new(a.count, s.seed.unwrap_or(0), 0), &mut rays, &mut targets);
        let (points, colors) = export::ray_points(&model, &ck.params, &rays, ck.occupancy.as_ref(), a.min_opacity);
        export::write_points_ply(path, &points, &colors).with_context(|| format!("writing {}", path.display()))?;
        println!(
            "points: {} of {} training rays reach opacity {} ({:.1}s) -> {}",
            points.len(),
            rays.len(),
            a.min_opacity,
            t.elapsed().as_secs_f64(),
            path.display()
        );
    }
    Ok(())
}

/// Refuses an output whose folder does not exist, and one that exists unless it is a PLY file
/// export wrote and `overwrite` is set: a folder, a link, a device or any other file is never
/// replaced, `--overwrite` or not.
fn check_output(flag: &str, path: &Path, overwrite: bool) -> Result<()> {
    if let Ok(meta) = std::fs::symlink_metadata(path) {
        let kind = meta.file_type();
        if !kind.is_file() {
            let what = if kind.is_dir() {
                "a folder"
            } else if kind.is_symlink() {
                "a symbolic link"
            } else {
                "not a regular file (a device, pipe or socket)"
            };
            bail!(
                "{flag} {} is {what}; export writes only a new file or one it wrote, --overwrite or not",
                path.display()
            );
        }
        if !export::written_by_export(path) {
            bail!(
                "{flag} {} exists and is not a PLY file mipnerf export wrote; it is left as it is (choose another name)",
                path.display()
            );
        }
        if !overwrite {
            bail!("{flag} {} exists; pass --overwrite to replace it", path.display());
        }
    }
    let dir = mipnerf_core::io::parent_dir(path);
    if !dir.is_dir() {
        bail!("{}: no such folder for {}", dir.display(), path.display());
    }
    Ok(())
}

/// Whether two output paths name one file: the same name in the same folder once the folders'
/// links and `..` are resolved (both folders exist: [`check_output`] ran first).
fn same_file(a: &Path, b: &Path) -> bool {
    let resolved = |p: &Path| {
        std::fs::canonicalize(mipnerf_core::io::parent_dir(p)).ok().map(|d| d.join(p.file_name().unwrap_or_default()))
    };
    a == b || matches!((resolved(a), resolved(b)), (Some(x), Some(y)) if x == y)
}
