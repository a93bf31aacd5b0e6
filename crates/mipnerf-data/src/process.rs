//! The process step (`mipnerf colmap`): from a COLMAP workspace (the photos in `images/`, the
//! mapper's models in `sparse/N/`), or a capture in nerfstudio's or Instant-NGP's
//! `transforms.json` form read as one model ([`crate::nerfstudio`]), to a dataset the trainer
//! reads.
//!
//! 1. Every model in `sparse/` is counted and the one with the most registered photos is taken
//!    (COLMAP numbers its models as it finds them, not by size).
//! 2. Fewer registered photos than [`ProcessOptions::min_views`] is an error, fewer than
//!    [`ProcessOptions::recommended_views`] a warning.
//! 3. The photos are undistorted in Rust ([`crate::undistort`]) to one centred pinhole.
//! 4. They are box-filtered by the integer factor that brings their longer side to at most
//!    [`ProcessOptions::max_size`], and written as PNGs to `images_{factor}/`, numbered in name
//!    order, with LLFF's `poses_bounds.npy` for the undistorted camera (LLFF's `imgs2poses`,
//!    [`crate::colmap::poses_bounds`]), so `train --data OUT --llff-factor {factor}` reads them,
//!    holding out every 8th photo for testing as LLFF does.
//!
//! A step that stops part-way leaves no `poses_bounds.npy`, so a half-written dataset never loads:
//! the images go to a temporary folder renamed into place, and the index file is written last.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use rayon::prelude::*;

use crate::DataError;
use crate::colmap::{self, ColmapCamera, ColmapModel};
use crate::focal::{self, FocalCheck};
use crate::llff::LLFF_HOLD;
use crate::undistort::{self, LensCamera, Pinhole};

/// Registered photos below which the step refuses: a radiance field from fewer views is a guess.
pub const MIN_REGISTERED_VIEWS: usize = 8;
/// Registered photos below which the step warns (NeRF papers' own object captures have 50 to 100).
pub const RECOMMENDED_VIEWS: usize = 25;
/// The longest side, in pixels, of the processed images when none is asked for.
pub const DEFAULT_MAX_SIZE: u32 = 800;
/// The mean resultant length of the cameras' viewing directions below which a capture counts as
/// "all around the object" and `--spherify` is recommended (1 when all look the same way; a
/// half circle of cameras gives 2/π ≈ 0.64).
pub const ALL_AROUND_BELOW: f64 = 0.9;

/// The share of the photos' border pixels that must be near white (or near black) for the
/// photos to count as taken on a plain backdrop of that colour.
pub const BACKDROP_SHARE: f64 = 0.9;
/// How near: every channel at least this fraction of full scale (white), or at most one minus it
/// (black).
pub const BACKDROP_LEVEL: f64 = 0.9;

/// A plain backdrop the photos were taken on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Backdrop {
    /// White.
    White,
    /// Black.
    Black,
}

/// What the process step is asked to do.
#[derive(Clone, Debug, PartialEq)]
pub struct ProcessOptions {
    /// The longest side of the written images, at most (pixels; 0: full size).
    pub max_size: u32,
    /// Refuse below this many registered photos.
    pub min_views: usize,
    /// Warn below this many registered photos.
    pub recommended_views: usize,
    /// Replace a dataset already in the output folder.
    pub overwrite: bool,
    /// Registered photos to leave out (by file name, as COLMAP names them), such as those
    /// [`suspect_photos`] names.
    pub exclude: Vec<String>,
    /// A folder of foreground masks, one per photo (named as the photo, PNG or JPEG, white = the
    /// object; [`crate::masks`]), carried through the undistortion and the downscaling to
    /// `masks_{factor}/` beside the images, named as they are, for `train --masks`.
    pub masks: Option<PathBuf>,
}

impl Default for ProcessOptions {
    fn default() -> Self {
        Self {
            max_size: DEFAULT_MAX_SIZE,
            min_views: MIN_REGISTERED_VIEWS,
            recommended_views: RECOMMENDED_VIEWS,
            overwrite: false,
            exclude: Vec::new(),
            masks: None,
        }
    }
}

/// What the process step did, for the user.
#[derive(Clone, Debug)]
pub struct ProcessReport {
    /// A COLMAP workspace or a `transforms.json` capture.
    pub source: SourceKind,
    /// Every model found: `(N, registered photos)`.
    pub models: Vec<(u32, usize)>,
    /// The model taken (a capture: its `transforms.json`).
    pub model_dir: PathBuf,
    /// Its registered photos.
    pub registered: usize,
    /// The photos in the workspace's `images/` (a capture: in its frames' folders).
    pub photos: usize,
    /// The camera's COLMAP model name (a capture: PINHOLE, or OPENCV with distortion).
    pub camera_model: &'static str,
    /// The camera as COLMAP estimated it.
    pub lens: LensCamera,
    /// The undistorted pinhole at full size.
    pub pinhole: Pinhole,
    /// The factor the images were box-filtered by (the trainer's `--llff-factor`).
    pub factor: u32,
    /// The written images' size.
    pub size: (u32, u32),
    /// The nearest near bound and the farthest far bound of the photos, in COLMAP's units.
    pub bounds: (f64, f64),
    /// Whether the cameras surround the scene ([`ALL_AROUND_BELOW`]).
    pub all_around: bool,
    /// The photos held out for testing (every 8th in name order).
    pub held_out: Vec<String>,
    /// The plain backdrop the photos' borders show, if they show one ([`BACKDROP_SHARE`]).
    pub backdrop: Option<Backdrop>,
    /// The shares of the border pixels that are near white and near black.
    pub border_shares: (f64, f64),
    /// Photos whose reconstruction looks wrong ([`suspect_photos`]), with why.
    pub suspects: Vec<Suspect>,
    /// The photos left out (`ProcessOptions::exclude`).
    pub excluded: Vec<String>,
    /// COLMAP's focal length against the one the photos' EXIF implies ([`focal::check_focal`]);
    /// `None` when no photo has a usable EXIF focal length.
    pub focal: Option<FocalCheck>,
    /// The written masks (`masks_{factor}/`), when `ProcessOptions::masks` gave some.
    pub masks: Option<PathBuf>,
    /// Warnings for the user.
    pub warnings: Vec<String>,
}

/// A photo whose reconstruction looks wrong, and why.
#[derive(Clone, Debug, PartialEq)]
pub struct Suspect {
    /// Its file name.
    pub name: String,
    /// What is wrong with it, in a few words with the numbers.
    pub why: String,
}

/// A photo seeing fewer 3D points than this share of the median photo's is named.
pub const FEW_POINTS_SHARE: f64 = 0.1;

/// A photo whose points' mean reprojection error exceeds this many times the median photo's (and
/// [`HIGH_ERROR_MIN_PX`]) is named.
pub const HIGH_ERROR_FACTOR: f64 = 2.0;

/// Reprojection errors below this (pixels) are never named.
pub const HIGH_ERROR_MIN_PX: f64 = 1.0;

/// The capture's path around a photo: this many photos on each side of it in name order (the
/// order a camera numbers them in).
pub const PATH_WINDOW: usize = 4;

/// A photo looking more than this many degrees away from its neighbours on the path (and
/// [`PATH_TURN_FACTOR`] times the path's typical turn between photos) is named.
pub const PATH_TURN_DEGREES: f64 = 30.0;

/// See [`PATH_TURN_DEGREES`].
pub const PATH_TURN_FACTOR: f64 = 4.0;

/// A photo standing more than this many times the path's typical step between photos away from
/// its neighbours is named.
pub const PATH_SHIFT_FACTOR: f64 = 4.0;

/// The photos of `model` that COLMAP may have got wrong, in name order:
/// - a pose that disagrees with its neighbours on the capture's path (the [`PATH_WINDOW`]
///   photos on each side in name order): its angle to each neighbour, less the path's median
///   turn between consecutive photos times their distance in photos, has a median over the
///   neighbours above [`PATH_TURN_DEGREES`] (and [`PATH_TURN_FACTOR`] median turns); or the same
///   of its distance to them, in median steps, above [`PATH_SHIFT_FACTOR`] (medians, so that a
///   few wrong neighbours do not mark a right photo, and a few wrong photos in a row are each
///   marked);
/// - seeing fewer than [`FEW_POINTS_SHARE`] of the median photo's 3D points;
/// - its points' mean reprojection error above [`HIGH_ERROR_FACTOR`] times the median photo's
///   and [`HIGH_ERROR_MIN_PX`].
#[must_use]
pub fn suspect_photos(model: &colmap::ColmapModel) -> Vec<Suspect> {
    use glam::{DMat3, DQuat, DVec3};
    let mut order: Vec<usize> = (0..model.images.len()).collect();
    order.sort_by(|&a, &b| model.images[a].name.cmp(&model.images[b].name));
    let n = order.len();
    // Centre and viewing direction of each photo, in name order.
    let poses: Vec<(DVec3, DVec3)> = order
        .iter()
        .map(|&i| {
            let im = &model.images[i];
            let [qw, qx, qy, qz] = im.qvec;
            let r = DMat3::from_quat(DQuat::from_xyzw(qx, qy, qz, qw).normalize());
            let rt = r.transpose();
            (-(rt * DVec3::from_array(im.tvec)), rt.z_axis.normalize())
        })
        .collect();
    let slot: std::collections::HashMap<u32, usize> =
        order.iter().enumerate().map(|(k, &i)| (model.images[i].id, k)).collect();
    let (mut points, mut error_sum) = (vec![0usize; n], vec![0.0f64; n]);
    for p in &model.points {
        let mut seen = std::collections::HashSet::new();
        for id in &p.image_ids {
            if let Some(&k) = slot.get(id)
                && seen.insert(k)
            {
                points[k] += 1;
                error_sum[k] += p.error;
            }
        }
    }
    // The median (the mean of the middle two of an even count).
    let median = |mut v: Vec<f64>| -> f64 {
        if v.is_empty() {
            return 0.0;
        }
        v.sort_by(f64::total_cmp);
        let m = v.len() / 2;
        if v.len().is_multiple_of(2) { 0.5 * (v[m - 1] + v[m]) } else { v[m] }
    };
    let angle = |a: DVec3, b: DVec3| a.dot(b).clamp(-1.0, 1.0).acos().to_degrees();
    let typical_turn = median(poses.windows(2).map(|w| angle(w[0].1, w[1].1)).collect());
    let typical_step = median(poses.windows(2).map(|w| (w[0].0 - w[1].0).length()).collect());
    let median_points = median(points.iter().map(|&c| c as f64).collect());
    let mean_error: Vec<f64> =
        (0..n).map(|k| if points[k] > 0 { error_sum[k] / points[k] as f64 } else { 0.0 }).collect();
    let median_error = median(mean_error.clone());
    let mut out = Vec::new();
    for k in 0..n {
        let mut why = Vec::new();
        let around: Vec<usize> =
            (k.saturating_sub(PATH_WINDOW)..(k + PATH_WINDOW + 1).min(n)).filter(|&j| j != k).collect();
        if around.len() >= 2 {
            // How much farther the photo turns from (and stands from) each neighbour than the
            // path's typical turn (step) times their distance in photos, the median over the
            // neighbours: about 0 on a smooth path, whatever its own curve.
            let gap = |j: usize| k.abs_diff(j) as f64;
            let turn = median(around.iter().map(|&j| angle(poses[k].1, poses[j].1) - gap(j) * typical_turn).collect());
            let shift =
                median(around.iter().map(|&j| (poses[k].0 - poses[j].0).length() - gap(j) * typical_step).collect());
            if turn > PATH_TURN_DEGREES.max(PATH_TURN_FACTOR * typical_turn) {
                why.push(format!(
                    "looks {turn:.0} degrees away from its neighbours on the path (they turn {typical_turn:.1} degrees from photo to photo)"
                ));
            }
            if typical_step > 0.0 && shift > PATH_SHIFT_FACTOR * typical_step {
                why.push(format!(
                    "stands {:.1} steps away from its neighbours on the path (a step: {typical_step:.3}, the median between photos)",
                    shift / typical_step
                ));
            }
        }
        if (points[k] as f64) < FEW_POINTS_SHARE * median_points {
            why.push(format!("sees {} 3D points (the median photo {median_points:.0})", points[k]));
        }
        if mean_error[k] > HIGH_ERROR_MIN_PX.max(HIGH_ERROR_FACTOR * median_error) {
            why.push(format!(
                "its points' reprojection error is {:.2} px (the median photo's {median_error:.2})",
                mean_error[k]
            ));
        }
        if !why.is_empty() {
            out.push(Suspect { name: model.images[order[k]].name.clone(), why: why.join("; ") });
        }
    }
    out
}

fn is_image(p: &Path) -> bool {
    p.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| matches!(e.to_ascii_lowercase().as_str(), "png" | "jpg" | "jpeg" | "tif" | "tiff" | "bmp"))
}

/// Runs the process step on the workspace `input`, writing the dataset to `output`.
///
/// # Errors
/// [`DataError`] naming the file: no model, too few registered photos, several different
/// cameras, a camera model that cannot be undistorted, a missing, undecodable or wrongly sized
/// photo, a non-empty output folder (without `overwrite`), unwritable files; and every error of
/// [`colmap::read_model`] and [`colmap::poses_bounds`].
pub fn process(input: &Path, output: &Path, opts: &ProcessOptions) -> Result<ProcessReport, DataError> {
    let source = Source::read(input)?;
    let (file, kind) = (source.file.clone(), source.kind);
    // Errors of the COLMAP model's checks name the model's files (`sparse/N/images`); a
    // capture's are in its one file.
    let named = |e: DataError| match (e, kind) {
        (DataError::Invalid { path, problem }, SourceKind::Transforms) if path.parent() == Some(file.as_path()) => {
            DataError::Invalid { path: file.clone(), problem }
        }
        (e, _) => e,
    };
    process_source(source, output, opts).map_err(named)
}

/// Where the process step's model and photos come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SourceKind {
    /// A COLMAP workspace: `images/` and the models in `sparse/`.
    Colmap,
    /// A capture in nerfstudio's or Instant-NGP's `transforms.json` form ([`crate::nerfstudio`]).
    Transforms,
}

/// The model and photos the process step starts from.
struct Source {
    kind: SourceKind,
    /// Every model found: `(N, registered photos, its folder)` (a capture: one, numbered 0).
    models: Vec<(u32, PathBuf, usize)>,
    /// The model's folder, or the capture's `transforms.json`.
    file: PathBuf,
    model: colmap::ColmapModel,
    /// The folder the images' names are relative to.
    root: PathBuf,
    /// The folders of the photos (for the photo count and the masks' check).
    folders: Vec<PathBuf>,
    notes: Vec<String>,
}

impl Source {
    /// A COLMAP workspace when `input` has `sparse/`, else a capture when it has
    /// `transforms.json`.
    fn read(input: &Path) -> Result<Self, DataError> {
        if !input.join("sparse").is_dir() && crate::nerfstudio::is_capture(input) {
            let capture = crate::nerfstudio::read(input)?;
            let file = input.join(crate::nerfstudio::TRANSFORMS);
            return Ok(Self {
                kind: SourceKind::Transforms,
                models: vec![(0, file.clone(), capture.model.images.len())],
                file,
                model: capture.model,
                root: input.to_path_buf(),
                folders: capture.photo_folders,
                notes: capture.notes,
            });
        }
        let images_dir = input.join("images");
        if !images_dir.is_dir() {
            return Err(DataError::invalid(
                input,
                "no images/ folder: a COLMAP workspace holds the photos in images/ and the models in sparse/ (or give \
                 a folder with nerfstudio's or Instant-NGP's transforms.json)",
            ));
        }
        let models = colmap::list_models(input)?;
        let best = colmap::largest(&models).clone();
        let model = colmap::read_model(&best.1)?;
        Ok(Self {
            kind: SourceKind::Colmap,
            models,
            file: best.1,
            model,
            root: images_dir.clone(),
            folders: vec![images_dir],
            notes: Vec::new(),
        })
    }
}

fn process_source(source: Source, output: &Path, opts: &ProcessOptions) -> Result<ProcessReport, DataError> {
    let Source { kind, models, file: model_dir, mut model, root: images_dir, folders, notes } = source;
    let mut photos = 0;
    for folder in &folders {
        photos += std::fs::read_dir(folder)
            .map_err(|e| DataError::io(folder, e))?
            .filter_map(Result::ok)
            .filter(|e| is_image(&e.path()))
            .count();
    }
    colmap::check_model(&model, &model_dir)?;
    let excluded = exclude_photos(&mut model, kind, &model_dir, &opts.exclude)?;
    let suspects = suspect_photos(&model);
    let registered = model.images.len();
    let mut warnings = notes;
    let counts = Registered { registered, photos, excluded: excluded.len() };
    check_registered(counts, opts, &model_dir, &mut warnings)?;
    let cams = model_dir.join("cameras");
    let first = shared_camera(&model, &images_dir, &cams)?;
    let lens = LensCamera::from_colmap(&first).map_err(|e| DataError::invalid(&cams, e))?;
    let named: Vec<(String, PathBuf)> =
        model.images.iter().map(|im| (im.name.clone(), images_dir.join(&im.name))).collect();
    let focal = focal::check_focal((lens.fx * lens.fy).sqrt(), &named, lens.width, lens.height);
    if let Some(masks) = &opts.masks {
        check_masks(masks, &folders[0], &named, &lens)?;
    }
    let pinhole = undistort::undistorted_pinhole(&lens);
    let long = pinhole.width.max(pinhole.height);
    let factor = if opts.max_size == 0 { 1 } else { long.div_ceil(opts.max_size).max(1) };
    let size = ((pinhole.width / factor).max(1), (pinhole.height / factor).max(1));
    // The poses and bounds of the undistorted camera: the same extrinsics and points, a pinhole.
    with_pinhole(&mut model, first.id, &pinhole);
    let (rows, names) = colmap::poses_bounds(&model, &model_dir)?;

    // The output folder: new, empty, or (with overwrite) one whose dataset this step wrote. The
    // new dataset is built beside the old one and swapped in only when whole, so an interrupted
    // run leaves the old dataset as it was; only what this step wrote (its manifest,
    // `io::MANIFEST`, lists it) is ever replaced, and nothing else in the folder is touched.
    let npy = output.join("poses_bounds.npy");
    let folder = output.join(format!("images_{factor}"));
    let masks_folder = opts.masks.as_ref().map(|_| output.join(format!("masks_{factor}")));
    let mut ours = vec![String::from("poses_bounds.npy"), format!("images_{factor}")];
    if opts.masks.is_some() {
        ours.push(format!("masks_{factor}"));
    }
    check_output(output, &ours, opts.overwrite)?;
    std::fs::create_dir_all(output).map_err(|e| DataError::io(output, e))?;
    mipnerf_core::io::record(output, "colmap", ours.iter().cloned())?;
    let partial = mipnerf_core::io::start_partial_dir(&folder)?;
    let partial_masks = masks_folder.as_deref().map(mipnerf_core::io::start_partial_dir).transpose()?;
    let target = LensCamera::from(pinhole);
    let counts = names.par_iter().enumerate().map(|(i, name)| -> Result<[u64; 3], DataError> {
        let file = images_dir.join(name);
        crate::check_present(&file, "registered in the COLMAP model but missing from images/")?;
        let (w, h, rgba, _) = crate::read_png_rgba(&file)?;
        if (w, h) != (lens.width, lens.height) {
            return Err(DataError::invalid(
                &file,
                format!("is {w}x{h}, the COLMAP camera is {}x{} (resized after COLMAP ran?)", lens.width, lens.height),
            ));
        }
        let und = undistort::warp(&rgba, 4, &lens, &target);
        let (nw, nh) = size;
        let out = if factor > 1 { crate::box_resize_rgba8(&und, target.width, target.height, nw, nh) } else { und };
        let stem = Path::new(name).file_stem().map_or_else(String::new, |s| s.to_string_lossy().into_owned());
        let written = format!("{i:04}_{stem}.png");
        crate::write_png_rgba(&partial.join(&written), nw, nh, &out)?;
        if let (Some(dir), Some(partial_masks)) = (&opts.masks, &partial_masks) {
            let mask = mask_through(&crate::masks::mask_file(dir, Path::new(name))?, &lens, &target, size)?;
            crate::write_png_rgba(&partial_masks.join(&written), nw, nh, &mask)?;
        }
        Ok(border_counts(&out, nw as usize, nh as usize))
    });
    let counts = counts.collect::<Result<Vec<_>, _>>()?;
    let (backdrop, (white, black)) = backdrop_of(&counts);
    // The new images are whole: only now does the old dataset stop being whole (its index goes
    // first, so that a crash in these three steps leaves no index over mixed images).
    if npy.is_file() {
        std::fs::remove_file(&npy).map_err(|e| DataError::io(&npy, e))?;
    }
    mipnerf_core::io::swap_in_dir(&folder)?;
    if let Some(masks_folder) = &masks_folder {
        mipnerf_core::io::swap_in_dir(masks_folder)?;
    }
    remove_earlier_outputs(output, &ours)?;
    crate::llff::write_poses_bounds(&npy, &rows)?;

    let near = rows.iter().map(|r| r[15]).fold(f64::INFINITY, f64::min);
    let far = rows.iter().map(|r| r[16]).fold(f64::NEG_INFINITY, f64::max);
    let held_out = names.iter().enumerate().filter(|(i, _)| i % LLFF_HOLD == 0).map(|(_, n)| n.clone()).collect();
    Ok(ProcessReport {
        source: kind,
        models: models.iter().map(|(k, _, c)| (*k, *c)).collect(),
        model_dir,
        registered,
        photos,
        camera_model: colmap::model_name(first.model_id),
        lens,
        pinhole,
        factor,
        size,
        bounds: (near, far),
        all_around: faces_all_around(&rows),
        held_out,
        backdrop,
        border_shares: (white, black),
        suspects,
        excluded,
        focal,
        masks: masks_folder,
        warnings,
    })
}

/// Checks the masks' folder against the photos' and reads every registered photo's mask
/// (`named`: name and file), all before anything is written.
fn check_masks(masks: &Path, photos: &Path, named: &[(String, PathBuf)], lens: &LensCamera) -> Result<(), DataError> {
    crate::masks::check_folder(masks, photos)?;
    named.par_iter().try_for_each(|(name, _)| -> Result<(), DataError> {
        crate::masks::read_mask(&crate::masks::mask_file(masks, Path::new(name))?, lens.width, lens.height).map(|_| ())
    })
}

/// `model` with its one camera (of id `id`) replaced by the undistorted `pinhole`: the same
/// extrinsics and points, every photo on that camera.
fn with_pinhole(model: &mut ColmapModel, id: u32, pinhole: &undistort::Pinhole) {
    model.cameras = vec![ColmapCamera {
        id,
        model_id: 0,
        width: u64::from(pinhole.width),
        height: u64::from(pinhole.height),
        params: vec![pinhole.focal, f64::from(pinhole.width) / 2.0, f64::from(pinhole.height) / 2.0],
    }];
    for im in &mut model.images {
        im.camera_id = id;
    }
}

/// Leaves the photos named in `exclude` out of `model` (of the source `kind` at `model_dir`,
/// which errors name); each must be registered, and a name given twice, or an empty one from a
/// trailing comma, counts once or not at all. Returns the names left out.
fn exclude_photos(
    model: &mut ColmapModel,
    kind: SourceKind,
    model_dir: &Path,
    exclude: &[String],
) -> Result<Vec<String>, DataError> {
    // The photos left out, each of which must be registered (a name given twice, or an empty
    // one from a trailing comma, counts once or not at all).
    let mut excluded: Vec<String> = Vec::new();
    for name in exclude {
        if name.is_empty() || excluded.contains(name) {
            continue;
        }
        let before = model.images.len();
        model.images.retain(|im| im.name != *name);
        if model.images.len() == before {
            return Err(DataError::invalid(
                model_dir,
                match kind {
                    SourceKind::Colmap => {
                        format!("--exclude {name}: the model registers no photo of that name (names are as in images/)")
                    }
                    SourceKind::Transforms => format!(
                        "--exclude {name}: no frame has that photo (names are the frames' file_path without ./, such \
                         as {})",
                        model.images.first().map_or("images/a.jpg", |im| im.name.as_str())
                    ),
                },
            ));
        }
        excluded.push(name.clone());
    }
    Ok(excluded)
}

/// How many photos a model registers of how many, and how many were left out.
#[derive(Clone, Copy)]
struct Registered {
    registered: usize,
    photos: usize,
    excluded: usize,
}

/// Refuses a model that registers fewer photos than `opts.min_views` (saying whether leaving
/// photos out made it so), and warns under `opts.recommended_views`.
fn check_registered(
    counts: Registered,
    opts: &ProcessOptions,
    model_dir: &Path,
    warnings: &mut Vec<String>,
) -> Result<(), DataError> {
    let Registered { registered, photos, excluded } = counts;
    if registered < opts.min_views && excluded > 0 {
        return Err(DataError::invalid(
            model_dir,
            format!(
                "the largest COLMAP model registers {} of {photos} photos; leaving out {} (`ProcessOptions::exclude`) \
                 leaves {registered}, fewer than the minimum of {} (`ProcessOptions::min_views`): leave out fewer photos",
                registered + excluded,
                excluded,
                opts.min_views
            ),
        ));
    }
    if registered < opts.min_views {
        return Err(DataError::invalid(
            model_dir,
            format!(
                "the largest COLMAP model registers {registered} of {photos} photos, fewer than the minimum of {} \
                 (`ProcessOptions::min_views`): take more photos with more overlap between neighbours, or try COLMAP's mapper \
                 with looser settings (docs/guide/own-photos.md gives them)",
                opts.min_views
            ),
        ));
    }
    if registered < opts.recommended_views {
        warnings.push(format!(
            "only {registered} photos are registered; {} or more give a much better model",
            opts.recommended_views
        ));
    }
    Ok(())
}

/// The one camera every registered photo shares, checked against its first photo's size.
fn shared_camera(model: &ColmapModel, images_dir: &Path, cams: &Path) -> Result<ColmapCamera, DataError> {
    let first = model.cameras.first().cloned().ok_or_else(|| DataError::invalid(cams, "no cameras"))?;
    // The camera's size against a photo's, before anything is computed from the camera (a
    // camera 2^32 pixels wide would otherwise be undistorted pixel by pixel).
    if let Some(im) = model.images.iter().find(|im| im.camera_id == first.id) {
        let file = images_dir.join(&im.name);
        let (w, h) = crate::image_size(&file)?;
        if (u64::from(w), u64::from(h)) != (first.width, first.height) {
            return Err(DataError::invalid(
                cams,
                format!(
                    "camera {} is {}x{}, but its photo {} is {w}x{h}: the model is not of these photos (or they were \
                     resized after COLMAP ran)",
                    first.id, first.width, first.height, im.name
                ),
            ));
        }
    }
    let used: std::collections::HashSet<u32> = model.images.iter().map(|im| im.camera_id).collect();
    if let Some(c) = model.cameras.iter().find(|c| {
        used.contains(&c.id)
            && (c.model_id, c.width, c.height, &c.params) != (first.model_id, first.width, first.height, &first.params)
    }) {
        return Err(DataError::invalid(
            cams,
            format!(
                "camera {} differs from camera {}: the photos must share one camera (one lens, one zoom); \
                 reconstruct with COLMAP's --ImageReader.single_camera 1 (pycolmap: camera_mode=CameraMode.SINGLE)",
                c.id, first.id
            ),
        ));
    }
    Ok(first)
}

/// The photos' backdrop from their border pixels' counts (near white, near black, all), with
/// the shares of white and black.
fn backdrop_of(counts: &[[u64; 3]]) -> (Option<Backdrop>, (f64, f64)) {
    let total = counts.iter().map(|c| c[2]).sum::<u64>().max(1) as f64;
    let white = counts.iter().map(|c| c[0]).sum::<u64>() as f64 / total;
    let black = counts.iter().map(|c| c[1]).sum::<u64>() as f64 / total;
    let backdrop = if white >= BACKDROP_SHARE {
        Some(Backdrop::White)
    } else if black >= BACKDROP_SHARE {
        Some(Backdrop::Black)
    } else {
        None
    };
    (backdrop, (white, black))
}

/// Whether the cameras look all around the scene: their mean viewing direction (minus the
/// "back" column of each pose) is short.
fn faces_all_around(rows: &[[f64; 17]]) -> bool {
    // Viewing directions: minus the "back" column of each pose.
    let mut mean = [0.0f64; 3];
    for r in rows {
        for (k, m) in mean.iter_mut().enumerate() {
            *m -= r[k * 5 + 2] / rows.len() as f64;
        }
    }
    let resultant = mean.iter().map(|m| m * m).sum::<f64>().sqrt();
    resultant < ALL_AROUND_BELOW
}

/// The mask `path` of a photo of the COLMAP camera `lens` (its size, or larger with its aspect
/// ratio: [`crate::masks::read_mask`]), undistorted to `target` as the photo is and box-filtered
/// to `size`: grey RGBA8 (`train --masks` reads its luminance).
///
/// # Errors
/// [`crate::masks::read_mask`]'s: undecodable, of another size, all black; naming the file.
fn mask_through(path: &Path, lens: &LensCamera, target: &LensCamera, size: (u32, u32)) -> Result<Vec<u8>, DataError> {
    let alpha = crate::masks::read_mask(path, lens.width, lens.height)?;
    let grey: Vec<u8> = alpha.iter().map(|a| (a * 255.0).round() as u8).collect();
    let und = undistort::warp(&grey, 1, lens, target);
    let rgba: Vec<u8> = und.iter().flat_map(|&v| [v, v, v, 255]).collect();
    Ok(if size != (target.width, target.height) {
        crate::box_resize_rgba8(&rgba, target.width, target.height, size.0, size.1)
    } else {
        rgba
    })
}

/// Removes what an earlier run of this step wrote into `output` and this run does not (the
/// `images_4/` of a run at another `--max-size`, the `masks_2/` of a run with `--masks`), and
/// forgets it in the manifest: an overwrite replaces every output of the earlier run, so that no
/// old photos lie beside the new poses. Only this step's outputs are touched: what its manifest
/// lists as `colmap`'s, or, from a version whose manifest did not say, its image and mask folders.
fn remove_earlier_outputs(output: &Path, ours: &[String]) -> Result<(), DataError> {
    let stale: BTreeSet<String> = mipnerf_core::io::writers(output)?
        .into_iter()
        .filter(|(name, by)| match by.as_deref() {
            Some(by) => by == "colmap",
            None => name.starts_with("images_") || name.starts_with("masks_"),
        })
        .map(|(name, _)| name)
        .filter(|name| !ours.contains(name) && !name.contains(['/', '\\']) && name != ".." && name != ".")
        .collect();
    for name in &stale {
        let path = output.join(name);
        match std::fs::symlink_metadata(&path) {
            Ok(m) if m.is_dir() => std::fs::remove_dir_all(&path).map_err(|e| DataError::io(&path, e))?,
            Ok(_) => std::fs::remove_file(&path).map_err(|e| DataError::io(&path, e))?,
            Err(_) => {}
        }
    }
    Ok(mipnerf_core::io::forget(output, &stale)?)
}

/// Refuses an output folder that holds anything (but this step's manifest and temporary folders)
/// unless `overwrite`, and, with it, one where a name this step writes (`ours`) is taken by
/// something this step did not write.
fn check_output(output: &Path, ours: &[String], overwrite: bool) -> Result<(), DataError> {
    if std::fs::symlink_metadata(output).is_err() {
        return Ok(());
    }
    if !output.is_dir() {
        return Err(DataError::invalid(output, "is a file, not a folder"));
    }
    let recorded = mipnerf_core::io::recorded(output)?;
    let entries = mipnerf_core::io::names_in(output)?;
    if !entries.is_empty() && !overwrite {
        return Err(DataError::invalid(
            output,
            "is not empty; choose a new folder, or set `ProcessOptions::overwrite` to replace the dataset in it",
        ));
    }
    let mut taken: Vec<&String> = ours.iter().filter(|n| entries.contains(n) && !recorded.contains(*n)).collect();
    taken.sort();
    if !taken.is_empty() {
        return Err(DataError::invalid(
            output,
            format!(
                "holds {} that this step did not write (they are not in its {}); they are left as they are: \
                 choose another folder, or move them away",
                taken.iter().map(|n| n.as_str()).collect::<Vec<_>>().join(" and "),
                mipnerf_core::io::MANIFEST
            ),
        ));
    }
    Ok(())
}

/// `[near white, near black, all]` counts of the pixels on the outermost two-pixel ring of an
/// RGBA8 image ([`BACKDROP_LEVEL`]).
fn border_counts(rgba: &[u8], w: usize, h: usize) -> [u64; 3] {
    let hi = (BACKDROP_LEVEL * 255.0) as u8;
    let lo = ((1.0 - BACKDROP_LEVEL) * 255.0) as u8;
    let mut c = [0u64; 3];
    for y in 0..h {
        for x in 0..w {
            if x >= 2 && y >= 2 && x + 2 < w && y + 2 < h {
                continue;
            }
            let p = &rgba[(y * w + x) * 4..(y * w + x) * 4 + 3];
            c[0] += u64::from(p.iter().all(|&v| v >= hi));
            c[1] += u64::from(p.iter().all(|&v| v <= lo));
            c[2] += 1;
        }
    }
    c
}
