//! A dataset in memory: views (camera + pixels), and views to batches of rays with targets.
//!
//! The files a dataset is loaded from (Blender, multiscale, LLFF, COLMAP, nerfstudio captures,
//! masks, camera paths) are read by the `mipnerf-data` crate; this module is what training,
//! rendering and the occupancy grid take from them, and what an app that brings its own images and
//! cameras builds ([`Dataset::from_views`]).
//!
//! Training batches are drawn uniformly from all training pixels of all views and scales (the
//! official `all_images` batching): a batch samples global pixel indices and makes each pixel's
//! ray on the fly from its view's camera, so images are never copied per step and rays are never
//! stored for the whole dataset.

use std::path::{Path, PathBuf};

use glam::DVec3;

use crate::camera::{Camera, PixelCenters};
use crate::cone::{Ray, radius_from_spacing};
use crate::config::DataFit;
use crate::rng::{RayRng, Stream};
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
    /// [`DataError::Invalid`] naming `path`.
    #[must_use]
    pub fn invalid(path: &Path, problem: impl Into<String>) -> Self {
        Self::Invalid { path: path.to_path_buf(), problem: problem.into() }
    }
    /// [`DataError::Io`] naming `path`.
    #[must_use]
    pub fn io(path: &Path, error: std::io::Error) -> Self {
        Self::Io { path: path.to_path_buf(), error }
    }
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
    /// Photos whose foreground masks were applied as their alpha: an object alone.
    pub masked: bool,
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
            masked: false,
            notes: Vec::new(),
            data_to_scene: crate::camera::Similarity::IDENTITY,
            offsets,
        })
    }

    /// What this dataset implies for the model ([`DataFit`]): forward-facing when its rays are
    /// in NDC space, composited as it is, masked as it was loaded.
    #[must_use]
    pub fn model_fit(&self) -> DataFit {
        DataFit { forward_facing: self.ndc.is_some(), white_bkgd: self.white_bkgd, masked: self.masked }
    }

    /// The views (all scales of all images for multiscale data), in order.
    #[must_use]
    pub fn views(&self) -> &[View] {
        &self.views
    }

    /// The views, to change their pixels (not their sizes: the offsets are derived from them).
    pub fn views_mut(&mut self) -> &mut [View] {
        &mut self.views
    }

    /// Makes the scene unbounded (mip-NeRF 360's setting, [`crate::contract`]): every ray's far
    /// bound becomes [`UNBOUNDED_FAR`](crate::contract::UNBOUNDED_FAR). The cameras must lie in
    /// the unit ball (the region the photos were taken from is what the contraction leaves as it
    /// is; `mipnerf_data::llff::Spherify::UnitBall` puts them there).
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
            masked: self.masked,
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
        Some(ndc) => ndc_ray(camera, x, y, centers, ndc, ray),
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

impl From<crate::io::IoError> for DataError {
    fn from(e: crate::io::IoError) -> Self {
        Self::Io { path: e.path, error: e.error }
    }
}

/// NDC origin and direction of the world ray through continuous pixel coordinates `(px, py)`:
/// the official `convert_to_ndc` with the near plane at 1.
fn ndc_of(camera: &Camera, px: f64, py: f64, ndc: Ndc) -> (DVec3, DVec3) {
    let d = DVec3::from_array(camera.direction_f64(px, py));
    let o = DVec3::from_array(camera.origin());
    let near = 1.0;
    let t = -(near + o.z) / d.z;
    let o = o + t * d;
    let (fx, fy) =
        (2.0 * f64::from(ndc.focal) / f64::from(ndc.width), 2.0 * f64::from(ndc.focal) / f64::from(ndc.height));
    let origin = DVec3::new(-fx * (o.x / o.z), -fy * (o.y / o.z), 1.0 + 2.0 * near / o.z);
    let dir = DVec3::new(-fx * (d.x / d.z - o.x / o.z), -fy * (d.y / d.z - o.y / o.z), -2.0 * near / o.z);
    (origin, dir)
}

/// The NDC version of `world` (the ray of pixel `(x, y)`): origin and direction in NDC, the view
/// direction left as the world direction (unnormalised, as the official code does), and the
/// radius from the spacing of neighbouring NDC origins along both axes (the last row and column
/// reuse the one before the last, as in the official code), times `2/sqrt(12)`.
#[must_use]
pub fn ndc_ray(camera: &Camera, x: u32, y: u32, centers: PixelCenters, ndc: Ndc, world: Ray) -> Ray {
    let off = centers.offset();
    let at = |px: u32, py: u32| ndc_of(camera, f64::from(px) + off, f64::from(py) + off, ndc).0;
    let (o, d) = ndc_of(camera, f64::from(x) + off, f64::from(y) + off, ndc);
    let (w, h) = (camera.width, camera.height);
    let pick = |v: u32, n: u32| if v + 1 < n { v } else { n.saturating_sub(3) };
    let dy = if h > 1 { (at(x, pick(y, h)) - at(x, pick(y, h) + 1)).length() } else { 0.0 };
    let dx = if w > 1 { (at(pick(x, w), y) - at(pick(x, w) + 1, y)).length() } else { 0.0 };
    let spacing = match (h > 1, w > 1) {
        (true, true) => 0.5 * (dx + dy),
        (true, false) => dy,
        (false, _) => dx,
    };
    Ray {
        origin: o.as_vec3(),
        direction: d.as_vec3(),
        viewdir: world.direction,
        radius: radius_from_spacing(spacing),
        lossmult: 1.0,
        near: world.near,
        far: world.far,
    }
}
