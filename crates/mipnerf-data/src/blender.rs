//! The NeRF synthetic ("Blender") format: `transforms_{split}.json` and RGBA PNGs.
//!
//! `camera_angle_x` gives the horizontal field of view; each frame has a `file_path` (relative,
//! without or with `.png`) and a 4x4 camera-to-world `transform_matrix` (OpenGL axes). Near and
//! far are 2 and 6, as in the official loader.

use std::path::{Path, PathBuf};

use crate::{
    DataError, Dataset, Pixels, Split, View, check_pixel_memory, down2, image_pixels, pose_from_json, read_json,
    read_png_rgba,
};
use mipnerf_core::camera::Camera;

/// Near bound of the Blender scenes.
pub const NEAR: f32 = 2.0;
/// Far bound of the Blender scenes.
pub const FAR: f32 = 6.0;

/// One frame of a `transforms_*.json`.
#[derive(Clone, Debug)]
pub struct Frame {
    /// The image file.
    pub file: PathBuf,
    /// Camera-to-world, top 3 rows.
    pub cam2world: [[f64; 4]; 3],
}

/// Reads `transforms_{split}.json` of `dir`: the field of view and the frames.
///
/// # Errors
/// [`DataError`] naming the file for a missing or malformed file, a missing key, a non-finite
/// pose or an empty frame list.
pub fn read_transforms(dir: &Path, split: Split) -> Result<(f64, Vec<Frame>), DataError> {
    let path = dir.join(format!("transforms_{split}.json"));
    let meta = read_json(&path)?;
    let angle = meta
        .get("camera_angle_x")
        .ok_or_else(|| DataError::invalid(&path, "missing key \"camera_angle_x\""))?
        .as_f64()
        .filter(|a| a.is_finite() && *a > 0.0 && *a < std::f64::consts::PI)
        .ok_or_else(|| DataError::invalid(&path, "\"camera_angle_x\" must be a number of radians in (0, pi)"))?;
    let frames = meta
        .get("frames")
        .ok_or_else(|| DataError::invalid(&path, "missing key \"frames\""))?
        .as_array()
        .ok_or_else(|| DataError::invalid(&path, "\"frames\" must be a list"))?;
    if frames.is_empty() {
        return Err(DataError::invalid(&path, format!("the {split} split has no frames")));
    }
    let mut out = Vec::with_capacity(frames.len());
    for (i, fr) in frames.iter().enumerate() {
        let fp = fr
            .get("file_path")
            .and_then(|v| v.as_str())
            .ok_or_else(|| DataError::invalid(&path, format!("frame {i}: missing or non-string \"file_path\"")))?;
        let tm = fr
            .get("transform_matrix")
            .ok_or_else(|| DataError::invalid(&path, format!("frame {i}: missing key \"transform_matrix\"")))?;
        let cam2world = pose_from_json(tm, &path, &format!("frame {i} transform_matrix"))?;
        let rel = if fp.to_ascii_lowercase().ends_with(".png") { fp.to_string() } else { format!("{fp}.png") };
        out.push(Frame { file: dir.join(rel.trim_start_matches("./")), cam2world });
    }
    Ok((angle, out))
}

/// Loads `split` of a Blender scene: straight RGBA pixels (composited on white when `white_bkgd`
/// at batch time), optionally at half resolution with a 2x2 area filter (the official `factor 2`).
///
/// # Errors
/// Everything [`read_transforms`] reports, and for images: missing or undecodable files, a channel
/// count other than 3 or 4, sizes that differ between frames, odd sizes with `half_res`, and
/// singular poses.
pub fn load(dir: &Path, split: Split, white_bkgd: bool, half_res: bool) -> Result<Dataset, DataError> {
    let (angle, frames) = read_transforms(dir, split)?;
    let json = dir.join(format!("transforms_{split}.json"));
    let mut pixels = 0u64;
    for fr in &frames {
        pixels += image_pixels(&fr.file)?;
    }
    check_pixel_memory(&json, pixels, frames.len())?;
    let mut views = Vec::with_capacity(frames.len());
    let mut size = None;
    for (i, fr) in frames.iter().enumerate() {
        let (w, h, rgba, channels) = read_png_rgba(&fr.file)?;
        if channels != 3 && channels != 4 {
            return Err(DataError::invalid(
                &fr.file,
                format!("expected an RGB or RGBA image, found {channels} channel(s)"),
            ));
        }
        match size {
            None => size = Some((w, h)),
            Some((w0, h0)) if (w0, h0) != (w, h) => {
                return Err(DataError::invalid(
                    &fr.file,
                    format!("image is {w}x{h} but the split's first image is {w0}x{h0}; all images must have one size"),
                ));
            }
            Some(_) => {}
        }
        let (pixels, w, h) = if half_res {
            if w % 2 != 0 || h % 2 != 0 {
                return Err(DataError::invalid(
                    &fr.file,
                    format!("half resolution needs even sizes, image is {w}x{h}"),
                ));
            }
            let f: Vec<f32> = rgba.iter().map(|&b| f32::from(b) / 255.0).collect();
            (Pixels::RgbaF32(down2(&f, w as usize, h as usize)), w / 2, h / 2)
        } else {
            (Pixels::Rgba8(rgba), w, h)
        };
        let camera = Camera::from_camera_angle_x(w, h, angle, fr.cam2world)
            .map_err(|e| DataError::invalid(&json, format!("frame {i}: {e}")))?;
        views.push(View { file: fr.file.clone(), camera, pixels, near: NEAR, far: FAR, lossmult: 1.0, scale: 0 });
    }
    Dataset::new(dir, split, views, white_bkgd)
}
