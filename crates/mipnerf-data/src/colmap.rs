//! COLMAP sparse models (`sparse/N/{cameras,images,points3D}.{bin,txt}` beside `images/`), read and
//! turned into LLFF's `poses_bounds.npy` rows exactly as LLFF's own `imgs2poses.py` does
//! (`llff/poses/pose_utils.py`, functions `load_colmap_data` and `save_poses`), so that a COLMAP
//! scene then loads through the LLFF loader (recentring, scene scaling, NDC or spherical poses,
//! every 8th image held out).
//!
//! What `imgs2poses` does, and this module with it:
//! - the camera-to-world pose of each image is the inverse of COLMAP's world-to-camera `[R | t]`
//!   (`qvec`, `tvec`), its rotation columns reordered from COLMAP's `[right, down, forward]` to
//!   LLFF's `[down, right, back]` (`[-u, r, -t]` from `[r, -u, t]`, as its comment says);
//! - `[height, width, focal]` is that of the first camera of `cameras.bin`, `focal = params[0]`;
//! - each image's near and far bounds are the 0.1 and 99.9 percentiles (numpy's linear
//!   interpolation) of the depths, along its viewing direction, of the 3D points it sees;
//! - rows are sorted by image name, as `images/` is listed.
//!
//! Where this module differs on purpose: it maps a point's track to images by image id, where
//! `imgs2poses` indexes by `image_id - 1` (the same when ids run 1..N in file order, as a fresh
//! reconstruction's do; a model with gaps in its ids is then still right); and it refuses what the
//! LLFF format cannot hold instead of ignoring it: lens distortion (undistort first), several
//! different cameras, `fx != fy`, and a principal point away from the image centre.

use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};

use glam::{DMat3, DQuat, DVec3};

use crate::llff::{self, LlffImage};
use crate::{DataError, Dataset, Split, read_png_rgba};

/// A COLMAP camera model this module reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CameraModel {
    /// `f, cx, cy`.
    SimplePinhole,
    /// `fx, fy, cx, cy`.
    Pinhole,
    /// `f, cx, cy, k`.
    SimpleRadial,
    /// `f, cx, cy, k1, k2`.
    Radial,
    /// `fx, fy, cx, cy, k1, k2, p1, p2`.
    Opencv,
}

/// COLMAP's model ids and names (`colmap/src/colmap/sensor/models.h`) with their parameter counts;
/// the ones past OPENCV are fisheye or exotic models this module refuses.
const MODELS: [(i32, &str, usize); 11] = [
    (0, "SIMPLE_PINHOLE", 3),
    (1, "PINHOLE", 4),
    (2, "SIMPLE_RADIAL", 4),
    (3, "RADIAL", 5),
    (4, "OPENCV", 8),
    (5, "OPENCV_FISHEYE", 8),
    (6, "FULL_OPENCV", 12),
    (7, "FOV", 5),
    (8, "SIMPLE_RADIAL_FISHEYE", 4),
    (9, "RADIAL_FISHEYE", 5),
    (10, "THIN_PRISM_FISHEYE", 12),
];

/// COLMAP's name of a camera model id (`unknown` for an id COLMAP does not have).
#[must_use]
pub fn model_name(id: i32) -> &'static str {
    MODELS.iter().find(|m| m.0 == id).map_or("unknown", |m| m.1)
}

/// The number of parameters of a camera model id, if COLMAP has it.
pub(crate) fn model_param_count(id: i32) -> Option<usize> {
    MODELS.iter().find(|m| m.0 == id).map(|m| m.2)
}

/// `(fx, fy, cx, cy, distortion coefficients)` from a camera's parameters in COLMAP's order for
/// `model`; `p` holds the model's count ([`model_param_count`]).
pub(crate) fn intrinsics(model: CameraModel, p: &[f64]) -> (f64, f64, f64, f64, &[f64]) {
    match model {
        CameraModel::SimplePinhole => (p[0], p[0], p[1], p[2], &[]),
        CameraModel::Pinhole => (p[0], p[1], p[2], p[3], &[]),
        CameraModel::SimpleRadial | CameraModel::Radial => (p[0], p[0], p[1], p[2], &p[3..]),
        CameraModel::Opencv => (p[0], p[1], p[2], p[3], &p[4..]),
    }
}

/// The camera model of an id this module reads (the fisheye and exotic ones are `None`).
pub(crate) fn model_of(id: i32) -> Option<CameraModel> {
    Some(match id {
        0 => CameraModel::SimplePinhole,
        1 => CameraModel::Pinhole,
        2 => CameraModel::SimpleRadial,
        3 => CameraModel::Radial,
        4 => CameraModel::Opencv,
        _ => return None,
    })
}

/// One camera (intrinsics).
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapCamera {
    /// COLMAP's camera id.
    pub id: u32,
    /// COLMAP's model id (0..=10).
    pub model_id: i32,
    /// Image width and height in pixels.
    pub width: u64,
    /// Image height in pixels.
    pub height: u64,
    /// The model's parameters, in COLMAP's order.
    pub params: Vec<f64>,
}

/// One registered image (extrinsics).
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapImage {
    /// COLMAP's image id.
    pub id: u32,
    /// World-to-camera rotation as a unit quaternion `[w, x, y, z]`.
    pub qvec: [f64; 4],
    /// World-to-camera translation.
    pub tvec: [f64; 3],
    /// The camera (intrinsics) it was taken with.
    pub camera_id: u32,
    /// File name relative to the image folder.
    pub name: String,
}

/// One 3D point and the images that see it.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapPoint {
    /// Position in world units.
    pub xyz: [f64; 3],
    /// Ids of the images whose features observe it (its track).
    pub image_ids: Vec<u32>,
    /// Its mean reprojection error over its track (pixels), as COLMAP stores it.
    pub error: f64,
}

/// A sparse model, in file order.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct ColmapModel {
    /// Cameras.
    pub cameras: Vec<ColmapCamera>,
    /// Registered images.
    pub images: Vec<ColmapImage>,
    /// 3D points.
    pub points: Vec<ColmapPoint>,
}

/// The model folder of a COLMAP scene: `dir/sparse/N` (or `dir/sparse` holding the files). With
/// several `sparse/N`, the one with the most registered images is taken (ties: the lowest `N`),
/// as COLMAP's mapper numbers its models as it finds them, not by size; the returned note says
/// which, and of how many.
///
/// # Errors
/// No `sparse` folder with a model in it.
pub fn find_model(dir: &Path) -> Result<(PathBuf, Option<String>), DataError> {
    let models = list_models(dir)?;
    if models.len() == 1 {
        return Ok((models[0].1.clone(), None));
    }
    let best = largest(&models);
    let list: Vec<String> = models.iter().map(|(k, _, c)| format!("sparse/{k} ({c} images)")).collect();
    let note = format!("{} COLMAP models: {}; took sparse/{}, the largest", models.len(), list.join(", "), best.0);
    Ok((best.1.clone(), Some(note)))
}

/// Every model under `dir/sparse` as `(N, folder, registered images)`, by `N` (a model directly in
/// `dir/sparse` is `N = 0`).
///
/// # Errors
/// No `sparse` folder with a model in it.
pub fn list_models(dir: &Path) -> Result<Vec<(u32, PathBuf, usize)>, DataError> {
    models_in(&dir.join("sparse"))
}

/// Every model in the folder `sparse` (itself, or its numbered subfolders), as [`list_models`].
pub(crate) fn models_in(sparse: &Path) -> Result<Vec<(u32, PathBuf, usize)>, DataError> {
    let sparse = sparse.to_path_buf();
    if has_model(&sparse) {
        let c = registered_images(&sparse).unwrap_or(0);
        return Ok(vec![(0, sparse, c)]);
    }
    let entries = std::fs::read_dir(&sparse).map_err(|e| DataError::io(&sparse, e))?;
    let mut found: Vec<(u32, PathBuf)> = entries
        .filter_map(Result::ok)
        .filter_map(|e| e.file_name().to_str().and_then(|n| n.parse::<u32>().ok()).map(|n| (n, e.path())))
        .filter(|(_, p)| has_model(p))
        .collect();
    found.sort();
    if found.is_empty() {
        return Err(DataError::invalid(&sparse, "no COLMAP model here (cameras, images and points3D .bin or .txt)"));
    }
    Ok(found
        .into_iter()
        .map(|(k, p)| {
            let c = registered_images(&p).unwrap_or(0);
            (k, p, c)
        })
        .collect())
}

/// The model with the most registered images (ties: the lowest `N`) of [`list_models`]'s list.
pub(crate) fn largest(models: &[(u32, PathBuf, usize)]) -> &(u32, PathBuf, usize) {
    models.iter().max_by_key(|(k, _, c)| (*c, std::cmp::Reverse(*k))).unwrap_or(&models[0])
}

fn has_model(dir: &Path) -> bool {
    ["bin", "txt"]
        .iter()
        .any(|e| ["cameras", "images", "points3D"].iter().all(|f| dir.join(format!("{f}.{e}")).is_file()))
}

/// The number of registered images of the model in `dir`, read from its header (binary) or its
/// lines (text).
fn registered_images(dir: &Path) -> Option<usize> {
    let bin = dir.join("images.bin");
    if bin.is_file() {
        let mut f = mipnerf_core::io::open_regular(&bin).ok()?;
        let mut b = [0u8; 8];
        std::io::Read::read_exact(&mut f, &mut b).ok()?;
        return usize::try_from(u64::from_le_bytes(b)).ok();
    }
    let text =
        mipnerf_core::io::read_regular_text(&dir.join("images.txt"), mipnerf_core::io::cap::COLMAP_MODEL).ok()?;
    Some(text.lines().filter(|l| !l.starts_with('#')).count() / 2)
}

/// Reads the model in `dir` (`.bin` files if present, else `.txt`).
///
/// # Errors
/// [`DataError`] naming the file: missing files, truncated or malformed records, unknown model
/// ids, wrong parameter counts, non-finite values.
pub fn read_model(dir: &Path) -> Result<ColmapModel, DataError> {
    if dir.join("cameras.bin").is_file() {
        Ok(ColmapModel {
            cameras: read_cameras_bin(&dir.join("cameras.bin"))?,
            images: read_images_bin(&dir.join("images.bin"))?,
            points: read_points_bin(&dir.join("points3D.bin"))?,
        })
    } else {
        Ok(ColmapModel {
            cameras: read_cameras_txt(&dir.join("cameras.txt"))?,
            images: read_images_txt(&dir.join("images.txt"))?,
            points: read_points_txt(&dir.join("points3D.txt"))?,
        })
    }
}

/// A little-endian reader over a file's bytes whose errors name the file and the offset.
struct Reader<'a> {
    path: &'a Path,
    bytes: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], DataError> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.bytes.len()).ok_or_else(|| {
            DataError::invalid(self.path, format!("truncated: {what} at byte {} runs past the end", self.at))
        })?;
        let s = &self.bytes[self.at..end];
        self.at = end;
        Ok(s)
    }
    fn u64(&mut self, what: &str) -> Result<u64, DataError> {
        Ok(u64::from_le_bytes(self.take(8, what)?.try_into().unwrap_or_default()))
    }
    fn i32(&mut self, what: &str) -> Result<i32, DataError> {
        Ok(i32::from_le_bytes(self.take(4, what)?.try_into().unwrap_or_default()))
    }
    fn u32(&mut self, what: &str) -> Result<u32, DataError> {
        let v = self.i32(what)?;
        u32::try_from(v).map_err(|_| DataError::invalid(self.path, format!("{what} is negative ({v})")))
    }
    fn f64(&mut self, what: &str) -> Result<f64, DataError> {
        let v = f64::from_le_bytes(self.take(8, what)?.try_into().unwrap_or_default());
        if v.is_finite() { Ok(v) } else { Err(DataError::invalid(self.path, format!("{what} is not finite"))) }
    }
    /// A count of records of at least `record` bytes each, checked against the bytes left.
    fn count(&mut self, record: usize, what: &str) -> Result<usize, DataError> {
        let n = self.u64(what)?;
        let left = (self.bytes.len() - self.at) as u64;
        if n.saturating_mul(record as u64) > left {
            return Err(DataError::invalid(
                self.path,
                format!("truncated: {what} says {n} records at byte {}, only {left} bytes follow", self.at),
            ));
        }
        Ok(n as usize)
    }
    fn name(&mut self) -> Result<String, DataError> {
        let end = self.bytes[self.at..].iter().position(|&b| b == 0).ok_or_else(|| {
            DataError::invalid(self.path, format!("truncated: an image name at byte {} has no end", self.at))
        })?;
        let s = String::from_utf8_lossy(&self.bytes[self.at..self.at + end]).into_owned();
        self.at += end + 1;
        Ok(s)
    }
    fn done(&self) -> Result<(), DataError> {
        if self.at == self.bytes.len() {
            Ok(())
        } else {
            Err(DataError::invalid(
                self.path,
                format!("{} unexpected bytes after the last record", self.bytes.len() - self.at),
            ))
        }
    }
}

fn read_bytes(path: &Path) -> Result<Vec<u8>, DataError> {
    mipnerf_core::io::read_regular(path, mipnerf_core::io::cap::COLMAP_MODEL).map_err(|e| DataError::io(path, e))
}

fn param_count(path: &Path, model_id: i32, camera: u32) -> Result<usize, DataError> {
    model_param_count(model_id).ok_or_else(|| {
        DataError::invalid(path, format!("camera {camera}: unknown camera model id {model_id} (COLMAP's are 0 to 10)"))
    })
}

fn read_cameras_bin(path: &Path) -> Result<Vec<ColmapCamera>, DataError> {
    let bytes = read_bytes(path)?;
    let mut r = Reader { path, bytes: &bytes, at: 0 };
    let n = r.count(24, "the camera count")?;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let id = r.u32("a camera id")?;
        let model_id = r.i32("a camera model id")?;
        let (width, height) = (r.u64("a width")?, r.u64("a height")?);
        let k = param_count(path, model_id, id)?;
        let params = (0..k).map(|_| r.f64("a camera parameter")).collect::<Result<_, _>>()?;
        out.push(ColmapCamera { id, model_id, width, height, params });
    }
    r.done()?;
    Ok(out)
}

fn read_images_bin(path: &Path) -> Result<Vec<ColmapImage>, DataError> {
    let bytes = read_bytes(path)?;
    let mut r = Reader { path, bytes: &bytes, at: 0 };
    let n = r.count(73, "the image count")?;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let id = r.u32("an image id")?;
        let qvec = [r.f64("qw")?, r.f64("qx")?, r.f64("qy")?, r.f64("qz")?];
        let tvec = [r.f64("tx")?, r.f64("ty")?, r.f64("tz")?];
        let camera_id = r.u32("a camera id")?;
        let name = r.name()?;
        let points = r.count(24, "a 2D point count")?;
        r.take(points * 24, "2D points")?;
        out.push(ColmapImage { id, qvec, tvec, camera_id, name });
    }
    r.done()?;
    Ok(out)
}

fn read_points_bin(path: &Path) -> Result<Vec<ColmapPoint>, DataError> {
    let bytes = read_bytes(path)?;
    let mut r = Reader { path, bytes: &bytes, at: 0 };
    let n = r.count(51, "the 3D point count")?;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        r.u64("a point id")?;
        let xyz = [r.f64("x")?, r.f64("y")?, r.f64("z")?];
        r.take(3, "a colour")?;
        let error = r.f64("an error")?;
        let len = r.count(8, "a track length")?;
        let mut image_ids = Vec::with_capacity(len);
        for _ in 0..len {
            image_ids.push(r.u32("a track's image id")?);
            r.i32("a track's 2D point index")?;
        }
        out.push(ColmapPoint { xyz, image_ids, error });
    }
    r.done()?;
    Ok(out)
}

/// Non-comment lines of a text model, with their 1-based line numbers.
fn text_lines(path: &Path) -> Result<Vec<(usize, String)>, DataError> {
    let text = mipnerf_core::io::read_regular_text(path, mipnerf_core::io::cap::COLMAP_MODEL)
        .map_err(|e| DataError::io(path, e))?;
    Ok(text.lines().enumerate().filter(|(_, l)| !l.starts_with('#')).map(|(i, l)| (i + 1, l.to_string())).collect())
}

fn field<T: std::str::FromStr>(path: &Path, line: usize, tok: Option<&str>, what: &str) -> Result<T, DataError> {
    tok.and_then(|t| t.parse().ok())
        .ok_or_else(|| DataError::invalid(path, format!("line {line}: {what} is missing or not a number")))
}

fn finite(path: &Path, line: usize, tok: Option<&str>, what: &str) -> Result<f64, DataError> {
    let v: f64 = field(path, line, tok, what)?;
    if v.is_finite() { Ok(v) } else { Err(DataError::invalid(path, format!("line {line}: {what} is not finite"))) }
}

fn read_cameras_txt(path: &Path) -> Result<Vec<ColmapCamera>, DataError> {
    let mut out = Vec::new();
    for (line, text) in text_lines(path)?.into_iter().filter(|(_, l)| !l.trim().is_empty()) {
        let mut t = text.split_whitespace();
        let id = field(path, line, t.next(), "the camera id")?;
        let name = t.next().unwrap_or("");
        let model_id = MODELS
            .iter()
            .find(|m| m.1 == name)
            .map(|m| m.0)
            .ok_or_else(|| DataError::invalid(path, format!("line {line}: unknown camera model {name:?}")))?;
        let (width, height) = (field(path, line, t.next(), "the width")?, field(path, line, t.next(), "the height")?);
        let params: Vec<f64> = t.map(|p| finite(path, line, Some(p), "a parameter")).collect::<Result<_, _>>()?;
        let k = param_count(path, model_id, id)?;
        if params.len() != k {
            return Err(DataError::invalid(
                path,
                format!("line {line}: {name} takes {k} parameters, found {}", params.len()),
            ));
        }
        out.push(ColmapCamera { id, model_id, width, height, params });
    }
    Ok(out)
}

fn read_images_txt(path: &Path) -> Result<Vec<ColmapImage>, DataError> {
    let lines = text_lines(path)?;
    let mut out = Vec::new();
    // Two lines per image: the pose, then its 2D points (possibly empty).
    for pair in lines.chunks(2) {
        let (line, text) = &pair[0];
        if text.trim().is_empty() && pair.len() == 1 {
            continue;
        }
        let mut t = text.split_whitespace();
        let id = field(path, *line, t.next(), "the image id")?;
        let mut q = [0.0; 4];
        for (k, v) in q.iter_mut().enumerate() {
            *v = finite(path, *line, t.next(), ["qw", "qx", "qy", "qz"][k])?;
        }
        let mut tv = [0.0; 3];
        for (k, v) in tv.iter_mut().enumerate() {
            *v = finite(path, *line, t.next(), ["tx", "ty", "tz"][k])?;
        }
        let camera_id = field(path, *line, t.next(), "the camera id")?;
        let name: Vec<&str> = t.collect();
        if name.is_empty() {
            return Err(DataError::invalid(path, format!("line {line}: the image name is missing")));
        }
        out.push(ColmapImage { id, qvec: q, tvec: tv, camera_id, name: name.join(" ") });
    }
    Ok(out)
}

fn read_points_txt(path: &Path) -> Result<Vec<ColmapPoint>, DataError> {
    let mut out = Vec::new();
    for (line, text) in text_lines(path)?.into_iter().filter(|(_, l)| !l.trim().is_empty()) {
        let t: Vec<&str> = text.split_whitespace().collect();
        if t.len() < 8 || !(t.len() - 8).is_multiple_of(2) {
            return Err(DataError::invalid(
                path,
                format!("line {line}: expected ID X Y Z R G B ERROR and (IMAGE_ID, POINT2D_IDX) pairs"),
            ));
        }
        let xyz = [
            finite(path, line, Some(t[1]), "x")?,
            finite(path, line, Some(t[2]), "y")?,
            finite(path, line, Some(t[3]), "z")?,
        ];
        let image_ids =
            t[8..].chunks(2).map(|p| field(path, line, Some(p[0]), "a track's image id")).collect::<Result<_, _>>()?;
        let error = finite(path, line, Some(t[7]), "the error")?;
        out.push(ColmapPoint { xyz, image_ids, error });
    }
    Ok(out)
}

/// The `poses_bounds.npy` rows of `model` as `imgs2poses` computes them (see the module docs),
/// sorted by image name, with the names. `model_dir` names the files in errors.
///
/// # Errors
/// What the LLFF format cannot hold (distortion, several different cameras, `fx != fy`, an
/// off-centre principal point), an unsupported camera model, an image with an unknown camera,
/// a non-unit or non-finite rotation, an image that sees no 3D point (no bounds), or no images.
pub fn poses_bounds(model: &ColmapModel, model_dir: &Path) -> Result<(Vec<[f64; 17]>, Vec<String>), DataError> {
    check_model(model, model_dir)?;
    let cams = model_dir.join("cameras");
    let imgs = model_dir.join("images");
    let first = model.cameras.first().ok_or_else(|| DataError::invalid(&cams, "no cameras"))?;
    if model.images.is_empty() {
        return Err(DataError::invalid(&imgs, "no registered images"));
    }
    for c in &model.cameras {
        check_camera(c, &cams)?;
        if c.width != first.width || c.height != first.height || c.params != first.params {
            return Err(DataError::invalid(
                &cams,
                format!(
                    "camera {} differs from camera {} ({}x{} {:?} against {}x{} {:?}): the LLFF format holds one \
                     camera; reconstruct with one shared camera (COLMAP's --ImageReader.single_camera 1)",
                    c.id, first.id, c.width, c.height, c.params, first.width, first.height, first.params
                ),
            ));
        }
    }
    let (h, w, f) = (first.height as f64, first.width as f64, first.params[0]);
    // Camera-to-world poses with LLFF's column order [down, right, back], in file order (every
    // image's camera exists: `check_model`).
    let mut poses = Vec::with_capacity(model.images.len());
    for im in &model.images {
        let [qw, qx, qy, qz] = im.qvec;
        let norm = (qw * qw + qx * qx + qy * qy + qz * qz).sqrt();
        if (norm - 1.0).abs() > 1e-3 {
            return Err(DataError::invalid(
                &imgs,
                format!("image {} ({}): qvec {:?} is not a unit quaternion", im.id, im.name, im.qvec),
            ));
        }
        // COLMAP's qvec2rotmat of the normalised quaternion.
        let r = DMat3::from_quat(DQuat::from_xyzw(qx / norm, qy / norm, qz / norm, qw / norm));
        let rt = r.transpose();
        let center = -(rt * DVec3::from_array(im.tvec));
        let (right, down, forward) = (rt.x_axis, rt.y_axis, rt.z_axis);
        poses.push((down, right, -forward, center));
    }
    // Depth of every point in every image that sees it.
    let index: HashMap<u32, usize> = model.images.iter().enumerate().map(|(i, im)| (im.id, i)).collect();
    let mut depths: Vec<Vec<f64>> = vec![Vec::new(); poses.len()];
    for p in &model.points {
        let x = DVec3::from_array(p.xyz);
        let mut seen = HashSet::new();
        for id in &p.image_ids {
            // An image that observes a point twice (two features) counts it once, as the visibility
            // matrix of imgs2poses does.
            if let Some(&i) = index.get(id)
                && seen.insert(i)
            {
                let (_, _, back, c) = poses[i];
                depths[i].push(-(x - c).dot(back));
            }
        }
    }
    let mut order: Vec<usize> = (0..poses.len()).collect();
    order.sort_by(|&a, &b| model.images[a].name.cmp(&model.images[b].name));
    let mut rows = Vec::with_capacity(order.len());
    for &i in &order {
        let d = &mut depths[i];
        if d.is_empty() {
            let im = &model.images[i];
            return Err(DataError::invalid(
                &imgs,
                format!(
                    "image {} ({}) sees no 3D point, so it has no depth bounds; remove it from the model",
                    im.id, im.name
                ),
            ));
        }
        d.sort_by(f64::total_cmp);
        let (near, far) = (llff::percentile(d, 0.1), llff::percentile(d, 99.9));
        let im = &model.images[i];
        if near.is_nan() || near <= 0.0 {
            return Err(DataError::invalid(
                &imgs,
                format!(
                    "image {} ({}): its 3D points lie behind it (near bound {}): the model's poses or points are \
                     wrong; reconstruct again",
                    im.id,
                    im.name,
                    crate::show(near)
                ),
            ));
        }
        if !(far.is_finite() && far <= MAX_DEPTH_RATIO * near) {
            return Err(DataError::invalid(
                &imgs,
                format!(
                    "image {} ({}): its 3D points reach from {} to {} away, more than {} times as far as near: an \
                     outlier point the model should not hold; remove it (or reconstruct again)",
                    im.id,
                    im.name,
                    crate::show(near),
                    crate::show(far),
                    crate::show(MAX_DEPTH_RATIO)
                ),
            ));
        }
        let (a, b, c, t) = poses[i];
        let hwf = [h, w, f];
        let mut row = [0.0; 17];
        for r in 0..3 {
            row[r * 5..r * 5 + 5].copy_from_slice(&[a[r], b[r], c[r], t[r], hwf[r]]);
        }
        row[15] = near;
        row[16] = far;
        rows.push(row);
    }
    Ok((rows, order.iter().map(|&i| model.images[i].name.clone()).collect()))
}

/// The most the far bound of a photo may be over its near bound: real scenes span far less (the
/// LLFF scenes 10 to 100); more means an outlier 3D point, whose far bound would stretch every
/// sample of that photo's rays over empty space.
pub const MAX_DEPTH_RATIO: f64 = 1e6;

/// Refuses a model whose images or points make no sense, naming the image or point: duplicate
/// image ids or names, an image of a camera the model does not have, an image name that leads
/// out of `images/` (`..`, an absolute path), a 3D point that is not finite.
///
/// # Errors
/// The first problem found, naming the file of the model it is in.
pub fn check_model(model: &ColmapModel, model_dir: &Path) -> Result<(), DataError> {
    let imgs = model_dir.join("images");
    let camera_ids: HashSet<u32> = model.cameras.iter().map(|c| c.id).collect();
    let (mut ids, mut names) = (HashSet::new(), HashSet::new());
    for im in &model.images {
        let what = format!("image {} ({})", im.id, im.name);
        if !ids.insert(im.id) {
            return Err(DataError::invalid(&imgs, format!("{what}: image id {} is given twice", im.id)));
        }
        if !names.insert(im.name.as_str()) {
            return Err(DataError::invalid(&imgs, format!("{what}: the name {:?} is given twice", im.name)));
        }
        if !camera_ids.contains(&im.camera_id) {
            return Err(DataError::invalid(
                &imgs,
                format!("{what} uses camera {}, which the model's cameras do not have", im.camera_id),
            ));
        }
        let inside = !im.name.is_empty()
            && Path::new(&im.name).components().all(|c| matches!(c, std::path::Component::Normal(_)));
        if !inside {
            return Err(DataError::invalid(
                &imgs,
                format!("{what}: the name leads out of images/ (only names inside the folder are read)"),
            ));
        }
        if im.qvec.iter().chain(&im.tvec).any(|x| !x.is_finite()) {
            return Err(DataError::invalid(&imgs, format!("{what}: its pose is not finite")));
        }
    }
    if let Some(p) = model.points.iter().find(|p| p.xyz.iter().any(|x| !x.is_finite())) {
        return Err(DataError::invalid(
            &model_dir.join("points3D"),
            format!("a 3D point at {:?} is not finite", p.xyz),
        ));
    }
    Ok(())
}

/// Refuses a camera the LLFF format cannot hold, with what to do instead.
fn check_camera(c: &ColmapCamera, path: &Path) -> Result<(), DataError> {
    let name = model_name(c.model_id);
    let Some(model) = model_of(c.model_id) else {
        return Err(DataError::invalid(
            path,
            format!(
                "camera {} is {name}: a fisheye or exotic model; supported are SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, \
                 RADIAL and OPENCV (undistort first: colmap image_undistorter, or pycolmap.undistort_images)",
                c.id
            ),
        ));
    };
    let (fx, fy, cx, cy, distortion) = intrinsics(model, &c.params);
    if distortion.iter().any(|&k| k != 0.0) {
        return Err(DataError::invalid(
            path,
            format!(
                "camera {} ({name}) has lens distortion {distortion:?}, which the pinhole cameras of NeRF cannot \
                 model; undistort the images first: colmap image_undistorter --image_path images --input_path \
                 sparse/0 --output_path undistorted (or pycolmap.undistort_images), then use that folder",
                c.id
            ),
        ));
    }
    if !(fx > 0.0 && fy > 0.0 && c.width > 0 && c.height > 0) {
        return Err(DataError::invalid(
            path,
            format!("camera {}: focal {fx} and size {}x{} must be positive", c.id, c.width, c.height),
        ));
    }
    if (fx - fy).abs() > 1e-3 * fx {
        return Err(DataError::invalid(
            path,
            format!("camera {}: fx {fx} and fy {fy} differ; the LLFF format holds one focal length", c.id),
        ));
    }
    let (w, h) = (c.width as f64, c.height as f64);
    if (cx - w / 2.0).abs() > 0.01 * w || (cy - h / 2.0).abs() > 0.01 * h {
        return Err(DataError::invalid(
            path,
            format!(
                "camera {}: the principal point ({cx}, {cy}) is more than 1% away from the image centre ({}, {}), \
                 which the LLFF format assumes",
                c.id,
                w / 2.0,
                h / 2.0
            ),
        ));
    }
    Ok(())
}

/// The images of `names` (in that order) at `factor` (0 and 1: full size): from
/// `dir/images_{factor}` when it holds them, else `dir/images` box-filtered by `factor` in memory
/// (said in the returned note). Each full-size image must have `camera`'s size.
///
/// # Errors
/// A missing or undecodable image, or one of another size than the camera's.
pub fn read_images(
    dir: &Path,
    names: &[String],
    camera: &ColmapCamera,
    factor: u32,
) -> Result<(Vec<LlffImage>, Option<String>), DataError> {
    let small = dir.join(format!("images_{factor}"));
    let from_small = factor > 1 && names.iter().all(|n| small.join(n).is_file());
    let mut out = Vec::with_capacity(names.len());
    for n in names {
        let file = if from_small { small.join(n) } else { dir.join("images").join(n) };
        crate::check_present(
            &file,
            "listed in the COLMAP model's images but missing on disk (the model and images/ disagree)",
        )?;
        let (w, h, rgba, _) = read_png_rgba(&file)?;
        let mut im = LlffImage { file, width: w, height: h, rgba };
        if !from_small {
            if (u64::from(w), u64::from(h)) != (camera.width, camera.height) {
                return Err(DataError::invalid(
                    &im.file,
                    format!("image is {w}x{h}, the COLMAP camera {} is {}x{}", camera.id, camera.width, camera.height),
                ));
            }
            if factor > 1 {
                let (nw, nh) = ((w / factor).max(1), (h / factor).max(1));
                im.rgba = crate::box_resize_rgba8(&im.rgba, w, h, nw, nh);
                (im.width, im.height) = (nw, nh);
            }
        }
        out.push(im);
    }
    let note = (factor > 1 && !from_small).then(|| {
        format!("images_{factor}/ is absent: images/ box-filtered by {factor} in memory (as LLFF's images_{factor} would be)")
    });
    Ok((out, note))
}

/// Loads `split` of a COLMAP scene in `dir` as LLFF loads `poses_bounds.npy` (see the module
/// docs), with images at `factor` ([`read_images`]).
///
/// # Errors
/// Every [`DataError`] of [`find_model`], [`read_model`], [`poses_bounds`], [`read_images`] and
/// the LLFF loader.
pub fn load(dir: &Path, split: Split, factor: u32, spherify: Option<llff::Spherify>) -> Result<Dataset, DataError> {
    let s = Scene::read(dir, factor)?;
    let mut ds = llff::from_rows(dir, &s.model_dir, &s.rows, s.images, factor, split, spherify)?;
    ds.notes.extend(s.notes);
    Ok(ds)
}

/// A COLMAP scene as the LLFF loader takes it: the model's folder, the `poses_bounds` rows and
/// image names in name order, the images at the chosen factor, and the notes on the choices made.
struct Scene {
    model_dir: PathBuf,
    rows: Vec<[f64; 17]>,
    names: Vec<String>,
    images: Vec<LlffImage>,
    notes: Vec<String>,
}

impl Scene {
    /// [`find_model`], [`read_model`], [`poses_bounds`] and [`read_images`], in that order.
    fn read(dir: &Path, factor: u32) -> Result<Self, DataError> {
        let (model_dir, model_note) = find_model(dir)?;
        let model = read_model(&model_dir)?;
        let (rows, names) = poses_bounds(&model, &model_dir)?;
        let (images, image_note) = read_images(dir, &names, &model.cameras[0], factor)?;
        Ok(Self { model_dir, rows, names, images, notes: model_note.into_iter().chain(image_note).collect() })
    }
}

/// `mipnerf convert --to llff`: writes `out/poses_bounds.npy` for the COLMAP scene in `input` and
/// its registered images, sorted by name, as PNGs in `out/images` (factor 0 or 1) or
/// `out/images_{factor}`, so that the LLFF loader (or the official code) reads `out`. The images
/// are written under a temporary name and replace the folder whole (never mixed into it), and
/// `poses_bounds.npy` is written last; nothing in `out` is touched before the scene is read.
///
/// # Errors
/// The errors of [`load`]'s steps, and unwritable files.
pub fn convert_to_llff(input: &Path, out: &Path, factor: u32) -> Result<Vec<String>, DataError> {
    let Scene { rows, names, images, .. } = Scene::read(input, factor)?;
    let folder = if factor > 1 { out.join(format!("images_{factor}")) } else { out.join("images") };
    std::fs::create_dir_all(out).map_err(|e| DataError::io(out, e))?;
    let partial = mipnerf_core::io::start_partial_dir(&folder)?;
    for (i, im) in images.iter().enumerate() {
        // Numbered in name order, so any reader that sorts the folder finds them in the rows' order.
        let stem = Path::new(&names[i]).file_stem().map_or_else(String::new, |s| s.to_string_lossy().into_owned());
        crate::write_png_rgba(&partial.join(format!("{i:04}_{stem}.png")), im.width, im.height, &im.rgba)?;
    }
    // The new images are whole: only now does the old dataset stop being whole.
    let npy = out.join("poses_bounds.npy");
    if npy.is_file() {
        std::fs::remove_file(&npy).map_err(|e| DataError::io(&npy, e))?;
    }
    mipnerf_core::io::swap_in_dir(&folder)?;
    llff::write_poses_bounds(&npy, &rows)?;
    Ok(names)
}
