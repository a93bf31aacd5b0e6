//! # mipnerf
//!
//! Anti-aliased neural radiance fields (Mip-NeRF, Barron et al. 2021) in Rust, on any GPU through
//! wgpu and on the CPU. This facade re-exports the two library crates:
//! - [`core`] (`mipnerf-core`): the maths on the CPU, the reference for every other path;
//! - [`gpu`] (`mipnerf-gpu`): the same passes as WGSL compute shaders.
//!
//! Training and rendering go through one trait, [`core::backend::Backend`], implemented by
//! [`core::backend::CpuBackend`] and [`gpu::GpuBackend`]:
//!
//! ```
//! use std::sync::Arc;
//!
//! use mipnerf::core::Camera;
//! use mipnerf::core::backend::{Backend, CpuBackend, ImageSpec, TrainState};
//! use mipnerf::core::data::{Dataset, Pixels, Split, View, demo};
//! use mipnerf::core::model::{Model, Preset};
//! use mipnerf::core::train::OptimConfig;
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! // Four 16x16 views of the built-in demo scene, in memory (`core::data::load` reads files).
//! let mut views = Vec::new();
//! for (i, pose) in demo::view_poses(4, 0.0).into_iter().enumerate() {
//!     let camera = Camera::from_camera_angle_x(16, 16, 0.69, pose)?;
//!     let pixels = Pixels::RgbaF32(demo::render_view(&camera, 1));
//!     let file = format!("view{i}.png").into();
//!     views.push(View { file, camera, pixels, near: 2.0, far: 6.0, lossmult: 1.0, scale: 0 });
//! }
//! let data = Arc::new(Dataset::new("demo".as_ref(), Split::Train, views, true)?);
//! let model = Model::new(Preset::Tiny.config())?;
//! let state = TrainState::fresh(&model, 0);
//! // On a GPU instead: `mipnerf::gpu::GpuBackend::new(GpuContext::new(AdapterChoice::Any)?,
//! // model, optim, seed, state)?.with_data(&data, 64)?`.
//! let mut backend = CpuBackend::new(model, OptimConfig::default(), 0, state)?.with_data(Arc::clone(&data), 64);
//! for step in 0..3 {
//!     // Ask for the losses on the last step only (a GPU reads them back only then).
//!     if let Some(report) = backend.train_step(step == 2)? {
//!         assert!(report.stats.loss.is_finite());
//!     }
//! }
//! // Every pixel of view 0 at both levels (coarse, fine), pixel-major.
//! let outputs = backend.render_image(&ImageSpec::of_view(&data, 0, 1))?;
//! assert_eq!(outputs.len(), 16 * 16 * 2);
//! # Ok(())
//! # }
//! ```

pub use mipnerf_core as core;
pub use mipnerf_gpu as gpu;
