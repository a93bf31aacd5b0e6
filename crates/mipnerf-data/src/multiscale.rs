//! The multiscale Blender format of the Mip-NeRF paper, and the converter that makes it.
//!
//! Each image is stored at 4 scales (`1, 1/2, 1/4, 1/8`) made by repeated 2x2 box filtering of
//! straight (not premultiplied) RGBA, as `images_{split}/{i:03d}_d{j}.png`. `metadata.json` holds,
//! per split, parallel lists: `file_path`, `cam2world`, `width`, `height`, `focal` (`f / 2^j`),
//! `label` (`j`), `near`, `far`, `lossmult` (`4^j`) and `pix2cam`.

use std::path::Path;

use serde_json::{Value, json};

use crate::{
    DataError, Dataset, Pixels, Split, View, blender, check_pixel_memory, down2, pose_from_json, read_json,
    read_png_rgba, show, write_png_rgba,
};
use mipnerf_core::camera::{
    Camera, MAX_FIELD_OF_VIEW_DEG, MAX_SCENE_COORDINATE, MIN_FIELD_OF_VIEW_DEG, pinhole_pix2cam,
};

/// Scales the official converter writes.
pub const NUM_SCALES: u32 = 4;

/// One image at full resolution, straight RGBA in `[0, 1]`, with its pose.
#[derive(Clone, Debug)]
pub struct SourceImage {
    /// Width.
    pub width: u32,
    /// Height.
    pub height: u32,
    /// `width * height * 4` values.
    pub rgba: Vec<f32>,
    /// Camera-to-world, top 3 rows.
    pub cam2world: [[f64; 4]; 3],
}

/// `np.uint8(x * 255)` of the official converter: truncation, not rounding.
#[must_use]
pub fn quantise(rgba: &[f32]) -> Vec<u8> {
    rgba.iter().map(|&x| (x * 255.0).clamp(0.0, 255.0) as u8).collect()
}

/// How a split's images are laid out at every scale: the full-resolution focal length in pixels,
/// the number of scales, and every ray's bounds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Scales {
    /// Full-resolution focal length, pixels (scale `j`'s is `focal / 2^j`).
    pub focal: f64,
    /// Scales, full resolution first, each half the one before.
    pub n_scales: u32,
    /// Near bound of every ray.
    pub near: f64,
    /// Far bound of every ray.
    pub far: f64,
}

/// Writes one split's images at `scales.n_scales` scales into `out/images_{split}/` and returns
/// its `metadata.json` entry. The folder is filled under a temporary name and replaces
/// `out/images_{split}/` only when whole ([`mipnerf_core::io::swap_in_dir`]).
///
/// # Errors
/// [`DataError`] for sizes not divisible by `2^n_scales` (the official converter's requirement)
/// or unwritable files.
pub fn write_split(out: &Path, split: Split, images: &[SourceImage], scales: Scales) -> Result<Value, DataError> {
    let meta = fill_split(out, split, images, scales)?;
    mipnerf_core::io::swap_in_dir(&out.join(format!("images_{split}")))?;
    Ok(meta)
}

/// [`write_split`] up to the swap: the images are left in the temporary folder
/// ([`mipnerf_core::io::partial_dir`] of `out/images_{split}`).
fn fill_split(out: &Path, split: Split, images: &[SourceImage], scales: Scales) -> Result<Value, DataError> {
    let Scales { focal, n_scales, near, far } = scales;
    let imgdir = format!("images_{split}");
    let partial = mipnerf_core::io::start_partial_dir(&out.join(&imgdir))?;
    let mut meta: Vec<(&str, Vec<Value>)> =
        ["file_path", "cam2world", "width", "height", "focal", "label", "near", "far", "lossmult", "pix2cam"]
            .into_iter()
            .map(|k| (k, Vec::new()))
            .collect();
    for (i, img) in images.iter().enumerate() {
        let div = 1u32 << n_scales;
        if img.width % div != 0 || img.height % div != 0 {
            return Err(DataError::invalid(
                &out.join(&imgdir),
                format!("image {i} is {}x{}; {n_scales} scales need sizes divisible by {div}", img.width, img.height),
            ));
        }
        let (mut w, mut h, mut px) = (img.width, img.height, img.rgba.clone());
        for j in 0..n_scales {
            let name = format!("{i:03}_d{j}.png");
            write_png_rgba(&partial.join(&name), w, h, &quantise(&px))?;
            let rel = format!("{imgdir}/{name}");
            let f = focal / f64::from(1u32 << j);
            let c2w: Vec<Vec<f64>> =
                img.cam2world.iter().map(|r| r.to_vec()).chain([vec![0.0, 0.0, 0.0, 1.0]]).collect();
            let p2c = pinhole_pix2cam(w, h, f);
            let values = [
                json!(rel),
                json!(c2w),
                json!(w),
                json!(h),
                json!(f),
                json!(j),
                json!(near),
                json!(far),
                json!(4f64.powi(j as i32)),
                json!(p2c.iter().map(|r| r.to_vec()).collect::<Vec<_>>()),
            ];
            for ((_, list), v) in meta.iter_mut().zip(values) {
                list.push(v);
            }
            px = down2(&px, w as usize, h as usize);
            w /= 2;
            h /= 2;
        }
    }
    Ok(Value::Object(meta.into_iter().map(|(k, v)| (k.to_string(), Value::Array(v))).collect()))
}

/// Converts the Blender scene in `input` into the multiscale format in `output`, exactly as the
/// official `convert_blender_data.py`: every split present (`train`, `val`, `test`; missing ones are
/// skipped, and it is an error if none is present), 4 scales, near 2, far 6. Returns the splits
/// converted.
///
/// # Errors
/// [`DataError`] for unreadable inputs or unwritable outputs.
pub fn convert(input: &Path, output: &Path) -> Result<Vec<Split>, DataError> {
    convert_resized(input, output, None)
}

/// [`convert`], after first box-filtering every Blender image to `width` pixels wide (the height
/// in proportion): straight RGBA, area average, any ratio ([`crate::box_resize`]); the focal
/// length scales alike. `None` is [`convert`] itself, byte for byte the official converter's.
///
/// # Errors
/// As [`convert`], and for a `width` under 16 or not divisible by 8 (the 1/8 scale must be at
/// least 2 pixels and whole), for a height that would not be a whole multiple of 8, and for a
/// `width` larger than the images.
pub fn convert_resized(input: &Path, output: &Path, width: Option<u32>) -> Result<Vec<Split>, DataError> {
    if let Some(n) = width
        && (n < 16 || n % 8 != 0)
    {
        return Err(DataError::invalid(
            input,
            format!("a width of {n} px: the width must be at least 16 and divisible by 8 (for the 1/8 scale)"),
        ));
    }
    let present: Vec<Split> = [Split::Train, Split::Val, Split::Test]
        .into_iter()
        .filter(|split| input.join(format!("transforms_{split}.json")).is_file())
        .collect();
    if present.is_empty() {
        let why = if input.join("sparse").is_dir() {
            "no transforms_{train,val,test}.json: this is a COLMAP workspace (sparse/); convert it with `colmap::convert_to_llff`"
        } else if input.join("metadata.json").is_file() {
            "no transforms_{train,val,test}.json: this is already a multiscale dataset (metadata.json); train on it \
             as it is"
        } else {
            "no transforms_{train,val,test}.json to convert (a Blender scene has them; a COLMAP workspace has \
             sparse/ and converts with `colmap::convert_to_llff`)"
        };
        return Err(DataError::invalid(input, why));
    }
    // Nothing in `output` is touched before the input is known to convert; every split's images
    // are filled under a temporary name and moved in whole, and metadata.json is written last, so
    // a conversion that stops part-way never looks complete and never mixes two conversions.
    std::fs::create_dir_all(output).map_err(|e| DataError::io(output, e))?;
    let meta_path = output.join("metadata.json");
    let mut all = serde_json::Map::new();
    let mut done = Vec::new();
    for &split in &present {
        let (angle, frames) = blender::read_transforms(input, split)?;
        let mut images = Vec::with_capacity(frames.len());
        for fr in &frames {
            let (w, h, rgba, _) = read_png_rgba(&fr.file)?;
            let mut rgba: Vec<f32> = rgba.iter().map(|&b| f32::from(b) / 255.0).collect();
            let (mut w2, mut h2) = (w, h);
            if let Some(n) = width {
                (w2, h2) = resized_shape(&fr.file, w, h, n)?;
                rgba = crate::box_resize(&rgba, w as usize, h as usize, w2 as usize, h2 as usize);
            }
            images.push(SourceImage { width: w2, height: h2, rgba, cam2world: fr.cam2world });
        }
        // The focal length follows the width: the field of view is unchanged.
        let focal = mipnerf_core::camera::focal_from_camera_angle_x(images[0].width, angle);
        let scales =
            Scales { focal, n_scales: NUM_SCALES, near: f64::from(blender::NEAR), far: f64::from(blender::FAR) };
        let meta = fill_split(output, split, &images, scales)?;
        all.insert(split.name().to_string(), meta);
        done.push(split);
    }
    // Every split is whole beside the old dataset: only now does the old one stop being whole.
    if meta_path.is_file() {
        std::fs::remove_file(&meta_path).map_err(|e| DataError::io(&meta_path, e))?;
    }
    for split in &done {
        mipnerf_core::io::swap_in_dir(&output.join(format!("images_{split}")))?;
    }
    write_metadata(output, &Value::Object(all))?;
    Ok(done)
}

/// The `width x height` an image of `w x h` gets at `width` pixels wide, checked.
fn resized_shape(file: &Path, w: u32, h: u32, width: u32) -> Result<(u32, u32), DataError> {
    if width > w {
        return Err(DataError::invalid(file, format!("a width of {width} px is larger than the image ({w}x{h})")));
    }
    let hh = u64::from(h) * u64::from(width);
    if hh % u64::from(w) != 0 || (hh / u64::from(w)) % 8 != 0 {
        return Err(DataError::invalid(
            file,
            format!(
                "a width of {width} px: a {w}x{h} image would be {width}x{:.2}, not a whole multiple of 8 high",
                hh as f64 / f64::from(w)
            ),
        ));
    }
    Ok((width, (hh / u64::from(w)) as u32))
}

/// Writes `metadata.json` atomically ([`mipnerf_core::io::write_atomic`]).
pub(crate) fn write_metadata(dir: &Path, meta: &Value) -> Result<(), DataError> {
    let path = dir.join("metadata.json");
    let text = serde_json::to_string_pretty(meta).map_err(|e| DataError::invalid(&path, e.to_string()))?;
    mipnerf_core::io::write_atomic(&path, text.as_bytes()).map_err(|e| DataError::io(&e.path, e.error))
}

fn list<'a>(
    meta: &'a Value,
    key: &str,
    n: Option<usize>,
    path: &Path,
    split: Split,
) -> Result<&'a Vec<Value>, DataError> {
    let v = meta
        .get(key)
        .ok_or_else(|| DataError::invalid(path, format!("{split}: missing key \"{key}\"")))?
        .as_array()
        .ok_or_else(|| DataError::invalid(path, format!("{split}: \"{key}\" must be a list")))?;
    if let Some(n) = n
        && v.len() != n
    {
        return Err(DataError::invalid(
            path,
            format!("{split}: \"{key}\" has {} entries, \"file_path\" has {n}", v.len()),
        ));
    }
    Ok(v)
}

/// The largest image side the loaders accept.
pub const MAX_SIDE: u32 = 1 << 16;

/// `v` as a whole number in `lo..=hi` (`3.0` is accepted, `3.5` is not).
fn integer(v: &Value, path: &Path, what: &str, lo: u32, hi: u32) -> Result<u32, DataError> {
    let x = number(v, path, what)?;
    if x.fract() != 0.0 || x < f64::from(lo) || x > f64::from(hi) {
        return Err(DataError::invalid(path, format!("{what} must be a whole number from {lo} to {hi}, got {x}")));
    }
    Ok(x as u32)
}

/// The largest `lossmult` accepted: the area weight `4^j` of scale 10 (the format has 4 scales);
/// larger weights overflow the loss's `f32` sums.
pub const MAX_LOSSMULT: f64 = 1_048_576.0;

/// `focal` (pixels) if positive and giving a field of view within the camera's accepted range.
fn checked_focal(focal: f64, width: u32, path: &Path, what: &str) -> Result<f64, DataError> {
    let fov = (2.0 * (0.5 * f64::from(width) / focal).atan()).to_degrees();
    if focal > 0.0 && (MIN_FIELD_OF_VIEW_DEG..=MAX_FIELD_OF_VIEW_DEG).contains(&fov) {
        return Ok(focal);
    }
    let lo = 0.5 * f64::from(width) / (0.5 * MAX_FIELD_OF_VIEW_DEG.to_radians()).tan();
    let hi = 0.5 * f64::from(width) / (0.5 * MIN_FIELD_OF_VIEW_DEG.to_radians()).tan();
    Err(DataError::invalid(
        path,
        format!(
            "{what} is {} pixels; for a {width}-pixel-wide image it must be between {lo:.4} and {hi:.4e} \
             ({MAX_FIELD_OF_VIEW_DEG} to {MIN_FIELD_OF_VIEW_DEG} degrees of field of view)",
            show(focal)
        ),
    ))
}

fn number(v: &Value, path: &Path, what: &str) -> Result<f64, DataError> {
    v.as_f64()
        .filter(|x| x.is_finite())
        .ok_or_else(|| DataError::invalid(path, format!("{what} must be a finite number")))
}

/// Loads `split` of a multiscale dataset: every image at every scale is a view with its own
/// camera (`pix2cam`, `cam2world`), near, far and `lossmult`.
///
/// # Errors
/// [`DataError`] naming `metadata.json` or the image for a missing split or key, lists of
/// different lengths, non-finite or singular poses, and missing, undecodable or wrongly sized
/// images.
pub fn load(dir: &Path, split: Split, white_bkgd: bool) -> Result<Dataset, DataError> {
    let path = dir.join("metadata.json");
    let all = read_json(&path)?;
    let meta = all.get(split.name()).ok_or_else(|| DataError::invalid(&path, format!("no \"{split}\" split")))?;
    let files = list(meta, "file_path", None, &path, split)?;
    let n = Some(files.len());
    let (c2w, widths, heights) = (
        list(meta, "cam2world", n, &path, split)?,
        list(meta, "width", n, &path, split)?,
        list(meta, "height", n, &path, split)?,
    );
    let (nears, fars, lossmults) = (
        list(meta, "near", n, &path, split)?,
        list(meta, "far", n, &path, split)?,
        list(meta, "lossmult", n, &path, split)?,
    );
    // Optional lists, each as long as "file_path" when present.
    let optional = |key: &str| -> Result<Option<&Vec<Value>>, DataError> {
        if meta.get(key).is_some() { list(meta, key, n, &path, split).map(Some) } else { Ok(None) }
    };
    let (labels, pix2cams, focals) = (optional("label")?, optional("pix2cam")?, optional("focal")?);
    // Every image's size is in the metadata: check that they fit in memory before decoding any.
    let mut pixels = 0u64;
    for i in 0..files.len() {
        let what = |k: &str| format!("{split} entry {i} \"{k}\"");
        let w = integer(&widths[i], &path, &what("width"), 1, MAX_SIDE)?;
        let h = integer(&heights[i], &path, &what("height"), 1, MAX_SIDE)?;
        pixels += u64::from(w) * u64::from(h);
    }
    check_pixel_memory(&path, pixels, files.len())?;
    let mut views = Vec::with_capacity(files.len());
    for i in 0..files.len() {
        let what = |k: &str| format!("{split} entry {i} \"{k}\"");
        let rel = files[i]
            .as_str()
            .ok_or_else(|| DataError::invalid(&path, format!("{} must be a string", what("file_path"))))?;
        let file = dir.join(rel);
        let w = integer(&widths[i], &path, &what("width"), 1, MAX_SIDE)?;
        let h = integer(&heights[i], &path, &what("height"), 1, MAX_SIDE)?;
        let pose = pose_from_json(&c2w[i], &path, &what("cam2world"))?;
        // "focal" is checked wherever it is given, even when "pix2cam" (which wins) makes it unused.
        let focal = match focals.and_then(|f| f.get(i)) {
            Some(f) => Some(checked_focal(number(f, &path, &what("focal"))?, w, &path, &what("focal"))?),
            None => None,
        };
        let pix2cam = match (pix2cams.and_then(|p| p.get(i)), focal) {
            (Some(p), _) => {
                let rows = p
                    .as_array()
                    .filter(|r| r.len() == 3)
                    .ok_or_else(|| DataError::invalid(&path, format!("{} must be 3x3", what("pix2cam"))))?;
                let mut m = [[0.0; 3]; 3];
                for (r, row) in rows.iter().enumerate() {
                    let row = row
                        .as_array()
                        .filter(|x| x.len() == 3)
                        .ok_or_else(|| DataError::invalid(&path, format!("{} must be 3x3", what("pix2cam"))))?;
                    for (c, x) in row.iter().enumerate() {
                        m[r][c] = number(x, &path, &what("pix2cam"))?;
                    }
                }
                m
            }
            (None, Some(focal)) => pinhole_pix2cam(w, h, focal),
            (None, None) => return Err(DataError::invalid(&path, format!("{split}: needs \"pix2cam\" or \"focal\""))),
        };
        let camera = Camera::from_pix2cam(w, h, pix2cam, pose)
            .map_err(|e| DataError::invalid(&path, format!("{split} entry {i}: {e}")))?;
        let (iw, ih, rgba, channels) = read_png_rgba(&file)?;
        if (iw, ih) != (w, h) {
            return Err(DataError::invalid(&file, format!("image is {iw}x{ih}, metadata.json says {w}x{h}")));
        }
        if channels != 3 && channels != 4 {
            return Err(DataError::invalid(
                &file,
                format!("expected an RGB or RGBA image, found {channels} channel(s)"),
            ));
        }
        let scale = match labels.and_then(|l| l.get(i)) {
            Some(l) => integer(l, &path, &what("label"), 0, NUM_SCALES - 1)?,
            None => 0,
        };
        let (near, far) = (number(&nears[i], &path, &what("near"))?, number(&fars[i], &path, &what("far"))?);
        if near <= 0.0 || far <= near || far > MAX_SCENE_COORDINATE {
            return Err(DataError::invalid(
                &path,
                format!(
                    "{split} entry {i}: \"near\" {} and \"far\" {}: need 0 < near < far <= {MAX_SCENE_COORDINATE:e}",
                    show(near),
                    show(far)
                ),
            ));
        }
        let lossmult = number(&lossmults[i], &path, &what("lossmult"))?;
        if !(lossmult > 0.0 && lossmult <= MAX_LOSSMULT) {
            return Err(DataError::invalid(
                &path,
                format!(
                    "{} must be positive and at most {MAX_LOSSMULT:e} (a pixel's weight in the loss: its area, 4^scale), \
                     got {}",
                    what("lossmult"),
                    show(lossmult)
                ),
            ));
        }
        views.push(View {
            file,
            camera,
            pixels: Pixels::Rgba8(rgba),
            near: near as f32,
            far: far as f32,
            lossmult: lossmult as f32,
            scale,
        });
    }
    Dataset::new(dir, split, views, white_bkgd)
}
