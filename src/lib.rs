//! # mipnerf
//!
//! Anti-aliased neural radiance fields (Mip-NeRF, Barron et al. 2021) in Rust, on any GPU through
//! wgpu and on the CPU. This facade re-exports the two library crates:
//! - [`core`] (`mipnerf-core`): the maths on the CPU, the reference for every other path;
//! - [`gpu`] (`mipnerf-gpu`): the same passes as WGSL compute shaders.

pub use mipnerf_core as core;
pub use mipnerf_gpu as gpu;
