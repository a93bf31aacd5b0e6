//! One interface for training and rendering, whatever runs them: [`Backend`], implemented here on
//! the CPU ([`CpuBackend`]) and in `mipnerf-gpu` on any wgpu device (`GpuBackend`).
//!
//! A backend owns a model's parameters and Adam state and, for training, the training images: it
//! draws its own batches (a pure function of the run's seed and the step), so two backends started
//! from the same seed train on the same pixels and follow the same loss curve up to rounding.

use std::sync::Arc;

use crate::bf16::Precision;
use crate::camera::{Camera, PixelCenters};
use crate::checkpoint::Checkpoint;
use crate::cone::Ray;
use crate::dataset::{BatchDraw, Dataset, Ndc, RaySpec, push_camera_rays};
use crate::model::{LevelOutput, Levels, Model};
use crate::occupancy::OccupancyGrid;
use crate::schedule::LrSchedule;
use crate::train::{AdamState, OptimConfig, StepReport, Trainer};

/// The most rays a training batch may hold: 1,024 times the paper's 4,096, and far below where a
/// ray index or a buffer offset (`u32` on the GPU) would overflow.
pub const MAX_BATCH_RAYS: usize = 1 << 22;

/// Why a backend could not do what was asked.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum BackendError {
    /// The backend does not implement this configuration.
    #[error(transparent)]
    Unsupported(#[from] Unsupported),
    /// Training was asked of a backend made without training data.
    #[error("this backend holds no training data (it was made for rendering only)")]
    NoData,
    /// The inputs disagree with the model (sizes, parameter counts).
    #[error("{0}")]
    Invalid(String),
    /// The device ran out of memory (the device's own error, shown as is).
    #[error(transparent)]
    OutOfMemory(Box<dyn std::error::Error + Send + Sync>),
    /// The device was lost: driver reset, device removed (the device's own error, shown as is).
    #[error(transparent)]
    DeviceLost(Box<dyn std::error::Error + Send + Sync>),
    /// Any other failure of the device (a rejected command, a failed wait or readback), with the
    /// device's own error as the source.
    #[error(transparent)]
    Device(Box<dyn std::error::Error + Send + Sync>),
}

/// A configuration a backend does not run, named.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum Unsupported {
    /// Supersampling of forward-facing (NDC) data.
    #[error("{NDC_SUPERSAMPLE}")]
    NdcSupersample,
    /// bf16 matrix products, which only the CPU backend runs.
    #[error("bf16 precision runs on the CPU backend only; this backend computes in f32")]
    Bf16,
}

/// A full image to render: its camera and how its pixels become rays.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageSpec {
    /// The camera (its size is the image's).
    pub camera: Camera,
    /// Near bound along every ray.
    pub near: f32,
    /// Far bound along every ray.
    pub far: f32,
    /// Rays through pixel centres or corners.
    pub centers: PixelCenters,
    /// NDC mapping for forward-facing scenes.
    pub ndc: Option<Ndc>,
    /// Rays per pixel side (`supersample²` rays per pixel, averaged); 1 for Mip-NeRF.
    pub supersample: usize,
}

impl ImageSpec {
    /// View `v` of `ds`, at its own resolution, with `supersample²` rays per pixel.
    ///
    /// # Panics
    /// If `v` is out of range.
    #[must_use]
    pub fn of_view(ds: &Dataset, v: usize, supersample: usize) -> Self {
        let view = &ds.views()[v];
        Self {
            camera: view.camera.clone(),
            near: view.near,
            far: view.far,
            centers: ds.centers,
            ndc: ds.ndc,
            supersample: supersample.max(1),
        }
    }

    /// Pixels in the image.
    #[must_use]
    pub fn pixels(&self) -> usize {
        self.camera.width as usize * self.camera.height as usize
    }

    /// Whether `model` renders this image: the same rays per pixel as the model's, and no
    /// supersampling of forward-facing (NDC) rays.
    ///
    /// # Errors
    /// [`BackendError::Invalid`] or [`BackendError::Unsupported`] saying which.
    pub fn check_for(&self, model: &Model) -> Result<(), BackendError> {
        let k = model.config().supersample;
        if self.supersample != k {
            return Err(BackendError::Invalid(format!(
                "the image asks for {0}x{0} rays per pixel; the model renders {k}x{k}",
                self.supersample
            )));
        }
        check_ndc_supersample(self.ndc, k)
    }

    /// Appends the rays of pixels `first..first + count` (raster order), `supersample²` per pixel.
    pub fn push_rays(&self, first: usize, count: usize, out: &mut Vec<Ray>) {
        let w = self.camera.width as usize;
        for i in first..(first + count).min(self.pixels()) {
            let (x, y) = ((i % w) as u32, (i / w) as u32);
            let spec = RaySpec { centers: self.centers, bounds: (self.near, self.far), lossmult: 1.0, ndc: self.ndc };
            push_camera_rays(&self.camera, x, y, spec, self.supersample, out);
        }
    }
}

/// One rendered image: per pixel (raster order) the fine level's colour, distance and opacity,
/// and the coarse level's where the render asked for every level ([`Levels::All`]).
#[derive(Clone, Debug, PartialEq)]
pub struct RenderedImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// The last (fine) level, the model's output.
    pub fine: Vec<LevelOutput>,
    /// The first (coarse) level; `None` when rendered with [`Levels::Last`].
    pub coarse: Option<Vec<LevelOutput>>,
}

impl RenderedImage {
    /// Pixel-major outputs of `which` levels of a model of `levels` levels (as
    /// [`Model::render_levels`] gives them), split into the fine level and, with every level,
    /// the coarse one.
    #[must_use]
    pub fn from_outputs(width: u32, height: u32, (levels, which): (usize, Levels), outputs: &[LevelOutput]) -> Self {
        let levels = match which {
            Levels::All => levels.max(1),
            Levels::Last => 1,
        };
        Self {
            width,
            height,
            fine: outputs.chunks(levels).map(|l| l[levels - 1]).collect(),
            coarse: (which == Levels::All).then(|| outputs.chunks(levels).map(|l| l[0]).collect()),
        }
    }

    /// The fine level's colour as an 8-bit image (clamped to `[0, 1]`, rounded).
    ///
    /// # Errors
    /// [`BackendError::Invalid`] when `fine` does not hold `width x height` pixels (an image
    /// assembled by hand; a backend's renders always do).
    pub fn to_rgb_image(&self) -> Result<image::RgbImage, BackendError> {
        let bytes = self.fine.iter().flat_map(|o| o.rgb.map(|c| (c.clamp(0.0, 1.0) * 255.0).round() as u8)).collect();
        image::RgbImage::from_raw(self.width, self.height, bytes).ok_or_else(|| {
            BackendError::Invalid(format!(
                "a rendered image of {}x{} pixels holds {} pixels",
                self.width,
                self.height,
                self.fine.len()
            ))
        })
    }
}

/// Trains and renders one model. Implemented by [`CpuBackend`] and by `mipnerf_gpu::GpuBackend`.
pub trait Backend: Send {
    /// What runs the work, for logs: "CPU (2 threads)", "GPU: NVIDIA H100 (Vulkan)".
    fn describe(&self) -> String;

    /// The model.
    fn model(&self) -> &Model;

    /// Sets the precision of the MLP's matrix products for the steps and renders that follow.
    /// The default accepts only [`Precision::F32`] (a device backend's precision).
    ///
    /// # Errors
    /// [`BackendError::Unsupported`] with [`Unsupported::Bf16`] where the backend does not run
    /// bf16, [`BackendError::Invalid`] where the CPU lacks the feature (named).
    fn set_precision(&mut self, precision: Precision) -> Result<(), BackendError> {
        match precision {
            Precision::F32 => Ok(()),
            Precision::Bf16 => Err(Unsupported::Bf16.into()),
        }
    }

    /// Whether the training steps that follow flush subnormal floats to zero
    /// ([`crate::subnormals`]). The default ignores it: a device backend computes in its
    /// shaders' own float mode.
    fn set_flush_subnormals(&mut self, _flush: bool) {}

    /// The number of the next training step (the steps done so far).
    fn step(&self) -> u64;

    /// One training step: draws the step's batch from the training data, computes the loss and
    /// gradient of both levels, clips, and applies Adam. Returns the step's losses when `report`
    /// is set (a backend on a device only reads them back then); `None` otherwise.
    ///
    /// # Errors
    /// [`BackendError::NoData`] without training data; device failures.
    fn train_step(&mut self, report: bool) -> Result<Option<StepReport>, BackendError>;

    /// Replaces the learning-rate schedule from the next step on (`train --time-budget` stretches
    /// it to the steps the budget allows as the run learns its speed).
    fn set_lr_schedule(&mut self, lr: LrSchedule);

    /// The parameters, Adam state and step, as a checkpoint (read back from a device).
    ///
    /// # Errors
    /// Device failures.
    fn checkpoint(&mut self) -> Result<Checkpoint, BackendError>;

    /// Renders every pixel of `image` with the current parameters (evaluation mode): per pixel
    /// the fine level's colour, distance and opacity and, with [`Levels::All`], the coarse
    /// level's (the levels of [`Model::render_levels`]); supersampled rays are averaged per
    /// pixel. [`Levels::Last`] is what images, depth maps and metrics need: its fine level is the
    /// same as with [`Levels::All`], and a backend may skip work only the coarse level's outputs
    /// need (the CPU skips the coarse level's colour layers).
    ///
    /// # Errors
    /// [`BackendError::Unsupported`] for what the backend does not render; device failures.
    fn render(&mut self, image: &ImageSpec, levels: Levels) -> Result<RenderedImage, BackendError>;

    /// What the backend has sent to and read from a device so far, for `mipnerf bench`; `None`
    /// for a backend without a device (the CPU).
    fn work_counters(&self) -> Option<WorkCounters> {
        None
    }

    /// Host memory a training step of `batch_rays` rays takes, in bytes, for checking it against
    /// the memory available before the first step; 0 for a device backend, whose batch lives on
    /// the device (and is sized against the device's limits).
    fn host_training_bytes(&self, batch_rays: usize) -> u64 {
        let _ = batch_rays;
        0
    }
}

/// Running totals of a device backend's work and allocations since it was made. The difference
/// of two snapshots is what happened in between (`a - b`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct WorkCounters {
    /// Compute dispatches recorded.
    pub dispatches: u64,
    /// Compute passes recorded.
    pub compute_passes: u64,
    /// Command buffers submitted.
    pub submits: u64,
    /// Device buffers created (storage, uniform and staging).
    pub buffers_created: u64,
    /// Bind groups created.
    pub bind_groups_created: u64,
    /// Bytes copied back from the device to the host.
    pub bytes_read_back: u64,
    /// Rays run through the model (sampling, MLP and rendering of every level), summed over
    /// passes: with occupancy-guided sampling, only the rays that meet an occupied cell.
    pub model_rays: u64,
}

impl std::ops::Sub for WorkCounters {
    type Output = Self;
    fn sub(self, b: Self) -> Self {
        Self {
            dispatches: self.dispatches - b.dispatches,
            compute_passes: self.compute_passes - b.compute_passes,
            submits: self.submits - b.submits,
            buffers_created: self.buffers_created - b.buffers_created,
            bind_groups_created: self.bind_groups_created - b.bind_groups_created,
            bytes_read_back: self.bytes_read_back - b.bytes_read_back,
            model_rays: self.model_rays - b.model_rays,
        }
    }
}

/// Where a training run starts: fresh parameters from the seed, or a checkpoint.
#[derive(Clone, Debug)]
pub struct TrainState {
    /// Parameters.
    pub params: Vec<f32>,
    /// Adam's moments and update count.
    pub adam: AdamState,
    /// The next step.
    pub step: u64,
    /// The occupancy grid guiding sampling, if the run uses one.
    pub occupancy: Option<OccupancyGrid>,
}

impl TrainState {
    /// Fresh Glorot parameters drawn from `seed`, zero moments, step 0 (what [`Trainer::new`]
    /// starts from).
    #[must_use]
    pub fn fresh(model: &Model, seed: u32) -> Self {
        Self {
            params: model.init_params(u64::from(seed)),
            adam: AdamState::new(model.num_params()),
            step: 0,
            occupancy: None,
        }
    }

    /// The state saved in `ck`.
    #[must_use]
    pub fn from_checkpoint(ck: Checkpoint) -> Self {
        Self { params: ck.params, adam: ck.adam, step: ck.step, occupancy: ck.occupancy }
    }

    /// Checks the lengths against `model`.
    ///
    /// # Errors
    /// [`BackendError::Invalid`] naming the mismatch.
    pub fn check(&self, model: &Model) -> Result<(), BackendError> {
        let n = model.num_params();
        if self.params.len() != n || self.adam.m.len() != n || self.adam.v.len() != n {
            return Err(BackendError::Invalid(format!(
                "the state holds {} parameters and {}/{} Adam moments; the model has {n}",
                self.params.len(),
                self.adam.m.len(),
                self.adam.v.len()
            )));
        }
        Ok(())
    }
}

/// The one check that supersampling is not asked of forward-facing (NDC) data, shared by the
/// CPU and GPU backends, images and the CLI.
///
/// # Errors
/// [`BackendError::Unsupported`] with [`Unsupported::NdcSupersample`].
pub fn check_ndc_supersample(ndc: Option<Ndc>, supersample: usize) -> Result<(), BackendError> {
    if ndc.is_some() && supersample > 1 {
        return Err(Unsupported::NdcSupersample.into());
    }
    Ok(())
}

/// Why forward-facing data and supersampling do not mix.
pub const NDC_SUPERSAMPLE: &str = "supersampling (`ModelConfig::supersample`) is not defined for forward-facing (NDC) datasets: sub-pixel rays are not mapped to NDC";

/// Rays per chunk when the CPU renders an image, unless set (bounds the rays held at once).
pub const CPU_RENDER_CHUNK: usize = 16 * 1024;

/// The CPU backend: [`Trainer`] with batches drawn by [`Dataset::sample_batch`], and
/// [`Model::render`] in chunks.
#[derive(Debug)]
pub struct CpuBackend {
    trainer: Trainer,
    data: Option<(Arc<Dataset>, usize)>,
    /// Rays per rendering chunk.
    render_chunk: usize,
    rays: Vec<Ray>,
    targets: Vec<[f32; 3]>,
    /// Training steps flush subnormals to zero ([`Backend::set_flush_subnormals`]).
    flush_subnormals: bool,
}

impl CpuBackend {
    /// A backend for `model` starting from `state`, training with `optim` and `seed`.
    ///
    /// # Errors
    /// [`BackendError::Invalid`] when the state does not fit the model.
    pub fn new(model: Model, optim: OptimConfig, seed: u32, state: TrainState) -> Result<Self, BackendError> {
        state.check(&model)?;
        let mut trainer = Trainer::new(model, optim, seed);
        trainer.params = state.params;
        trainer.adam = state.adam;
        trainer.step = state.step;
        trainer.occupancy = state.occupancy;
        Ok(Self {
            trainer,
            data: None,
            render_chunk: CPU_RENDER_CHUNK,
            rays: Vec::new(),
            targets: Vec::new(),
            flush_subnormals: false,
        })
    }

    /// Renders in chunks of about `rays` rays (whole pixels, at least one; default
    /// [`CPU_RENDER_CHUNK`]): the memory a render holds at once. Rays are independent, but the
    /// matrix product sums a partial block of rows in another order than a full one, so images
    /// rendered with different chunks agree only to rounding (about 1e-5 relative).
    #[must_use]
    pub fn with_render_chunk(mut self, rays: usize) -> Self {
        self.render_chunk = rays.max(1);
        self
    }

    /// Trains on batches of `batch_rays` pixels of `data`.
    #[must_use]
    pub fn with_data(mut self, data: Arc<Dataset>, batch_rays: usize) -> Self {
        self.data = Some((data, batch_rays));
        self
    }

    /// The trainer inside.
    #[must_use]
    pub fn trainer(&self) -> &Trainer {
        &self.trainer
    }
}

/// "1 thread", "2 threads": a thread count as [`CpuBackend`]'s description says it.
fn threads_in_words(n: usize) -> String {
    if n == 1 { "1 thread".to_string() } else { format!("{n} threads") }
}

impl Backend for CpuBackend {
    fn describe(&self) -> String {
        let threads = threads_in_words(rayon::current_num_threads());
        match self.trainer.model.precision() {
            Precision::F32 => format!("CPU ({threads})"),
            Precision::Bf16 => format!(
                "CPU ({threads}, bf16 on {})",
                crate::bf16::Bf16Support::detect().kernel().map_or("no bf16 kernel", crate::bf16::Bf16Kernel::name)
            ),
        }
    }

    fn model(&self) -> &Model {
        &self.trainer.model
    }

    fn set_precision(&mut self, precision: Precision) -> Result<(), BackendError> {
        self.trainer.model.set_precision(precision).map_err(|e| BackendError::Invalid(e.to_string()))
    }

    fn set_flush_subnormals(&mut self, flush: bool) {
        self.flush_subnormals = flush;
    }

    fn step(&self) -> u64 {
        self.trainer.step
    }

    fn train_step(&mut self, report: bool) -> Result<Option<StepReport>, BackendError> {
        let (ds, batch) = self.data.as_ref().ok_or(BackendError::NoData)?;
        let t = &self.trainer;
        let c = t.model.config();
        check_ndc_supersample(ds.ndc, c.supersample)?;
        ds.sample_batch(
            BatchDraw {
                supersample: c.supersample,
                random_bkgd: c.random_bkgd,
                ..BatchDraw::new(*batch, t.seed, t.step as u32)
            },
            &mut self.rays,
            &mut self.targets,
        );
        let _flushed = self.flush_subnormals.then(crate::subnormals::Flushed::begin);
        let rep = self.trainer.train_step(&self.rays, &self.targets);
        // The CPU has the losses anyway; it returns them only when asked, as the trait says.
        Ok(report.then_some(rep))
    }

    fn set_lr_schedule(&mut self, lr: LrSchedule) {
        self.trainer.optim.lr = lr;
    }

    fn checkpoint(&mut self) -> Result<Checkpoint, BackendError> {
        let t = &self.trainer;
        Ok(Checkpoint { step: t.step, params: t.params.clone(), adam: t.adam.clone(), occupancy: t.occupancy.clone() })
    }

    fn host_training_bytes(&self, batch_rays: usize) -> u64 {
        self.trainer.model.training_bytes(batch_rays)
    }

    fn render(&mut self, image: &ImageSpec, levels: Levels) -> Result<RenderedImage, BackendError> {
        let model = &self.trainer.model;
        image.check_for(model)?;
        let mut out = Vec::with_capacity(image.pixels() * model.config().num_levels);
        let mut rays = Vec::new();
        let chunk_pixels = (self.render_chunk / model.rays_per_pixel()).max(1);
        for first in (0..image.pixels()).step_by(chunk_pixels) {
            rays.clear();
            image.push_rays(first, chunk_pixels, &mut rays);
            out.extend(model.render_levels(&self.trainer.params, &rays, self.trainer.occupancy.as_ref(), levels));
        }
        let (w, h) = (image.camera.width, image.camera.height);
        Ok(RenderedImage::from_outputs(w, h, (model.config().num_levels, levels), &out))
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_thread_count_is_said_in_words() {
        assert_eq!(super::threads_in_words(1), "1 thread");
        assert_eq!(super::threads_in_words(2), "2 threads");
        assert_eq!(super::threads_in_words(16), "16 threads");
    }
}
