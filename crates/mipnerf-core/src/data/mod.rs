//! Datasets: files on disk to views (camera + pixels), and views to batches of rays with targets.
//!
//! Formats:
//! - [`blender`]: `transforms_{train,val,test}.json` with RGBA PNGs (the NeRF synthetic scenes);
//! - [`multiscale`]: the official multiscale Blender format (`metadata.json`, 4 scales per view),
//!   and its converter;
//! - [`llff`]: forward-facing captures (`poses_bounds.npy`, `images_{factor}`), NDC rays;
//! - [`nerfstudio`]: nerfstudio's and Instant-NGP's `transforms.json` captures, for the process
//!   step ([`process`]), with [`ply`] for their point clouds;
//! - [`camera_path`]: camera files (`transforms.json`-style poses and intrinsics) to render;
//! - [`demo`]: a procedural scene rendered by the project's own ray tracer, written in the
//!   multiscale format; it needs no files.
//!
//! Training batches are drawn uniformly from all training pixels of all views and scales (the
//! official `all_images` batching): a batch samples global pixel indices and makes each pixel's
//! ray on the fly from its view's camera, so images are never copied per step and rays are never
//! stored for the whole dataset.

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

pub(crate) use image_files::{check_present, image_pixels, image_size, read_png_rgba, write_png_rgba};

use std::path::{Path, PathBuf};

use crate::camera::{Camera, PixelCenters};
use crate::cone::Ray;
use crate::rng::{RayRng, Stream};
pub(crate) use resample::box_resize_rgba8;
pub use resample::{box_resize, down2};

/// A problem with a dataset's files. Every variant names the file and says what is wrong.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DataError {
    /// A file or directory could not be read or written.
    #[error("{}: {error}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// What the system said.
        error: std::io::Error,
    },
    /// A file's contents are malformed.
    #[error("{}: {problem}", path.display())]
    Invalid {
        /// The file.
        path: PathBuf,
        /// What is wrong, in words a user can act on.
        problem: String,
    },
    /// A directory is no dataset format this tool knows.
    #[error(
        "{}: not a known dataset: expected transforms_train.json (Blender), metadata.json \
         (multiscale Blender), poses_bounds.npy (LLFF) or sparse/ and images/ (COLMAP)",
        path.display()
    )]
    UnknownFormat {
        /// The directory.
        path: PathBuf,
    },
}

impl DataError {
    pub(crate) fn invalid(path: &Path, problem: impl Into<String>) -> Self {
        Self::Invalid { path: path.to_path_buf(), problem: problem.into() }
    }
    pub(crate) fn io(path: &Path, error: std::io::Error) -> Self {
        Self::Io { path: path.to_path_buf(), error }
    }
}

/// Reads and parses a JSON file, with errors naming the file (and the line for syntax errors).
/// Bytes of parsed JSON (`serde_json::Value`s, 32 bytes each, and their lists) per byte of
/// text, at most: a list of one-digit numbers is 2 bytes of text a value. The text itself is one
/// more.
const JSON_BYTES_PER_TEXT_BYTE: u64 = 17;

pub(crate) fn read_json(path: &Path) -> Result<serde_json::Value, DataError> {
    let len = std::fs::metadata(path).map_err(|e| DataError::io(path, e))?.len();
    crate::memory::check(len.saturating_mul(JSON_BYTES_PER_TEXT_BYTE), &format!("parsing this {len}-byte file"))
        .map_err(|e| DataError::invalid(path, e))?;
    let bytes = crate::io::read_regular(path, crate::io::cap::JSON).map_err(|e| DataError::io(path, e))?;
    if bytes.starts_with(b"\x93NUMPY") {
        return Err(DataError::invalid(path, "is a NumPy array file (such as poses_bounds.npy), not JSON"));
    }
    let text = String::from_utf8(bytes).map_err(|_| {
        DataError::invalid(path, "is not UTF-8 text, so not JSON (a binary file given for a JSON one?)")
    })?;
    serde_json::from_str(&text).map_err(|e| DataError::invalid(path, format!("malformed JSON: {e}")))
}

/// Which part of a dataset.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Split {
    /// Training views.
    Train,
    /// Validation views.
    Val,
    /// Held-out test views.
    Test,
}

impl Split {
    /// `train`, `val` or `test`.
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Self::Train => "train",
            Self::Val => "val",
            Self::Test => "test",
        }
    }
}

impl std::fmt::Display for Split {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// An image's pixels, straight (not premultiplied) RGBA, row-major.
#[derive(Clone, Debug, PartialEq)]
pub enum Pixels {
    /// 8 bits per channel, as read from a PNG (4 bytes per pixel).
    Rgba8(Vec<u8>),
    /// Floating point in `[0, 1]` (after area downsampling), 4 values per pixel.
    RgbaF32(Vec<f32>),
}

impl Pixels {
    /// Straight RGBA of pixel `i` in `[0, 1]`.
    #[must_use]
    #[inline]
    pub fn rgba(&self, i: usize) -> [f32; 4] {
        match self {
            Self::Rgba8(v) => std::array::from_fn(|c| f32::from(v[4 * i + c]) / 255.0),
            Self::RgbaF32(v) => std::array::from_fn(|c| v[4 * i + c]),
        }
    }

    /// Bytes held.
    #[must_use]
    pub fn bytes(&self) -> usize {
        match self {
            Self::Rgba8(v) => v.len(),
            Self::RgbaF32(v) => v.len() * 4,
        }
    }
}

/// One image with its camera.
#[derive(Clone, Debug)]
pub struct View {
    /// The image file it came from (or will be written to), for messages and outputs.
    pub file: PathBuf,
    /// Its camera.
    pub camera: Camera,
    /// Its pixels.
    pub pixels: Pixels,
    /// Near bound along its rays.
    pub near: f32,
    /// Far bound along its rays.
    pub far: f32,
    /// Loss weight of its rays (`4^scale` in a multiscale dataset).
    pub lossmult: f32,
    /// Scale index `j` (downsampled by `2^j`); 0 in single-scale datasets.
    pub scale: u32,
}

impl View {
    /// A full-resolution image held in memory (no file): `name` stands for it in messages and
    /// outputs; loss weight 1, scale 0.
    #[must_use]
    pub fn in_memory(name: &str, camera: Camera, pixels: Pixels, near: f32, far: f32) -> Self {
        Self { file: PathBuf::from(name), camera, pixels, near, far, lossmult: 1.0, scale: 0 }
    }
}

/// Maps rays to normalised device coordinates (forward-facing scenes, the official
/// `convert_to_ndc` with the near plane at 1).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Ndc {
    /// Focal length in pixels.
    pub focal: f32,
    /// Image width.
    pub width: f32,
    /// Image height.
    pub height: f32,
}

/// A loaded split: its views and how to make rays and colours from them.
#[derive(Clone, Debug)]
pub struct Dataset {
    /// Where it was loaded from.
    pub root: PathBuf,
    /// Which split.
    pub split: Split,
    /// The views (all scales of all images for multiscale data); private because the pixel
    /// offsets are derived from them.
    views: Vec<View>,
    /// Composite RGBA on white (Blender) rather than dropping alpha.
    pub white_bkgd: bool,
    /// Rays through pixel centres or corners.
    pub centers: PixelCenters,
    /// Rays in NDC space (LLFF), else world space.
    pub ndc: Option<Ndc>,
    /// A camera path for rendering videos, where the format defines one (LLFF's spiral).
    pub render_path: Vec<Camera>,
    /// Choices the loader made that a user should hear about (which COLMAP model was taken,
    /// images downsampled in memory), one sentence each.
    pub notes: Vec<String>,
    /// The similarity the loader applied to the data's own world frame to make the scene's:
    /// LLFF's and COLMAP's recentring, rescaling and spherifying; the identity for Blender,
    /// multiscale and demo data, whose frame is the scene's.
    pub data_to_scene: crate::camera::Similarity,
    /// Cumulative pixel counts: view `v` holds global pixels `offsets[v]..offsets[v + 1]`.
    offsets: Vec<u64>,
}

impl Dataset {
    /// A dataset of views held in memory (see [`View::in_memory`]), for apps that bring their own
    /// images and cameras.
    ///
    /// # Errors
    /// [`DataError::Invalid`] when there are no views.
    pub fn from_views(split: Split, views: Vec<View>, white_bkgd: bool) -> Result<Self, DataError> {
        Self::new(Path::new("<memory>"), split, views, white_bkgd)
    }

    /// A dataset of `views`.
    ///
    /// # Errors
    /// [`DataError::Invalid`] naming `root` when there are no views.
    pub fn new(root: &Path, split: Split, views: Vec<View>, white_bkgd: bool) -> Result<Self, DataError> {
        if views.is_empty() {
            return Err(DataError::invalid(root, format!("the {split} split has no images")));
        }
        let mut offsets = Vec::with_capacity(views.len() + 1);
        let mut acc = 0u64;
        offsets.push(0);
        for v in &views {
            acc += u64::from(v.camera.width) * u64::from(v.camera.height);
            offsets.push(acc);
        }
        Ok(Self {
            root: root.to_path_buf(),
            split,
            views,
            white_bkgd,
            centers: PixelCenters::Centered,
            ndc: None,
            render_path: Vec::new(),
            notes: Vec::new(),
            data_to_scene: crate::camera::Similarity::IDENTITY,
            offsets,
        })
    }

    /// The views (all scales of all images for multiscale data), in order.
    #[must_use]
    pub fn views(&self) -> &[View] {
        &self.views
    }

    /// The views, to change their pixels (not their sizes: the offsets are derived from them).
    pub(crate) fn views_mut(&mut self) -> &mut [View] {
        &mut self.views
    }

    /// Makes the scene unbounded (mip-NeRF 360's setting, [`crate::contract`]): every ray's far
    /// bound becomes [`UNBOUNDED_FAR`](crate::contract::UNBOUNDED_FAR). The cameras must lie in
    /// the unit ball (the region the photos were taken from is what the contraction leaves as it
    /// is; [`llff::Spherify::UnitBall`] puts them there).
    ///
    /// # Errors
    /// A camera outside the unit ball (beyond rounding), named.
    pub fn make_unbounded(&mut self) -> Result<(), String> {
        /// How far past the unit sphere rounding may put the farthest camera.
        const SLACK: f64 = 1e-6;
        for v in &self.views {
            let o = v.camera.origin();
            let d = (o[0] * o[0] + o[1] * o[1] + o[2] * o[2]).sqrt();
            if d.is_nan() || d > 1.0 + SLACK {
                return Err(format!(
                    "{}: its camera is {d:.4} from the scene's centre; an unbounded scene needs every camera in the unit \
                     ball",
                    v.file.display()
                ));
            }
        }
        for v in &mut self.views {
            v.far = crate::contract::UNBOUNDED_FAR;
        }
        Ok(())
    }

    /// Total pixels over all views.
    #[must_use]
    pub fn num_pixels(&self) -> u64 {
        *self.offsets.last().unwrap_or(&0)
    }

    /// Cumulative pixel counts: view `v` holds global pixels `offsets[v]..offsets[v + 1]` (one more
    /// entry than views). Global pixel `g` is what [`sample_batch`](Self::sample_batch) draws.
    #[must_use]
    pub fn pixel_offsets(&self) -> &[u64] {
        &self.offsets
    }

    /// Bytes of pixel data held in memory.
    #[must_use]
    pub fn pixel_bytes(&self) -> usize {
        self.views.iter().map(|v| v.pixels.bytes()).sum()
    }

    /// The view and pixel coordinates of global pixel `g`.
    #[must_use]
    pub fn locate(&self, g: u64) -> (usize, u32, u32) {
        let v = self.offsets.partition_point(|&o| o <= g) - 1;
        let local = g - self.offsets[v];
        let w = u64::from(self.views[v].camera.width);
        (v, (local % w) as u32, (local / w) as u32)
    }

    /// The target colour of pixel `(x, y)` of view `v`: composited on white, or RGB with alpha
    /// dropped, as the official loaders do.
    #[must_use]
    pub fn target(&self, v: usize, x: u32, y: u32) -> [f32; 3] {
        let view = &self.views[v];
        let [r, g, b, a] = view.pixels.rgba((y * view.camera.width + x) as usize);
        if self.white_bkgd { [r * a + (1.0 - a), g * a + (1.0 - a), b * a + (1.0 - a)] } else { [r, g, b] }
    }

    /// How view `v`'s pixels become rays: the dataset's pixel centres and NDC mapping, the
    /// view's bounds and loss weight.
    #[must_use]
    pub fn ray_spec(&self, v: usize) -> RaySpec {
        let view = &self.views[v];
        RaySpec { centers: self.centers, bounds: (view.near, view.far), lossmult: view.lossmult, ndc: self.ndc }
    }

    /// The ray of pixel `(x, y)` of view `v` (in NDC space for NDC datasets).
    #[must_use]
    pub fn ray(&self, v: usize, x: u32, y: u32) -> Ray {
        let view = &self.views[v];
        camera_ray(&view.camera, x, y, self.ray_spec(v))
    }

    /// Every ray of view `v`, row-major.
    #[must_use]
    pub fn view_rays(&self, v: usize) -> Vec<Ray> {
        let c = &self.views[v].camera;
        (0..c.height).flat_map(|y| (0..c.width).map(move |x| (x, y))).map(|(x, y)| self.ray(v, x, y)).collect()
    }

    /// Appends the `k x k` rays of pixel `(x, y)` of view `v` for a supersampled NeRF (see
    /// [`push_camera_rays`]).
    pub fn push_pixel_rays(&self, v: usize, x: u32, y: u32, k: usize, out: &mut Vec<Ray>) {
        let view = &self.views[v];
        push_camera_rays(&view.camera, x, y, self.ray_spec(v), k, out);
    }

    /// Every target colour of view `v`, row-major.
    #[must_use]
    pub fn view_targets(&self, v: usize) -> Vec<[f32; 3]> {
        let c = &self.views[v].camera;
        (0..c.height).flat_map(|y| (0..c.width).map(move |x| (x, y))).map(|(x, y)| self.target(v, x, y)).collect()
    }

    /// A training batch of `draw.pixels` pixels drawn uniformly (with replacement) from all
    /// pixels of all views, a pure function of `(seed, step)`. Fills `targets` with one colour
    /// per pixel and `rays` with `supersample²` rays per pixel (see
    /// [`push_pixel_rays`](Self::push_pixel_rays)). With `random_bkgd` (the model's
    /// `ModelConfig::random_bkgd`), batch pixel `i`'s target is
    /// its straight colour composited on [`random_background`](crate::rng::random_background)`(seed,
    /// step, i)`, the colour the model renders it on; otherwise [`target`](Self::target).
    ///
    /// # Panics
    /// If `n` is `2^31` or more (two 32-bit random draws per pixel are counted in a `u32`);
    /// callers bound the batch well below that.
    pub fn sample_batch(&self, draw: BatchDraw, rays: &mut Vec<Ray>, targets: &mut Vec<[f32; 3]>) {
        let BatchDraw { pixels: n, seed, step, supersample, random_bkgd } = draw;
        rays.clear();
        targets.clear();
        for (i, (v, x, y)) in self.batch_pixels(n, seed, step).enumerate() {
            let i = i as u32;
            self.push_pixel_rays(v, x, y, supersample, rays);
            targets.push(if random_bkgd {
                let view = &self.views[v];
                let [r, g, b, a] = view.pixels.rgba((y * view.camera.width + x) as usize);
                let bg = crate::rng::random_background(seed, step, i);
                [r * a + bg[0] * (1.0 - a), g * a + bg[1] * (1.0 - a), b * a + bg[2] * (1.0 - a)]
            } else {
                self.target(v, x, y)
            });
        }
    }

    /// The pixels (view, x, y) of [`sample_batch`](Self::sample_batch)`(n, seed, step, ..)`, in
    /// batch order: what a backend that makes its batches elsewhere (the GPU) needs to know
    /// which of them an occupancy grid lets through.
    ///
    /// # Panics
    /// If `n` is `2^31` or more.
    pub fn batch_pixels(&self, n: usize, seed: u32, step: u32) -> impl Iterator<Item = (usize, u32, u32)> + '_ {
        let total = self.num_pixels();
        let rng = RayRng::new(seed, step, Stream::RayBatch, 0);
        let n = u32::try_from(n).ok().filter(|n| *n < 1 << 31).unwrap_or_else(|| panic!("sample_batch: {n} pixels"));
        (0..n).map(move |i| {
            let r = (u64::from(rng.bits(2 * i)) << 32) | u64::from(rng.bits(2 * i + 1));
            self.locate(r % total)
        })
    }

    /// The same dataset without its pixels: cameras, bounds and offsets, enough for
    /// [`ray`](Self::ray) and [`batch_pixels`](Self::batch_pixels) at no memory cost (a backend
    /// that holds the pixels elsewhere keeps this). [`target`](Self::target) and
    /// [`sample_batch`](Self::sample_batch) must not be called on it (they panic: no pixels).
    #[must_use]
    pub fn without_pixels(&self) -> Self {
        let views = self
            .views
            .iter()
            .map(|v| View {
                file: v.file.clone(),
                camera: v.camera.clone(),
                pixels: Pixels::Rgba8(Vec::new()),
                near: v.near,
                far: v.far,
                lossmult: v.lossmult,
                scale: v.scale,
            })
            .collect();
        Self {
            root: self.root.clone(),
            split: self.split,
            views,
            white_bkgd: self.white_bkgd,
            centers: self.centers,
            ndc: self.ndc,
            render_path: self.render_path.clone(),
            notes: self.notes.clone(),
            data_to_scene: self.data_to_scene,
            offsets: self.offsets.clone(),
        }
    }

    /// Whether any pixel of any view is not fully opaque (alpha below 1): what training on
    /// random backgrounds needs (photos without alpha have none).
    #[must_use]
    pub fn has_transparency(&self) -> bool {
        self.views.iter().any(|v| match &v.pixels {
            Pixels::Rgba8(b) => b.chunks_exact(4).any(|p| p[3] < 255),
            Pixels::RgbaF32(f) => f.chunks_exact(4).any(|p| p[3] < 1.0),
        })
    }

    /// The scales present, sorted.
    #[must_use]
    pub fn scales(&self) -> Vec<u32> {
        let mut s: Vec<u32> = self.views.iter().map(|v| v.scale).collect();
        s.sort_unstable();
        s.dedup();
        s
    }
}

/// Which training batch [`Dataset::sample_batch`] draws: how many pixels, for which run and
/// step, with how many rays a pixel and on what background.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BatchDraw {
    /// Pixels in the batch.
    pub pixels: usize,
    /// The run's seed.
    pub seed: u32,
    /// The training step.
    pub step: u32,
    /// `supersample²` rays a pixel (a supersampled NeRF's), 1 for Mip-NeRF's one cone.
    pub supersample: usize,
    /// Targets composited on the random background the model renders them on.
    pub random_bkgd: bool,
}

impl BatchDraw {
    /// `pixels` pixels of step `step` of run `seed`, one ray a pixel, the dataset's own
    /// background.
    #[must_use]
    pub fn new(pixels: usize, seed: u32, step: u32) -> Self {
        Self { pixels, seed, step, supersample: 1, random_bkgd: false }
    }
}

/// How a camera's pixels become rays: where in a pixel its ray passes, the near and far
/// bounds, the loss weight the rays carry, and the NDC mapping of forward-facing data.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RaySpec {
    /// Where in a pixel its ray passes.
    pub centers: PixelCenters,
    /// Near and far bounds along the ray.
    pub bounds: (f32, f32),
    /// The loss weight of the rays (a multiscale dataset's per-scale weight).
    pub lossmult: f32,
    /// The NDC mapping of a forward-facing dataset.
    pub ndc: Option<Ndc>,
}

/// The ray of pixel `(x, y)` of `camera` made as `spec` says, mapped to NDC space when
/// `spec.ndc` is given (forward-facing scenes).
#[must_use]
pub fn camera_ray(camera: &Camera, x: u32, y: u32, spec: RaySpec) -> Ray {
    let RaySpec { centers, bounds: (near, far), lossmult, ndc } = spec;
    let ray = camera.ray_at(x, y, centers, near, far, lossmult);
    match ndc {
        None => ray,
        Some(ndc) => llff::ndc_ray(camera, x, y, centers, ndc, ray),
    }
}

/// Appends the `k x k` rays of pixel `(x, y)` of `camera` for a supersampled NeRF: through a
/// regular sub-pixel grid, each a cone of `1/k` of the pixel's radius. With `k == 1`, the pixel's
/// own ray ([`camera_ray`]). Sub-pixel rays in NDC space are not supported: `k` is taken as 1.
pub fn push_camera_rays(camera: &Camera, x: u32, y: u32, spec: RaySpec, k: usize, out: &mut Vec<Ray>) {
    let base = camera_ray(camera, x, y, spec);
    if k <= 1 || spec.ndc.is_some() {
        out.push(base);
        return;
    }
    for sy in 0..k {
        for sx in 0..k {
            let px = f64::from(x) + (sx as f64 + 0.5) / k as f64;
            let py = f64::from(y) + (sy as f64 + 0.5) / k as f64;
            let d = glam::DVec3::from_array(camera.direction_f64(px, py));
            out.push(Ray {
                direction: d.as_vec3(),
                viewdir: d.normalize().as_vec3(),
                radius: base.radius / k as f32,
                ..base
            });
        }
    }
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
    /// official loaders do).
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
    /// An unbounded scene ([`crate::contract`]): photos spherified with the farthest camera on the
    /// unit sphere ([`llff::Spherify::UnitBall`]), every ray's far bound at
    /// [`UNBOUNDED_FAR`](crate::contract::UNBOUNDED_FAR) ([`Dataset::make_unbounded`]). Needs
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
    let white = opts.white_bkgd.unwrap_or(!format.is_photos());
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
    crate::memory::check(pixels.saturating_mul(4), &format!("loading {images} images of {pixels} pixels in all"))
        .map_err(|e| {
            DataError::invalid(
                path,
                format!("{e}; train on fewer or smaller images (`multiscale::convert_resized` makes smaller ones)"),
            )
        })
}

impl From<crate::io::IoError> for DataError {
    fn from(e: crate::io::IoError) -> Self {
        Self::Io { path: e.path, error: e.error }
    }
}

/// A 3x4 camera-to-world matrix from a JSON 4x4 (or 3x4) array, checked for finiteness.
/// A number as an error message shows it: plainly between 1e-3 and 1e7 (and 0), else in
/// scientific notation (`3e38`, not 39 digits).
#[must_use]
pub(crate) fn show(x: f64) -> String {
    if x == 0.0 || (1e-3..1e7).contains(&x.abs()) { format!("{x}") } else { format!("{x:e}") }
}

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
