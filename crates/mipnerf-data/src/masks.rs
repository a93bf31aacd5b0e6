//! Foreground masks for photos: one image per photo, white where the object is, that turns a
//! capture of an object in a room into the object alone.
//!
//! [`apply`] reads the mask of every view (matched by file name without extension, PNG or JPEG;
//! white = the object, or a cut-out's alpha) and stores it as the view's alpha, the photo's
//! colours kept straight. The dataset then trains as Blender's RGBA images do: targets composited
//! on the background (white, or a random colour per pixel), and the occupancy grid carved to the
//! masks' visual hull.

use std::path::{Path, PathBuf};

use crate::{DataError, Dataset, Pixels, box_resize, read_png_rgba};

/// Mask values within this many 8-bit levels of 0 or 255 are taken as exactly 0 or 255: a JPEG's
/// ringing (or a painted mask's stray levels) must not make the backdrop slightly opaque, nor
/// the object slightly transparent.
pub const MASK_SNAP_LEVELS: u8 = 8;

/// The file extensions a mask may have.
const MASK_EXTENSIONS: [&str; 6] = ["png", "PNG", "jpg", "JPG", "jpeg", "JPEG"];

/// The mask file of the photo `photo` in `dir`: `dir/<stem>.{png,jpg,...}`, matched by the
/// names in the folder (so a case-insensitive file system does not see one file under two
/// names).
///
/// # Errors
/// [`DataError::Invalid`] naming the file names looked for when none exists, or the files when
/// the photo has more than one mask (say `a.png` and `a.jpg`: which one is meant is not for the
/// loader to guess); [`DataError::Io`] when the folder cannot be listed.
pub fn mask_file(dir: &Path, photo: &Path) -> Result<PathBuf, DataError> {
    let stem = photo.file_stem().and_then(|s| s.to_str()).unwrap_or_default();
    let wanted: Vec<String> = MASK_EXTENSIONS.iter().map(|e| format!("{stem}.{e}")).collect();
    let mut found: Vec<PathBuf> = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(|e| DataError::io(dir, e))? {
        let entry = entry.map_err(|e| DataError::io(dir, e))?;
        // Whatever kind of file it is: one that is not a regular file (a FIFO, a device) is then
        // refused by name when it is read, not reported missing.
        if wanted.iter().any(|w| entry.file_name() == w.as_str()) && !entry.path().is_dir() {
            found.push(entry.path());
        }
    }
    found.sort();
    match found.as_slice() {
        [one] => Ok(one.clone()),
        [] => Err(DataError::invalid(
            &dir.join(format!("{stem}.png")),
            format!(
                "no mask for photo {}: expected {stem}.png (or .jpg) in {} (one mask per photo, named as the photo, \
                 white = the object)",
                photo.display(),
                dir.display()
            ),
        )),
        [first, ..] => Err(DataError::invalid(
            first,
            format!(
                "photo {} has {} masks ({}): keep one",
                photo.display(),
                found.len(),
                found
                    .iter()
                    .map(|p| p.file_name().unwrap_or_default().to_string_lossy())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        )),
    }
}

/// Reads a mask as alpha in `[0, 1]`, `width x height`: its grey levels (the luminance of a colour
/// image), or its alpha channel where it has one that is not opaque everywhere (a cut-out, as
/// background-removal tools write: the object's pixels over transparency), values within
/// [`MASK_SNAP_LEVELS`] of black or white snapped to them, area-resampled when it is larger than
/// the photo with the same aspect ratio (masks made at the photos' full size, photos read from
/// `images_N`).
///
/// # Errors
/// [`DataError::Invalid`] naming the file: undecodable, of another aspect ratio or smaller than
/// the photo, or all black (no object).
pub fn read_mask(path: &Path, width: u32, height: u32) -> Result<Vec<f32>, DataError> {
    // The photos' reader: a JPEG cut short is refused, not filled with grey.
    let (mw, mh, rgba, channels) = read_png_rgba(path)?;
    let has_alpha = channels == 2 || channels == 4;
    let grey = if has_alpha && rgba.chunks_exact(4).any(|p| p[3] < 255) {
        image::GrayImage::from_raw(mw, mh, rgba.chunks_exact(4).map(|p| p[3]).collect())
    } else {
        image::RgbaImage::from_raw(mw, mh, rgba).map(|rgba| image::DynamicImage::ImageRgba8(rgba).to_luma8())
    }
    .ok_or_else(|| DataError::invalid(path, "cannot decode the mask: its size does not match its pixels"))?;
    let snap = |v: u8| -> f32 {
        if v <= MASK_SNAP_LEVELS {
            0.0
        } else if v >= 255 - MASK_SNAP_LEVELS {
            1.0
        } else {
            f32::from(v) / 255.0
        }
    };
    let alpha: Vec<f32> = if (mw, mh) == (width, height) {
        grey.as_raw().iter().map(|&v| snap(v)).collect()
    } else {
        // Same aspect ratio to within a pixel of the photo's size, and larger.
        let same_aspect = (f64::from(mw) * f64::from(height) / f64::from(mh) - f64::from(width)).abs() <= 1.0;
        if !(same_aspect && mw >= width && mh >= height) {
            return Err(DataError::invalid(
                path,
                format!(
                    "the mask is {mw}x{mh} but its photo is {width}x{height}: a mask must be the photo's size, or \
                     larger with the same aspect ratio"
                ),
            ));
        }
        let rgba: Vec<f32> = grey.as_raw().iter().flat_map(|&v| [0.0, 0.0, 0.0, snap(v)]).collect();
        box_resize(&rgba, mw as usize, mh as usize, width as usize, height as usize)
            .chunks_exact(4)
            .map(|p| p[3])
            .collect()
    };
    if alpha.iter().all(|&a| a == 0.0) {
        return Err(DataError::invalid(
            path,
            "the mask is all black (or all transparent): it marks no object in its photo (white = the object, black \
             = what is left out)",
        ));
    }
    Ok(alpha)
}

/// Checks that `dir`, a folder of masks for the photos in `photos`, is a folder and not the
/// photos' own (whose photos would each be "found" as their own mask, their luminance taken as
/// alpha).
///
/// # Errors
/// [`DataError::Invalid`] naming `dir`.
pub fn check_folder(dir: &Path, photos: &Path) -> Result<(), DataError> {
    if !dir.is_dir() {
        return Err(DataError::invalid(dir, "the masks folder does not exist (or is not a folder)"));
    }
    if dir.canonicalize().ok().is_some_and(|d| photos.canonicalize().ok() == Some(d)) {
        return Err(DataError::invalid(
            dir,
            "this is the photos' own folder, not their masks': give the folder of the masks (one image per photo, \
             named as the photo, white = the object)",
        ));
    }
    Ok(())
}

/// Gives every view of `ds` the mask in `dir` of its photo as its alpha (see the module docs);
/// the photos' colours stay straight. Returns the number of views masked.
///
/// # Errors
/// A missing, undecodable, wrongly sized or all-black mask, naming its file; a folder that is
/// not one or is the photos' own ([`check_folder`]).
pub fn apply(ds: &mut Dataset, dir: &Path) -> Result<usize, DataError> {
    if let Some(photos) = ds.views().first().and_then(|v| v.file.parent()) {
        check_folder(dir, photos)?;
    }
    let mut n = 0;
    for view in ds.views_mut() {
        let path = mask_file(dir, &view.file)?;
        let alpha = read_mask(&path, view.camera.width, view.camera.height)?;
        match &mut view.pixels {
            Pixels::Rgba8(px) => {
                for (p, a) in px.chunks_exact_mut(4).zip(&alpha) {
                    p[3] = (a * 255.0).round() as u8;
                }
            }
            Pixels::RgbaF32(px) => {
                for (p, a) in px.chunks_exact_mut(4).zip(&alpha) {
                    p[3] = *a;
                }
            }
        }
        n += 1;
    }
    Ok(n)
}
