//! # mipnerf
//!
//! Anti-aliased neural radiance fields (Mip-NeRF, Barron et al. 2021) in Rust, on any GPU through
//! wgpu and on the CPU. Give [`Nerf`] posed images (a dataset folder, or your own images held in
//! memory), train it for a number of steps or a time budget, render any camera, save and load it:
//!
//! ```
//! use mipnerf::{Camera, Nerf, Options, Pixels, Preset, View, demo};
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! // Your images and cameras: here four 16x16 renders of the built-in demo scene, straight RGBA
//! // in [0, 1] (`Pixels::Rgba8` takes bytes), with camera-to-world poses (OpenGL axes).
//! let mut views = Vec::new();
//! for (i, pose) in demo::view_poses(4, 0.0).into_iter().enumerate() {
//!     let camera = Camera::from_camera_angle_x(16, 16, 0.69, pose)?;
//!     let pixels = Pixels::RgbaF32(demo::render_view(&camera, 1));
//!     views.push(View::in_memory(&format!("view {i}"), camera, pixels, 2.0, 6.0));
//! }
//! // On a hardware GPU when there is one, else on the CPU (`nerf.fallback()` says why).
//! let mut nerf = Nerf::from_views(views, Options::preset(Preset::Tiny))?;
//! let report = nerf.train(3)?;
//! assert!(report.stats.loss.is_finite());
//! // A novel view: a camera at a pose no training image has, at 32x24 pixels.
//! let camera = Camera::from_camera_angle_x(32, 24, 0.69, demo::camera_pose(1.0, 0.4))?;
//! let picture = nerf.render(&camera)?.to_rgb_image()?;
//! assert_eq!(picture.dimensions(), (32, 24));
//! # let dir = tempfile::tempdir()?;
//! # let path = dir.path().join("lego.safetensors");
//! nerf.save(&path)?;
//! # Ok(())
//! # }
//! ```
//!
//! The `gpu` feature (on by default) brings the WGSL backend (the `mipnerf-gpu` crate); without
//! it, nothing of wgpu is compiled, [`Device::Auto`] runs on the CPU and [`Device::Gpu`] is
//! [`Error::NoGpuBackend`].
//!
//! This crate re-exports what the calls above take and give. The two library crates behind it,
//! `mipnerf-core` (the maths on the CPU, the reference for every other path: data formats, the
//! model and its stages, checkpoints, metrics) and `mipnerf-gpu` (the same passes as WGSL compute
//! shaders, `open_backend`, a backend on an app's own wgpu device), are for an app that needs
//! more: depend on them beside this one.

mod nerf;

pub use image::RgbImage;
pub use mipnerf_core::Camera;
pub use mipnerf_core::backend::{Backend, BackendError, MAX_BATCH_RAYS, RenderedImage};
pub use mipnerf_core::checkpoint::CheckpointError;
pub use mipnerf_core::dataset::{DataError, Dataset, Pixels, View};
pub use mipnerf_core::demo;
pub use mipnerf_core::hash_grid::HashGridConfig;
pub use mipnerf_core::model::{Field, LevelOutput, LossStats, ModelConfig, ModelError, Preset};
pub use mipnerf_core::schedule::LrSchedule;
pub use mipnerf_core::train::{OptimConfig, StepReport};
pub use mipnerf_core::tri_mip::TriMipConfig;
#[cfg(feature = "gpu")]
pub use mipnerf_gpu::OpenError;
pub use nerf::{Device, Error, Nerf, Options, Precision};

use std::sync::Arc;

use mipnerf_core::backend::TrainState;
use mipnerf_core::model::Model;

/// The backend `options.device` selects, and why `Auto` fell back to the CPU. With the `gpu`
/// feature, the GPU crate's `open_backend` chooses; without it, the CPU runs `Cpu` and `Auto`.
fn open_backend(
    options: &Options,
    model: Model,
    state: TrainState,
    data: Option<(Arc<Dataset>, usize)>,
) -> Result<(Box<dyn Backend>, Option<String>), Error> {
    #[cfg(feature = "gpu")]
    {
        use mipnerf_gpu::{BackendChoice, BackendSetup};
        let choice = match options.device {
            Device::Cpu => BackendChoice::Cpu,
            Device::Gpu => BackendChoice::Gpu,
            Device::Auto => BackendChoice::Auto,
        };
        let setup = BackendSetup {
            model,
            optim: options.optim.clone(),
            seed: options.seed,
            state,
            data,
            render_chunk: None,
            device: mipnerf_gpu::DeviceOptions::default(),
        };
        let opened = mipnerf_gpu::open_backend(choice, setup)?;
        Ok((opened.backend, opened.fallback))
    }
    #[cfg(not(feature = "gpu"))]
    {
        let fallback = match options.device {
            Device::Gpu => return Err(Error::NoGpuBackend),
            Device::Auto => Some("this build of mipnerf has no GPU backend (its `gpu` feature is off)".to_owned()),
            Device::Cpu => None,
        };
        let mut cpu = mipnerf_core::backend::CpuBackend::new(model, options.optim.clone(), options.seed, state)?;
        if let Some((ds, batch)) = data {
            cpu = cpu.with_data(ds, batch);
        }
        Ok((Box::new(cpu), fallback))
    }
}
