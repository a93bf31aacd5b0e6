//! # mipnerf
//!
//! Anti-aliased neural radiance fields (Mip-NeRF, Barron et al. 2021) in Rust, on any GPU through
//! wgpu and on the CPU. This facade re-exports the two library crates:
//! - [`core`] (`mipnerf-core`): the maths on the CPU, the reference for every other path;
//! - [`gpu`] (`mipnerf-gpu`): the same passes as WGSL compute shaders.
//!
//! Training and rendering go through one trait, [`core::backend::Backend`], implemented by
//! [`core::backend::CpuBackend`] and [`gpu::GpuBackend`]; [`gpu::open_backend`] opens either
//! (`Cpu`, `Gpu`, or `Auto`: a hardware GPU when there is one, else the CPU, saying why). Train on
//! your own images held in memory, then render a novel view:
//!
//! ```
//! use std::sync::Arc;
//!
//! use mipnerf::core::Camera;
//! use mipnerf::core::backend::{ImageSpec, TrainState};
//! use mipnerf::core::data::{Dataset, Pixels, Split, View, demo};
//! use mipnerf::core::model::{Model, Preset};
//! use mipnerf::core::train::OptimConfig;
//! use mipnerf::gpu::{BackendChoice, BackendSetup, DeviceOptions, open_backend};
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
//! let data = Arc::new(Dataset::from_views(Split::Train, views, true)?);
//! let model = Model::new(Preset::Tiny.config())?;
//! let setup = BackendSetup {
//!     state: TrainState::fresh(&model, 0),
//!     model,
//!     optim: OptimConfig::default(),
//!     seed: 0,
//!     data: Some((Arc::clone(&data), 64)),
//!     render_chunk: None,
//!     // The best adapter (or the one WGPU_ADAPTER_NAME names), its memory budget from its limits.
//!     device: DeviceOptions::default(),
//! };
//! let opened = open_backend(BackendChoice::Auto, setup)?;
//! if let Some(why) = &opened.fallback {
//!     println!("on the CPU: {why}");
//! }
//! let mut backend = opened.backend;
//! for step in 0..3 {
//!     // Ask for the losses on the last step only (a GPU reads them back only then).
//!     if let Some(report) = backend.train_step(step == 2)? {
//!         assert!(report.stats.loss.is_finite());
//!     }
//! }
//! // A novel view: a camera at a pose no training image has, at 32x24 pixels.
//! let camera = Camera::from_camera_angle_x(32, 24, 0.69, demo::camera_pose(1.0, 0.4))?;
//! let spec = ImageSpec { camera, ..ImageSpec::of_view(&data, 0, 1) };
//! let rendered = backend.render(&spec)?;
//! let picture: image::RgbImage = rendered.to_rgb_image();
//! assert_eq!(picture.dimensions(), (32, 24));
//! assert!(rendered.fine.iter().all(|o| (0.0..=1.0).contains(&o.acc)));
//! # Ok(())
//! # }
//! ```

pub use mipnerf_core as core;
pub use mipnerf_gpu as gpu;
