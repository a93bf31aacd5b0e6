//! Dataset files: what is on disk to a [`Dataset`] in memory, and captures to datasets.
//!
//! Formats:
//! - [`blender`]: `transforms_{train,val,test}.json` with RGBA PNGs (the NeRF synthetic scenes);
//! - [`multiscale`]: the official multiscale Blender format (`metadata.json`, 4 scales per view),
//!   and its converter;
//! - [`llff`]: forward-facing captures (`poses_bounds.npy`, `images_{factor}`), NDC rays;
//! - [`colmap`]: COLMAP sparse models beside their photos, with [`undistort`] for their lenses and
//!   [`focal`] for the focal length the photos' EXIF implies;
//! - [`nerfstudio`]: nerfstudio's and Instant-NGP's `transforms.json` captures, for the process
//!   step ([`process`]), with [`ply`] for their point clouds;
//! - [`masks`]: foreground masks taken as the photos' alpha;
//! - [`camera_path`]: camera files (`transforms.json`-style poses and intrinsics) to render;
//! - [`demo`]: the procedural demo scene (`mipnerf_core::demo`) written in the multiscale format.
//!
//! [`load`] detects a folder's format and loads one split. The maths the loaders share with
//! training (cameras, rays, NDC) is `mipnerf_core`'s.

pub mod blender;
pub mod camera_path;
pub mod colmap;
pub mod demo;
pub mod focal;
mod image_files;
pub mod llff;
pub mod masks;
pub mod multiscale;
pub mod nerfstudio;
pub mod ply;
pub mod process;
mod resample;
pub mod undistort;

use std::path::{Path, PathBuf};

use mipnerf_core::camera::PixelCenters;
use mipnerf_core::config::DataFit;
use mipnerf_core::dataset::{DataError, Dataset, Ndc, Pixels, Split, View};

pub(crate) use image_files::{check_present, image_pixels, image_size, read_png_rgba, write_png_rgba};
pub(crate) use resample::box_resize_rgba8;
pub use resample::{box_resize, down2};

/// Bytes of parsed JSON (`serde_json::Value`s, 32 bytes each, and their lists) per byte of
/// text, at most: a list of one-digit numbers is 2 bytes of text a value. The text itself is one
/// more.
const JSON_BYTES_PER_TEXT_BYTE: u64 = 17;

/// Reads and parses a JSON file, with errors naming the file (and the line for syntax errors).
pub(crate) fn read_json(path: &Path) -> Result<serde_json::Value, DataError> {
    let len = std::fs::metadata(path).map_err(|e| DataError::io(path, e))?.len();
    mipnerf_core::memory::check(len.saturating_mul(JSON_BYTES_PER_TEXT_BYTE), &format!("parsing this {len}-byte file"))
        .map_err(|e| DataError::invalid(path, e))?;
    let bytes =
        mipnerf_core::io::read_regular(path, mipnerf_core::io::cap::JSON).map_err(|e| DataError::io(path, e))?;
    if bytes.starts_with(b"\x93NUMPY") {
        return Err(DataError::invalid(path, "is a NumPy array file (such as poses_bounds.npy), not JSON"));
    }
    let text = String::from_utf8(bytes).map_err(|_| {
        DataError::invalid(path, "is not UTF-8 text, so not JSON (a binary file given for a JSON one?)")
    })?;
    serde_json::from_str(&text).map_err(|e| DataError::invalid(path, format!("malformed JSON: {e}")))
}

/// The dataset formats this tool reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// `transforms_{split}.json`.
    Blender,
    /// `metadata.json`.
    Multiscale,
    /// `poses_bounds.npy`.
    Llff,
    /// A COLMAP sparse model (`sparse/0/cameras.bin` or `.txt`, ...) beside `images/`.
    Colmap,
}

impl Format {
    /// Photos with poses from LLFF or COLMAP (forward-facing or spherified), whose training
    /// defaults differ from the Blender formats' (no compositing, cylinders in NDC, the tiny
    /// preset's learning rate).
    #[must_use]
    pub fn is_photos(self) -> bool {
        matches!(self, Self::Llff | Self::Colmap)
    }
}

/// Detects the format of the dataset in `dir`.
///
/// # Errors
/// [`DataError::Io`] if `dir` is not a readable directory, [`DataError::UnknownFormat`] if it holds
/// none of the formats' marker files.
pub fn detect_format(dir: &Path) -> Result<Format, DataError> {
    let meta = std::fs::metadata(dir).map_err(|e| DataError::io(dir, e))?;
    if !meta.is_dir() {
        return Err(DataError::invalid(dir, "is not a directory"));
    }
    if dir.join("metadata.json").is_file() {
        Ok(Format::Multiscale)
    } else if dir.join("transforms_train.json").is_file() || dir.join("transforms_test.json").is_file() {
        Ok(Format::Blender)
    } else if dir.join("poses_bounds.npy").is_file() {
        Ok(Format::Llff)
    } else if dir.join("sparse").is_dir() && dir.join("images").is_dir() {
        Ok(Format::Colmap)
    } else if nerfstudio::is_capture(dir) {
        Err(DataError::invalid(
            &dir.join(nerfstudio::TRANSFORMS),
            format!(
                "a capture in nerfstudio's or Instant-NGP's form: process it first with `mipnerf colmap --input {} \
                 --output DATASET` (it undistorts the photos and measures their depth bounds), then train on DATASET",
                dir.display()
            ),
        ))
    } else {
        Err(DataError::UnknownFormat { path: dir.to_path_buf() })
    }
}

/// Options that apply when loading any format.
#[derive(Clone, Debug, PartialEq)]
pub struct LoadOptions {
    /// Composite the images' alpha on white (`Some(true)`) or drop it (`Some(false)`, black);
    /// `None`: the format's own choice (white for the Blender formats, none for photos, as the
    /// official loaders do; white for masked photos).
    pub white_bkgd: Option<bool>,
    /// Blender: load at half resolution (2x2 area filter), as the official `factor = 2`.
    pub half_res: bool,
    /// LLFF and COLMAP: the image folder's downsampling factor (`images_{factor}`; 0 = `images`).
    pub llff_factor: u32,
    /// LLFF and COLMAP: spherical poses instead of forward-facing NDC.
    pub llff_spherify: bool,
    /// With `llff_spherify` (and not `unbounded`, whose poses are [`llff::Spherify::UnitBall`]'s):
    /// `None` for the official spherical poses ([`llff::Spherify::Official`],
    /// the default), or the cameras' distance from the centre with the up axis their ring's
    /// ([`llff::Spherify::Ring`]; the CLI trains new runs at [`llff::SPHERIFY_RADIUS`]).
    pub spherify_radius: Option<f64>,
    /// Rays through pixel centres or corners.
    pub centers: PixelCenters,
    /// Photos (LLFF, COLMAP): a folder of foreground masks, one per photo, taken as the photos'
    /// alpha ([`masks::apply`]).
    pub masks: Option<PathBuf>,
    /// An unbounded scene ([`mipnerf_core::contract`]): photos spherified with the farthest camera on the
    /// unit sphere ([`llff::Spherify::UnitBall`]), every ray's far bound at
    /// [`UNBOUNDED_FAR`](mipnerf_core::contract::UNBOUNDED_FAR) ([`Dataset::make_unbounded`]). Needs
    /// `llff_spherify` on photos; Blender scenes (an object alone) are refused.
    pub unbounded: bool,
}

impl Default for LoadOptions {
    fn default() -> Self {
        Self {
            white_bkgd: None,
            masks: None,
            half_res: false,
            llff_factor: 4,
            llff_spherify: false,
            spherify_radius: None,
            centers: PixelCenters::Centered,
            unbounded: false,
        }
    }
}

/// Loads `split` of the dataset in `dir`, whatever its format.
///
/// # Errors
/// Any [`DataError`] of the format's loader.
pub fn load(dir: &Path, split: Split, opts: &LoadOptions) -> Result<Dataset, DataError> {
    let format = detect_format(dir)?;
    let white = opts.white_bkgd.unwrap_or(DataFit::white_by_default(format.is_photos(), opts.masks.is_some()));
    let spherify = opts.llff_spherify.then_some(match (opts.unbounded, opts.spherify_radius) {
        (true, _) => llff::Spherify::UnitBall,
        (false, None) => llff::Spherify::Official,
        (false, Some(radius)) => llff::Spherify::Ring { radius },
    });
    let mut ds = match format {
        Format::Blender => blender::load(dir, split, white, opts.half_res)?,
        Format::Multiscale => multiscale::load(dir, split, white)?,
        Format::Llff => llff::load(dir, split, opts.llff_factor, spherify)?,
        Format::Colmap => colmap::load(dir, split, opts.llff_factor, spherify)?,
    };
    // Photos with alpha (their own, or their masks') are composited as Blender's images are.
    ds.white_bkgd = white;
    if let Some(masks) = &opts.masks {
        if !format.is_photos() {
            return Err(DataError::invalid(
                masks,
                "masks are for photos (LLFF or COLMAP data); Blender images carry theirs as their alpha",
            ));
        }
        let n = masks::apply(&mut ds, masks)?;
        ds.masked = true;
        ds.notes.push(format!("{n} photos masked by {} (the object trained alone)", masks.display()));
    }
    ds.centers = opts.centers;
    if opts.unbounded {
        if !format.is_photos() {
            return Err(DataError::invalid(
                dir,
                "an unbounded scene is for photos of a scene and its surroundings (LLFF or COLMAP data); a Blender \
                 scene is an object alone on a transparent background, bounded already",
            ));
        }
        if ds.ndc.is_some() {
            return Err(DataError::invalid(
                dir,
                "an unbounded scene needs world-space rays: these forward-facing photos train in NDC space, which is \
                 bounded already (pass --spherify for photos taken all around)",
            ));
        }
        ds.make_unbounded().map_err(|e| DataError::invalid(dir, e))?;
        ds.notes.push(
            "unbounded: the farthest camera on the unit sphere; rays reach to infinity, contracted beyond it".into(),
        );
        // Forward-facing photos with --spherify --unbounded are a meaningful choice (mip-NeRF 360's
        // contraction holds what lies beyond the photos' depth range, as nerfstudio trains such
        // captures), but not the LLFF protocol's NDC: say so.
        let resultant = viewing_resultant(&ds);
        if resultant >= process::ALL_AROUND_BELOW {
            ds.notes.push(format!(
                "unbounded: these photos all look one way (mean viewing direction of length {resultant:.2}): the \
                 contracted space holds them, but the LLFF protocol and its published numbers train forward-facing \
                 photos in NDC (drop --spherify and --unbounded)"
            ));
        }
    }
    Ok(ds)
}

/// The length of the mean of the views' viewing directions: 1 when all look the same way, near
/// 0 all around ([`process::ALL_AROUND_BELOW`]).
fn viewing_resultant(ds: &Dataset) -> f64 {
    let views = ds.views();
    let mut mean = [0.0f64; 3];
    for v in views {
        let c2w = v.camera.cam2world;
        let back = [c2w[0][2], c2w[1][2], c2w[2][2]];
        let len = back.iter().map(|b| b * b).sum::<f64>().sqrt().max(f64::MIN_POSITIVE);
        for k in 0..3 {
            mean[k] -= back[k] / len / views.len().max(1) as f64;
        }
    }
    mean.iter().map(|m| m * m).sum::<f64>().sqrt()
}

/// Checks that `pixels` images' worth of straight RGBA8 (4 bytes a pixel, as loaded) fits in
/// memory before any is decoded; `path` names the dataset file in the error.
pub(crate) fn check_pixel_memory(path: &Path, pixels: u64, images: usize) -> Result<(), DataError> {
    mipnerf_core::memory::check(pixels.saturating_mul(4), &format!("loading {images} images of {pixels} pixels in all"))
        .map_err(|e| {
            DataError::invalid(
                path,
                format!("{e}; train on fewer or smaller images (`multiscale::convert_resized` makes smaller ones)"),
            )
        })
}

/// A number as an error message shows it: plainly between 1e-3 and 1e7 (and 0), else in
/// scientific notation (`3e38`, not 39 digits).
#[must_use]
pub(crate) fn show(x: f64) -> String {
    if x == 0.0 || (1e-3..1e7).contains(&x.abs()) { format!("{x}") } else { format!("{x:e}") }
}

/// A 3x4 camera-to-world matrix from a JSON 4x4 (or 3x4) array, checked for finiteness.
pub(crate) fn pose_from_json(v: &serde_json::Value, path: &Path, what: &str) -> Result<[[f64; 4]; 3], DataError> {
    let rows = v.as_array().filter(|r| r.len() == 4 || r.len() == 3);
    let rows = rows.ok_or_else(|| DataError::invalid(path, format!("{what}: expected a 4x4 matrix")))?;
    let mut m = [[0.0; 4]; 3];
    for (i, row) in rows.iter().take(3).enumerate() {
        let r = row.as_array().filter(|r| r.len() == 4);
        let r = r.ok_or_else(|| DataError::invalid(path, format!("{what}: row {i} is not 4 numbers")))?;
        for (j, x) in r.iter().enumerate() {
            let x = x
                .as_f64()
                .ok_or_else(|| DataError::invalid(path, format!("{what}: entry [{i}][{j}] is not a number")))?;
            if !x.is_finite() {
                return Err(DataError::invalid(path, format!("{what}: entry [{i}][{j}] is not finite")));
            }
            m[i][j] = x;
        }
    }
    Ok(m)
}

/// A number under `key` of a `transforms.json`-style file (camera paths, nerfstudio captures),
/// from the frame or else the top level; `None` when neither has it.
pub(crate) fn json_number(
    key: &str,
    frame: &serde_json::Map<String, serde_json::Value>,
    top: &serde_json::Map<String, serde_json::Value>,
) -> Result<Option<f64>, String> {
    match frame.get(key).or_else(|| top.get(key)) {
        None => Ok(None),
        Some(v) => {
            v.as_f64().filter(|x| x.is_finite()).map(Some).ok_or_else(|| format!("\"{key}\" is not a finite number"))
        }
    }
}
