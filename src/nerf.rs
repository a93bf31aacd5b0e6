//! [`Nerf`]: a model with its backend, its training data and its run state, behind the few calls an
//! app makes (train, render, save, load).

use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

use mipnerf_core::Camera;
use mipnerf_core::backend::{Backend, BackendError, ImageSpec, MAX_BATCH_RAYS, RenderedImage, TrainState};
use mipnerf_core::checkpoint::{self, CheckpointError};
use mipnerf_core::data::{self, DataError, Dataset, LoadOptions, Split, View};
use mipnerf_core::model::{FastRecipe, Field, Levels, Model, ModelConfig, ModelError, Preset, TriMipRecipe};
use mipnerf_core::occupancy::{OccupancyConfig, OccupancyGrid};
use mipnerf_core::train::{OptimConfig, StepReport};

/// Where a [`Nerf`] runs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Device {
    /// The CPU (every core).
    Cpu,
    /// Any GPU adapter, software ones (lavapipe) included; an error without the `gpu` feature.
    Gpu,
    /// A hardware GPU when there is one and it runs the configuration, else the CPU
    /// ([`Nerf::fallback`] says why).
    #[default]
    Auto,
}

/// How a [`Nerf`] is made. `Options::default()` is the paper's model on the best device; start
/// from [`Options::preset`] for a smaller one.
#[derive(Clone, Debug, PartialEq)]
pub struct Options {
    /// The model. Two settings follow the data: `white_bkgd` (composited as the data is), and
    /// for forward-facing data in NDC (LLFF, COLMAP) `ray_shape`, cylinders as the official LLFF
    /// configuration.
    pub model: ModelConfig,
    /// Learning-rate schedule, Adam and gradient clipping.
    pub optim: OptimConfig,
    /// Where to run.
    pub device: Device,
    /// The seed of the initial parameters and of every random draw of training.
    pub seed: u32,
    /// Rays (pixels) per training step.
    pub batch_rays: usize,
    /// Occupancy-guided sampling (what the `fast` preset is meant for): a 64³ grid around the
    /// scene, seeded with the visual hull of the images' alpha, then kept up to date from the
    /// model's density, so samples go where the scene is. Bounded scenes only.
    pub occupancy: bool,
    /// Near and far bounds of renders when the `Nerf` holds no data (loaded for rendering).
    pub render_bounds: (f32, f32),
    /// The MLP's products in bf16 on the CPU where it has a kernel for them (AMX or AVX-512
    /// BF16; see `mipnerf_core::bf16`), f32 elsewhere and on a GPU. [`Preset::Fast`] sets it.
    pub bf16: bool,
    /// Training steps on the CPU flush subnormal floats to zero (`mipnerf_core::subnormals`):
    /// faster where gradients in empty space go subnormal, not bit-identical to a run that keeps
    /// them. [`Options::preset`] sets it for the presets that do ([`Preset::flushes_subnormals`]).
    pub flush_subnormals: bool,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            model: ModelConfig::default(),
            optim: OptimConfig::default(),
            device: Device::Auto,
            seed: 0,
            batch_rays: 1024,
            occupancy: false,
            render_bounds: (2.0, 6.0),
            bf16: false,
            flush_subnormals: false,
        }
    }
}

impl Options {
    /// Refuses values no run can use, naming the option.
    fn check(&self) -> Result<(), Error> {
        if !(1..=MAX_BATCH_RAYS).contains(&self.batch_rays) {
            return Err(Error::Options(format!(
                "`Options::batch_rays` must be between 1 and {MAX_BATCH_RAYS}, got {}",
                self.batch_rays
            )));
        }
        let (near, far) = self.render_bounds;
        if !(near.is_finite() && far.is_finite() && 0.0 <= near && near < far) {
            return Err(Error::Options(format!(
                "`Options::render_bounds` must be finite with 0 <= near < far, got ({near}, {far})"
            )));
        }
        Ok(())
    }

    /// A named model size with the other defaults; [`Preset::Fast`] trains as the CLI's
    /// `--preset fast` does ([`FastRecipe`]: occupancy-guided sampling, its batch and learning
    /// rates, bf16 where the CPU has it).
    #[must_use]
    pub fn preset(preset: Preset) -> Self {
        let mut options =
            Self { model: preset.config(), flush_subnormals: preset.flushes_subnormals(), ..Self::default() };
        if preset == Preset::Fast {
            let recipe = FastRecipe::RECIPE;
            options.occupancy = true;
            options.batch_rays = recipe.batch_rays;
            options.optim.lr = recipe.schedule(options.optim.lr.max_steps);
            options.bf16 = recipe.bf16_where_available;
        }
        options
    }

    /// These options with the Tri-Mip field ([`Field::TriMip`]: cones read from pre-filtered
    /// feature planes, then a small MLP) in place of the Mip-NeRF MLP, with the field's recipe
    /// ([`TriMipRecipe`]: its planes, its MLP, the planes' own Adam settings) as the CLI's
    /// `--field tri-mip` takes it. `half_side`: half the side of the cube around the origin the
    /// planes cover (the scene's, in world units). The field's small MLP computes in f32.
    #[must_use]
    pub fn tri_mip(mut self, half_side: f32) -> Self {
        let recipe = TriMipRecipe::RECIPE;
        self.model = TriMipRecipe::with_mlp(self.model, recipe.mlp);
        self.model.field =
            Field::TriMip { planes: TriMipRecipe::planes(recipe.resolution), half_side, pre_filtered: true };
        self.model.planes_tv_mult = recipe.planes_tv;
        self.optim.field = Some(recipe.adam);
        self.bf16 = false;
        self
    }
}

/// What went wrong, in library terms.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The model configuration is invalid.
    #[error(transparent)]
    Model(#[from] ModelError),
    /// The data could not be loaded or is unusable.
    #[error(transparent)]
    Data(#[from] DataError),
    /// The backend refused or failed.
    #[error(transparent)]
    Backend(#[from] BackendError),
    /// A checkpoint could not be written or read.
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    /// The GPU backend could not be opened.
    #[cfg(feature = "gpu")]
    #[error(transparent)]
    Open(#[from] mipnerf_gpu::OpenError),
    /// `Device::Gpu` asked of a build without the `gpu` feature.
    #[error("this build of mipnerf has no GPU backend (its `gpu` feature is off): use `Device::Cpu` or `Device::Auto`")]
    NoGpuBackend,
    /// Occupancy-guided sampling asked of data it cannot guide.
    #[error("occupancy-guided sampling: {0}")]
    Occupancy(String),
    /// An option is out of range, or a training step would not fit in memory.
    #[error("{0}")]
    Options(String),
    /// The `Nerf` holds no training data (it was loaded for rendering).
    #[error("this Nerf holds no training data: make it with `Nerf::new`, `from_views` or `from_dir` to train")]
    NoData,
}

/// A Mip-NeRF with its backend: train it on posed images, render any camera, save and load it.
///
/// ```
/// use mipnerf::{Camera, Nerf, Options, Preset, demo};
///
/// # fn main() -> Result<(), Box<dyn std::error::Error>> {
/// let mut nerf = Nerf::new(demo::dataset(4, 16)?, Options::preset(Preset::Tiny))?;
/// let report = nerf.train(3)?;
/// assert!(report.stats.loss.is_finite());
/// let camera = Camera::from_camera_angle_x(32, 24, 0.69, demo::camera_pose(1.0, 0.4))?;
/// assert_eq!(nerf.render(&camera)?.to_rgb_image().dimensions(), (32, 24));
/// # Ok(())
/// # }
/// ```
pub struct Nerf {
    backend: Box<dyn Backend>,
    data: Option<Arc<Dataset>>,
    fallback: Option<String>,
    /// How pixels become rays without data: from the checkpoint it was loaded from, else
    /// `Options::render_bounds` through pixel centres.
    rays: RaySettings,
}

/// How a camera's pixels become rays: bounds, pixel centres, the NDC mapping.
#[derive(Clone, Copy, Debug, PartialEq)]
struct RaySettings {
    near: f32,
    far: f32,
    centers: mipnerf_core::PixelCenters,
    ndc: Option<mipnerf_core::data::Ndc>,
}

impl std::fmt::Debug for Nerf {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Nerf").field("backend", &self.backend.describe()).field("step", &self.step()).finish()
    }
}

impl Nerf {
    /// A fresh model to train on `data` (its training views).
    ///
    /// # Errors
    /// An invalid model, occupancy on data it cannot guide, or a device that cannot be opened.
    pub fn new(data: Dataset, options: Options) -> Result<Self, Error> {
        let data = Arc::new(data);
        let model = model_for(&options, Some(&data))?;
        let mut state = TrainState::fresh(&model, options.seed);
        if options.occupancy {
            state.occupancy = Some(occupancy_grid(&data)?);
        }
        Self::open(model, state, Some(data), &options)
    }

    /// A fresh model to train on images held in memory (straight RGBA, camera-to-world poses in
    /// OpenGL axes), composited on white.
    ///
    /// # Errors
    /// No views, or as [`Nerf::new`].
    pub fn from_views(views: Vec<View>, options: Options) -> Result<Self, Error> {
        Self::new(Dataset::from_views(Split::Train, views, true)?, options)
    }

    /// A fresh model to train on the training split of a dataset folder (Blender, multiscale
    /// Blender, LLFF or COLMAP; see `mipnerf_core::data::load`).
    ///
    /// # Errors
    /// A folder that is no dataset or a malformed one (the error names the file), or as
    /// [`Nerf::new`].
    pub fn from_dir(dir: impl AsRef<Path>, options: Options) -> Result<Self, Error> {
        Self::new(data::load(dir.as_ref(), Split::Train, &LoadOptions::default())?, options)
    }

    /// The model saved at `path` by [`Nerf::save`], to render or to train further on `data`. The
    /// checkpoint holds the model's configuration and how its pixels become rays (bounds, pixel
    /// centres, the NDC mapping of forward-facing data), so a model loaded without data renders
    /// as it did; `options.model` and `options.render_bounds` serve only for a checkpoint saved
    /// without them (by the CLI, whose run folder keeps them in `config.toml`).
    ///
    /// # Errors
    /// A missing, damaged or foreign checkpoint (its checksum is verified), or as [`Nerf::new`].
    pub fn load(path: impl AsRef<Path>, options: Options, data: Option<Dataset>) -> Result<Self, Error> {
        let data = data.map(Arc::new);
        let stored = checkpoint::render_settings(path.as_ref())?;
        let mut options = options;
        if let Some(r) = &stored {
            options.model = r.model.clone();
        }
        let model = model_for(&options, data.as_deref())?;
        let state = TrainState::from_checkpoint(checkpoint::load(path.as_ref(), &model)?);
        let mut nerf = Self::open(model, state, data, &options)?;
        if let Some(r) = stored {
            nerf.rays = RaySettings { near: r.near, far: r.far, centers: r.centers, ndc: r.ndc };
        }
        Ok(nerf)
    }

    fn open(model: Model, state: TrainState, data: Option<Arc<Dataset>>, options: &Options) -> Result<Self, Error> {
        options.check()?;
        let batch = data.as_ref().map(|d| (Arc::clone(d), options.batch_rays));
        let (mut backend, fallback) = crate::open_backend(options, model, state, batch)?;
        if options.bf16 && mipnerf_core::bf16::Bf16Support::detect().available() {
            // A device backend runs f32 only and says so: it keeps f32, as the option promises.
            let _ = backend.set_precision(mipnerf_core::bf16::Precision::Bf16);
        }
        backend.set_flush_subnormals(options.flush_subnormals);
        if data.is_some() {
            let need = backend.host_training_bytes(options.batch_rays);
            let what = format!("a training step of {} rays (`Options::batch_rays`)", options.batch_rays);
            mipnerf_core::memory::check(need, &what).map_err(Error::Options)?;
        }
        let (near, far) = options.render_bounds;
        let rays = RaySettings { near, far, centers: mipnerf_core::PixelCenters::Centered, ndc: None };
        Ok(Self { backend, data, fallback, rays })
    }

    /// Takes `steps` training steps and reports the last.
    ///
    /// # Errors
    /// [`Error::Options`] for `steps` of 0 (there would be no step to report), [`Error::NoData`],
    /// or the backend's error (the state before the failing step is kept).
    pub fn train(&mut self, steps: u64) -> Result<StepReport, Error> {
        if steps == 0 {
            return Err(Error::Options("`Nerf::train(0)`: no step to take or report; ask for at least 1".into()));
        }
        if self.data.is_none() {
            return Err(Error::NoData);
        }
        for _ in 1..steps {
            self.backend.train_step(false)?;
        }
        Ok(self.backend.train_step(true)?.expect("a backend reports when asked"))
    }

    /// Trains for `budget` of wall-clock time (at least one step) and reports the last step.
    ///
    /// # Errors
    /// As [`Nerf::train`].
    pub fn train_for(&mut self, budget: Duration) -> Result<StepReport, Error> {
        let start = Instant::now();
        loop {
            let report = self.train(1)?;
            if start.elapsed() >= budget {
                return Ok(report);
            }
        }
    }

    /// Renders `camera` (`.fine` is the picture; the coarse level is not kept), as the training
    /// data's rays are made (bounds, pixel centres, NDC), or without data as the loaded
    /// checkpoint says (`Options::render_bounds` for one that says nothing).
    ///
    /// # Errors
    /// The backend's error.
    pub fn render(&mut self, camera: &Camera) -> Result<RenderedImage, Error> {
        let spec = self.image_spec(camera);
        Ok(self.backend.render(&spec, Levels::Last)?)
    }

    /// How pixels become rays here: as the training data's are, or as loaded.
    fn ray_settings(&self) -> RaySettings {
        match &self.data {
            Some(ds) => {
                let view = &ds.views()[0];
                RaySettings { near: view.near, far: view.far, centers: ds.centers, ndc: ds.ndc }
            }
            None => self.rays,
        }
    }

    /// How `camera`'s pixels become rays here.
    fn image_spec(&self, camera: &Camera) -> ImageSpec {
        let RaySettings { near, far, centers, ndc } = self.ray_settings();
        let supersample = self.backend.model().config().supersample;
        ImageSpec { camera: camera.clone(), near, far, centers, ndc, supersample }
    }

    /// Saves the parameters, Adam's state, the step and the occupancy grid to `path` (one
    /// safetensors file, written atomically: a failed write keeps the previous file), with the
    /// model's configuration and how its pixels become rays, so that [`Nerf::load`] without data
    /// renders as this does.
    ///
    /// # Errors
    /// The file system, or a non-finite state (nothing is written then).
    pub fn save(&mut self, path: impl AsRef<Path>) -> Result<(), Error> {
        let ck = self.backend.checkpoint()?;
        let RaySettings { near, far, centers, ndc } = self.ray_settings();
        let render =
            checkpoint::RenderSettings { model: self.backend.model().config().clone(), near, far, centers, ndc };
        checkpoint::save_for_rendering(path.as_ref(), self.backend.model(), &ck, &render)?;
        Ok(())
    }

    /// Training steps taken.
    #[must_use]
    pub fn step(&self) -> u64 {
        self.backend.step()
    }

    /// Where it runs, in words (the adapter's name on a GPU).
    #[must_use]
    pub fn device(&self) -> String {
        self.backend.describe()
    }

    /// Why `Device::Auto` runs on the CPU, when it does.
    #[must_use]
    pub fn fallback(&self) -> Option<&str> {
        self.fallback.as_deref()
    }

    /// The backend itself, for what this type does not wrap (learning-rate changes, precision,
    /// work counters).
    pub fn backend(&mut self) -> &mut dyn Backend {
        self.backend.as_mut()
    }
}

/// The model of `options`, composited as the data is, with cylinders for NDC data.
fn model_for(options: &Options, data: Option<&Dataset>) -> Result<Model, Error> {
    let mut config = options.model.clone();
    if let Some(ds) = data {
        config.white_bkgd = ds.white_bkgd;
        if ds.ndc.is_some() {
            config.ray_shape = mipnerf_core::RayShape::Cylinder;
        }
    }
    Ok(Model::new(config)?)
}

/// A 64³ occupancy grid around the scene of `data`, carved by its images' alpha; for
/// forward-facing data, over the NDC cube, carved where no training ray reaches.
fn occupancy_grid(data: &Dataset) -> Result<OccupancyGrid, Error> {
    let bound = mipnerf_core::occupancy::auto_bound(data)
        .ok_or_else(|| Error::Occupancy("a camera's near bound reaches the origin: no cube fits the scene".into()))?;
    let resolution = FastRecipe::RECIPE.occupancy_resolution;
    let mut grid = OccupancyGrid::new(OccupancyConfig { resolution, bound, ..OccupancyConfig::default() })
        .map_err(|e| Error::Occupancy(e.to_string()))?;
    grid.carve_with_masks(data);
    if data.ndc.is_some() {
        grid.carve_unreached(data);
    }
    Ok(grid)
}
