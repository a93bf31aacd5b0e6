//! # mipnerf-core
//!
//! The maths of Mip-NeRF (Barron et al., ICCV 2021) on the CPU, in `f32` as the paper and the
//! official JAX code use it. This crate is the reference that every other path (the WGSL kernels
//! of `mipnerf-gpu`) is checked against, and is itself pinned to numbers produced by the official
//! code (see `tests/golden.rs`).
//!
//! The data flow of one ray, in the paper's words:
//! 1. [`camera`] and [`cone`]: a pixel becomes a cone ([`cone::Ray`]: origin, direction, radius).
//! 2. [`sampling::sample_along_rays`]: interval edges `t` along the cone (stratified in training).
//! 3. [`mip::conical_frustum_to_gaussian`]: each interval becomes a Gaussian (mean, diagonal
//!    covariance), and [`mip::integrated_pos_enc`] encodes it (the IPE features fed to the MLP).
//! 4. The MLP gives a colour and a density per interval; [`render::volumetric_rendering`]
//!    composites them into a pixel colour, depth and opacity, with weights per interval.
//! 5. [`sampling::resample_along_rays`]: the fine level's edges from the coarse weights.
//!
//! Unbounded scenes (a room around the object) go through [`contract`]: the Gaussians of step 3
//! are contracted into a ball of radius 2 (mip-NeRF 360), and steps 2 and 5 space the edges in
//! a normalised distance that reaches infinity.
//!
//! [`stages`] runs this flow over a batch of rays, one public function per GPU kernel on the
//! kernel's buffer layout; [`model::Model`] composes them, and each kernel's test compares the
//! kernel with its function through [`compare::check_kernel`].
//!
//! Backward passes ([`render::volumetric_rendering_backward`], the activation derivatives) are
//! analytic and checked against finite differences.
//!
//! Randomness is counter-based ([`rng`]) so that the CPU and the GPU draw the same numbers.
//!
//! The MLP's matrix products run in `f32` ([`linalg`]) unless a model is set to
//! [`bf16::Precision::Bf16`]: operands rounded to bf16, sums in `f32`, on Intel AMX tiles or
//! AVX-512 BF16 (AMD Zen 4 and 5) ([`bf16`]), where the CPU has either.

pub mod backend;
#[cfg(feature = "bench")]
pub mod bench;
pub mod bf16;
pub mod camera;
pub mod checkpoint;
pub mod compare;
pub mod cone;
pub mod config;
pub mod contract;
pub mod dataset;
pub mod demo;
pub mod expf;
pub mod export;
pub mod hash_grid;
pub mod io;
pub mod linalg;
mod lines;
pub mod lpips;
pub mod memory;
pub mod metrics;
pub mod mip;
pub mod mlp;
pub mod model;
pub mod occupancy;
pub mod optim;
pub mod render;
pub mod rng;
pub mod sampling;
pub mod schedule;
pub mod stages;
pub mod subnormals;
#[cfg(any(test, feature = "test-support"))]
pub mod test_support;
pub mod train;
pub mod tri_mip;
pub mod wide;

pub use camera::{Camera, PixelCenters};
pub use cone::{Ray, RayShape, cast_ray, radius_from_spacing};
pub use mip::{
    FrustumMoments, Gaussian, conical_frustum_to_gaussian, cylinder_to_gaussian, integrated_pos_enc, lift_gaussian,
    pos_enc,
};
pub use render::{RenderedRay, volumetric_rendering, volumetric_rendering_backward};
pub use sampling::{PdfSamples, resample_along_rays, sample_along_rays, sorted_piecewise_constant_pdf};

/// Errors of the core crate. Every variant says what was wrong in words a user can act on.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A camera's size, intrinsics or pose is unusable.
    #[error("invalid camera: {0}")]
    InvalidCamera(String),
}
