//! [`Nerf`]: a model with its backend, its training data and its run state, behind the few calls an
//! app makes (train, render, save, load).

use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

use mipnerf_core::Camera;
use mipnerf_core::backend::{Backend, BackendError, ImageSpec, MAX_BATCH_RAYS, RenderedImage, TrainState};
use mipnerf_core::checkpoint::{self, CheckpointError};
use mipnerf_core::dataset::{DataError, Dataset, Split, View};
use mipnerf_core::model::{
    FastRecipe, Field, GridFit, HashGridRecipe, Levels, Model, ModelConfig, ModelError, Preset, TriMipRecipe,
};
use mipnerf_core::occupancy::{GridPlan, OccupancyGrid};
use mipnerf_core::schedule::LrSchedule;
use mipnerf_core::train::{OptimConfig, StepReport};
use mipnerf_data::LoadOptions;

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

/// The precision of the MLP's matrix products on the CPU.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[non_exhaustive]
pub enum Precision {
    /// f32, as the paper: every device.
    #[default]
    F32,
    /// bf16 products with f32 sums (`mipnerf_core::bf16`): an error ([`Error::Options`]) where
    /// the run has no kernel for them (a CPU without AMX or AVX-512 BF16, or a GPU).
    Bf16,
    /// bf16 where the CPU has a kernel for them, f32 elsewhere: what [`Preset::Fast`] asks.
    /// [`Nerf::precision`] says which runs.
    Bf16WhereAvailable,
}

/// How a [`Nerf`] is made: a preset ([`Options::preset`]; `Options::default()` is
/// [`Preset::Fast`], sized for a CPU), then `with_*` for what to change. Built only this way, so
/// that a preset's settings come together (the fast preset's occupancy grid, batch, learning
/// rates and precision with its model).
///
/// ```
/// use mipnerf::{Device, Options, Preset};
/// let options = Options::preset(Preset::Tiny).with_device(Device::Cpu).with_seed(7).with_batch_rays(256);
/// assert_eq!((options.seed(), options.batch_rays()), (7, 256));
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct Options {
    pub(crate) model: ModelConfig,
    /// Whether `model` was asked for (a preset or [`Options::with_model`]), rather than the
    /// default's: [`Nerf::load`] refuses a checkpoint of another model only then.
    pub(crate) model_chosen: bool,
    pub(crate) optim: OptimConfig,
    pub(crate) device: Device,
    pub(crate) seed: u32,
    pub(crate) batch_rays: usize,
    pub(crate) occupancy: bool,
    pub(crate) render_bounds: (f32, f32),
    pub(crate) precision: Precision,
    pub(crate) flush_subnormals: bool,
    /// Whether `model` is a grid field's recipe ([`Options::tri_mip`], [`Options::hash_grid`])
    /// to fit to the data when it is known ([`GridFit`]), as the CLI's `--field` does.
    pub(crate) grid_recipe: bool,
}

impl Default for Options {
    /// [`Preset::Fast`]'s options (a model a CPU trains in minutes), with the model not chosen:
    /// [`Nerf::load`] takes a checkpoint's model, whatever it is.
    fn default() -> Self {
        Self { model_chosen: false, ..Self::preset(Preset::Fast) }
    }
}

impl Options {
    /// A named model size with the training settings that go with it: [`Preset::Fast`] trains
    /// as the CLI's `--preset fast` does ([`FastRecipe`]: occupancy-guided sampling, its batch
    /// and learning rates, bf16 where the CPU has it); the others with the paper's optimiser,
    /// 1,024 rays a step, f32.
    #[must_use]
    pub fn preset(preset: Preset) -> Self {
        let mut options = Self {
            model: preset.config(),
            model_chosen: true,
            optim: OptimConfig::default(),
            device: Device::Auto,
            seed: 0,
            batch_rays: 1024,
            occupancy: false,
            render_bounds: (2.0, 6.0),
            precision: Precision::F32,
            flush_subnormals: preset.flushes_subnormals(),
            grid_recipe: false,
        };
        if preset == Preset::Fast {
            let recipe = FastRecipe::RECIPE;
            options.occupancy = true;
            options.batch_rays = recipe.batch_rays;
            options.optim.lr = recipe.schedule(options.optim.lr.max_steps);
            if recipe.bf16_where_available {
                options.precision = Precision::Bf16WhereAvailable;
            }
        }
        options
    }

    /// These options with the Tri-Mip field ([`Field::TriMip`]: cones read from pre-filtered
    /// feature planes, then a small MLP) in place of the Mip-NeRF MLP, with the field's recipe
    /// ([`TriMipRecipe`]: its planes, its MLP, the planes' own Adam settings) as the CLI's
    /// `--field tri-mip` takes it, fitted to the data when a [`Nerf`] is made for it
    /// ([`GridFit`]: for forward-facing photos the planes' total variation at 0.1; for an
    /// unbounded scene coarser planes held smoother). `half_side`: half the side of the cube
    /// around the origin the planes cover (the scene's, in world units). The field's small MLP
    /// computes in f32.
    #[must_use]
    pub fn tri_mip(mut self, half_side: f32) -> Self {
        let recipe = TriMipRecipe::RECIPE;
        self.model = TriMipRecipe::with_mlp(self.model, recipe.mlp);
        self.model.field =
            Field::TriMip { planes: TriMipRecipe::planes(recipe.resolution), half_side, pre_filtered: true };
        self.model.planes_tv_mult = recipe.planes_tv;
        self.model.grid_decay_mult = 0.0;
        self.model_chosen = true;
        self.grid_recipe = true;
        self.optim.field = Some(recipe.adam);
        self.precision = Precision::F32;
        self
    }

    /// These options with the hash-grid field ([`Field::HashGrid`]: Zip-NeRF's hash grid, each
    /// level down-weighted at the cone's footprint, then a small MLP) in place of the Mip-NeRF
    /// MLP, with the field's recipe ([`HashGridRecipe`]: its grid, its MLP, the grid's own Adam
    /// settings, its weight decay) as the CLI's `--field hash-grid` takes it, fitted to the data
    /// when a [`Nerf`] is made for it ([`GridFit`]: for forward-facing photos the grid's weight
    /// decay at 0.01 and the learning rate's decay ended at 10,000 steps), over the cube of half
    /// side `half_side` around the origin. CPU only (a GPU device refuses it by name); f32.
    #[must_use]
    pub fn hash_grid(mut self, half_side: f32) -> Self {
        let recipe = HashGridRecipe::RECIPE;
        self.model = TriMipRecipe::with_mlp(self.model, recipe.mlp);
        self.model.field = Field::HashGrid { grid: recipe.grid, half_side };
        self.model.planes_tv_mult = 0.0;
        self.model.grid_decay_mult = recipe.decay;
        self.model_chosen = true;
        self.grid_recipe = true;
        self.optim.field = Some(recipe.adam);
        self.precision = Precision::F32;
        self
    }

    /// Any model in place of the preset's (its other settings kept). Some settings follow the
    /// data as the CLI's do ([`mipnerf_core::config::DataFit`]): `white_bkgd` (composited as the
    /// data is); for forward-facing data in NDC (LLFF, COLMAP) `ray_shape`, cylinders, and
    /// `density_noise` 1 where it is 0, as the official LLFF configuration; for masked photos
    /// `random_bkgd`. A grid field's recipe ([`Options::tri_mip`]) is no longer fitted to the
    /// data: the model is as given.
    #[must_use]
    pub fn with_model(mut self, model: ModelConfig) -> Self {
        self.model = model;
        self.model_chosen = true;
        self.grid_recipe = false;
        self
    }

    /// The learning-rate schedule, Adam and gradient clipping.
    #[must_use]
    pub fn with_optim(mut self, optim: OptimConfig) -> Self {
        self.optim = optim;
        self
    }

    /// Where to run.
    #[must_use]
    pub fn with_device(mut self, device: Device) -> Self {
        self.device = device;
        self
    }

    /// The seed of the initial parameters and of every random draw of training.
    #[must_use]
    pub fn with_seed(mut self, seed: u32) -> Self {
        self.seed = seed;
        self
    }

    /// Rays (pixels) per training step, 1 to [`MAX_BATCH_RAYS`].
    #[must_use]
    pub fn with_batch_rays(mut self, rays: usize) -> Self {
        self.batch_rays = rays;
        self
    }

    /// Occupancy-guided sampling (what the fast preset is meant for): a 64³ grid around the
    /// scene, seeded with the visual hull of the images' alpha, then kept up to date from the
    /// model's density, so samples go where the scene is. Bounded and forward-facing scenes.
    #[must_use]
    pub fn with_occupancy(mut self, on: bool) -> Self {
        self.occupancy = on;
        self
    }

    /// Near and far bounds of renders when the `Nerf` holds no data (loaded for rendering from a
    /// checkpoint that does not say them).
    #[must_use]
    pub fn with_render_bounds(mut self, near: f32, far: f32) -> Self {
        self.render_bounds = (near, far);
        self
    }

    /// The precision of the MLP's products on the CPU.
    #[must_use]
    pub fn with_precision(mut self, precision: Precision) -> Self {
        self.precision = precision;
        self
    }

    /// Training steps on the CPU flush subnormal floats to zero (`mipnerf_core::subnormals`):
    /// faster where gradients in empty space go subnormal, not bit-identical to a run that keeps
    /// them. The presets that do set it ([`Preset::flushes_subnormals`]).
    #[must_use]
    pub fn with_flush_subnormals(mut self, flush: bool) -> Self {
        self.flush_subnormals = flush;
        self
    }

    /// The model.
    #[must_use]
    pub fn model(&self) -> &ModelConfig {
        &self.model
    }

    /// The learning-rate schedule, Adam and gradient clipping.
    #[must_use]
    pub fn optim(&self) -> &OptimConfig {
        &self.optim
    }

    /// Where to run.
    #[must_use]
    pub fn device(&self) -> Device {
        self.device
    }

    /// The seed.
    #[must_use]
    pub fn seed(&self) -> u32 {
        self.seed
    }

    /// Rays per training step.
    #[must_use]
    pub fn batch_rays(&self) -> usize {
        self.batch_rays
    }

    /// Whether sampling is occupancy-guided.
    #[must_use]
    pub fn occupancy(&self) -> bool {
        self.occupancy
    }

    /// Near and far bounds of renders without data.
    #[must_use]
    pub fn render_bounds(&self) -> (f32, f32) {
        self.render_bounds
    }

    /// The precision of the MLP's products on the CPU.
    #[must_use]
    pub fn precision(&self) -> Precision {
        self.precision
    }

    /// Whether CPU training steps flush subnormals.
    #[must_use]
    pub fn flush_subnormals(&self) -> bool {
        self.flush_subnormals
    }

    /// Refuses values no run can use, naming the option.
    fn check(&self) -> Result<(), Error> {
        if !(1..=MAX_BATCH_RAYS).contains(&self.batch_rays) {
            return Err(Error::Options(format!(
                "`Options::with_batch_rays` takes 1 to {MAX_BATCH_RAYS} rays, got {}",
                self.batch_rays
            )));
        }
        let (near, far) = self.render_bounds;
        if !(near.is_finite() && far.is_finite() && 0.0 <= near && near < far) {
            return Err(Error::Options(format!(
                "`Options::with_render_bounds` takes finite bounds with 0 <= near < far, got ({near}, {far})"
            )));
        }
        Ok(())
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
/// assert_eq!(nerf.render(&camera)?.to_rgb_image()?.dimensions(), (32, 24));
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
    /// The precision the MLP's products run in.
    precision: Precision,
    /// The options' learning-rate schedule, which [`Nerf::train_for`] stretches to its budget.
    schedule: LrSchedule,
}

/// How a camera's pixels become rays: bounds, pixel centres, the NDC mapping.
#[derive(Clone, Copy, Debug, PartialEq)]
struct RaySettings {
    near: f32,
    far: f32,
    centers: mipnerf_core::PixelCenters,
    ndc: Option<mipnerf_core::dataset::Ndc>,
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
        let options = fitted_to(&options, &data);
        let model = Model::new(options.model.clone())?;
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
    /// Blender, LLFF or COLMAP; see `mipnerf_data::load`).
    ///
    /// # Errors
    /// A folder that is no dataset or a malformed one (the error names the file), or as
    /// [`Nerf::new`].
    pub fn from_dir(dir: impl AsRef<Path>, options: Options) -> Result<Self, Error> {
        Self::new(mipnerf_data::load(dir.as_ref(), Split::Train, &LoadOptions::default())?, options)
    }

    /// The model saved at `path` by [`Nerf::save`], to render or to train further on `data`. The
    /// checkpoint holds the model's configuration and how its pixels become rays (bounds, pixel
    /// centres, the NDC mapping of forward-facing data), so a model loaded without data renders
    /// as it did. `Options::default()` takes the checkpoint's model, whatever it is; options
    /// whose model was chosen (a preset, [`Options::with_model`]) must match it. The options'
    /// model and render bounds serve for a checkpoint saved without them (by the CLI, whose run
    /// folder keeps them in `config.toml`).
    ///
    /// # Errors
    /// A missing, damaged or foreign checkpoint (its checksum is verified), [`Error::Options`]
    /// for a chosen model that is not the checkpoint's (both named), or as [`Nerf::new`].
    pub fn load(path: impl AsRef<Path>, options: Options, data: Option<Dataset>) -> Result<Self, Error> {
        let data = data.map(Arc::new);
        let stored = checkpoint::render_settings(path.as_ref())?;
        let mut options = options;
        if let Some(r) = &stored {
            if options.model_chosen && !same_model(&options.model, &r.model) {
                return Err(Error::Options(format!(
                    "{}: the checkpoint holds {}, not {} as `Options` asks; load it with \
                     `Options::default()` (which takes the checkpoint's model) or the options it was trained with",
                    path.as_ref().display(),
                    describe_model(&r.model),
                    describe_model(&options.model)
                )));
            }
            options.model = r.model.clone();
        }
        let mut config = options.model.clone();
        if let Some(ds) = data.as_deref() {
            // A trained model: what the data is changes its rays, not how it was trained.
            ds.model_fit().apply_to_rays(&mut config);
        }
        let model = Model::new(config)?;
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
        let bf16 = mipnerf_core::bf16::Precision::Bf16;
        let precision = match options.precision {
            Precision::F32 => Precision::F32,
            Precision::Bf16 => {
                backend
                    .set_precision(bf16)
                    .map_err(|e| Error::Options(format!("`Precision::Bf16` on {}: {e}", backend.describe())))?;
                Precision::Bf16
            }
            // f32 where bf16 has no kernel (a CPU without one, a GPU), as the option says.
            Precision::Bf16WhereAvailable => match backend.set_precision(bf16) {
                Ok(()) => Precision::Bf16,
                Err(_) => Precision::F32,
            },
        };
        backend.set_flush_subnormals(options.flush_subnormals);
        if data.is_some() {
            let need = backend.host_training_bytes(options.batch_rays);
            let what = format!("a training step of {} rays (`Options::with_batch_rays`)", options.batch_rays);
            mipnerf_core::memory::check(need, &what).map_err(Error::Options)?;
        }
        let (near, far) = options.render_bounds;
        let rays = RaySettings { near, far, centers: mipnerf_core::PixelCenters::Centered, ndc: None };
        Ok(Self { backend, data, fallback, rays, precision, schedule: options.optim.lr })
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

    /// Trains for `budget` of wall-clock time (at least one step) and reports the last step. The
    /// learning rate's decay is stretched over the steps the budget allows at the speed measured
    /// so far, so that it reaches the schedule's final rate as the budget runs out, as
    /// `mipnerf train --time-budget` does (`LrSchedule::stretched_to_budget`); each call is a
    /// budget of its own. [`Nerf::train`] follows the options' schedule by step.
    ///
    /// # Errors
    /// As [`Nerf::train`].
    pub fn train_for(&mut self, budget: Duration) -> Result<StepReport, Error> {
        if self.data.is_none() {
            return Err(Error::NoData);
        }
        let start = Instant::now();
        let budget = budget.as_secs_f64();
        let mut steps = 0u64;
        loop {
            let elapsed = start.elapsed().as_secs_f64();
            let per_step = (steps > 0).then(|| elapsed / steps as f64);
            let step = self.step();
            self.backend.set_lr_schedule(self.schedule.stretched_to_budget(step, budget - elapsed, per_step));
            let report = self.train(1)?;
            steps += 1;
            if start.elapsed().as_secs_f64() >= budget {
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

    /// The precision the MLP's products run in: [`Precision::Bf16WhereAvailable`] resolved to
    /// [`Precision::Bf16`] or [`Precision::F32`].
    #[must_use]
    pub fn precision(&self) -> Precision {
        self.precision
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

/// Whether two model configurations are the same model, the settings that follow the data
/// ([`mipnerf_core::config::DataFit`]: `white_bkgd`, `ray_shape`, `density_noise`, `random_bkgd`)
/// aside.
fn same_model(a: &ModelConfig, b: &ModelConfig) -> bool {
    let fitted = ModelConfig {
        white_bkgd: a.white_bkgd,
        ray_shape: a.ray_shape,
        density_noise: a.density_noise,
        random_bkgd: a.random_bkgd,
        ..b.clone()
    };
    *a == fitted
}

/// A model in a few words, for errors: its field, its MLP's trunk and its samples.
fn describe_model(c: &ModelConfig) -> String {
    let field = match c.field {
        Field::TriMip { planes, pre_filtered: true, .. } => {
            format!("the Tri-Mip field ({}² planes)", planes.resolution)
        }
        Field::TriMip { planes, pre_filtered: false, .. } => {
            format!("the tri-plane field ({}² planes)", planes.resolution)
        }
        Field::HashGrid { grid, .. } => {
            format!("the hash grid ({} levels to {} cells a side)", grid.levels, grid.finest)
        }
        Field::MipNerf => "the Mip-NeRF MLP".to_owned(),
    };
    format!(
        "{field} with a {}x{} trunk and {} samples on {} levels",
        c.net_depth, c.net_width, c.num_samples, c.num_levels
    )
}

/// `options` fitted to the data as the CLI fits its settings ([`Dataset::model_fit`]), and a
/// grid field's recipe to it ([`GridFit`]): the planes' resolution and total variation, the hash
/// grid's weight decay and, where the options leave them open, the steps its rate decays over
/// and the steps its density noise fades over.
fn fitted_to(options: &Options, data: &Dataset) -> Options {
    let mut options = options.clone();
    let fit = data.model_fit();
    fit.apply(&mut options.model);
    if options.grid_recipe {
        let m = &mut options.model;
        let recipe = GridFit::of(fit, m.unbounded);
        match &mut m.field {
            Field::TriMip { planes, .. } => {
                *planes = TriMipRecipe::planes(recipe.planes_resolution);
                m.planes_tv_mult = recipe.planes_tv;
            }
            Field::HashGrid { .. } => {
                m.grid_decay_mult = recipe.hash_grid_decay;
                if m.density_noise > 0.0 && m.density_noise_steps == 0 {
                    m.density_noise_steps = recipe.hash_grid_density_noise_steps.unwrap_or(0);
                }
                let lr = &mut options.optim.lr;
                lr.decay_steps = lr.decay_steps.or(recipe.hash_grid_lr_decay_steps);
            }
            Field::MipNerf => {}
        }
    }
    options
}

/// The fast recipe's occupancy grid around the scene of `data` as the CLI lays it
/// ([`OccupancyGrid::for_data`]): carved by its images' alpha; for forward-facing data, over the
/// NDC cube, carved where no training ray reaches.
fn occupancy_grid(data: &Dataset) -> Result<OccupancyGrid, Error> {
    let resolution = FastRecipe::RECIPE.occupancy_resolution;
    let plan = GridPlan { resolution, bound: None, unbounded: false, carve_masks: true };
    let (grid, _) = OccupancyGrid::for_data(data, plan).map_err(|e| Error::Occupancy(e.to_string()))?;
    Ok(grid)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The hash grid's rate on forward-facing photos decays over the recipe's 10,000 steps, as
    /// the CLI's; a schedule that says where its decay ends keeps it.
    #[test]
    fn the_hash_grids_rate_on_forward_facing_photos_ends_its_decay_where_the_clis_does() {
        let colmap = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/colmap_lego");
        let data = mipnerf_data::load(&colmap, Split::Train, &LoadOptions::default()).unwrap();
        let options = Options::preset(Preset::Tiny).hash_grid(1.5);
        let steps = HashGridRecipe::RECIPE.lr_decay_steps_forward_facing;
        assert_eq!(fitted_to(&options, &data).optim.lr.decay_steps, Some(steps));
        // The density noise of forward-facing photos fades with it, as the CLI's.
        let fitted = fitted_to(&options, &data);
        let fade = HashGridRecipe::RECIPE.density_noise_steps_forward_facing;
        assert_eq!((fitted.model.density_noise, fitted.model.density_noise_steps), (1.0, fade));
        let mut own = options.optim().clone();
        own.lr.decay_steps = Some(500);
        assert_eq!(fitted_to(&options.with_optim(own), &data).optim.lr.decay_steps, Some(500));
        let blender = mipnerf_data::load(
            &Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/lego_tiny"),
            Split::Train,
            &LoadOptions::default(),
        )
        .unwrap();
        let fitted = fitted_to(&Options::preset(Preset::Tiny).hash_grid(1.5), &blender);
        assert_eq!((fitted.optim.lr.decay_steps, fitted.model.density_noise_steps), (None, 0));
    }
}
