//! The paper's stages over a batch of rays: one public function per WGSL kernel, on flat arrays
//! laid out as the kernel's buffers are. [`crate::model::Model`] composes them (its chunk loop is
//! these calls in order), and each GPU kernel's test compares the kernel with its function here
//! through [`crate::compare::check_kernel`]. The one lookup path:
//!
//! | paper stage | CPU reference (here) | WGSL kernel (`shaders/`) and its Rust wrapper (`mipnerf-gpu/src/kernels/`) |
//! |---|---|---|
//! | stratified sampling along the ray | [`sample_intervals`], [`sample_occupied_intervals`] | `sample.wgsl` `stratified`, `occupancy.wgsl` (`sample.rs`, `occupancy.rs`) |
//! | hierarchical resampling | [`resample_intervals`] | `sample.wgsl` `resample` (`sample.rs`) |
//! | cast cones, conical frustum to Gaussian, IPE | [`cast_and_encode`] | `cast_ipe.wgsl` (`cast_ipe.rs`) |
//! | view-direction encoding | [`encode_view_directions`] | `view_enc.wgsl` (`view_enc.rs`) |
//! | the MLP's layers, forward and backward | [`crate::mlp::MlpShape::forward`], [`crate::mlp::MlpShape::backward`] | `matmul.wgsl`, `mlp_aux.wgsl` (`matmul.rs`, `mlp_aux.rs`) |
//! | density noise, activations, volume rendering, area loss and their backward pass | [`add_density_noise`], [`render_rays`], [`render_rays_backward`], [`crate::model::pixel_loss_gradient`] | `render.wgsl` (`render.rs`) |
//! | gradient clipping and Adam | [`adam_step`] | `adam.wgsl` (`adam.rs`) |
//!
//! Every function writes its outputs in place (allocating at most a per-call scratch the size of
//! one ray's samples) and runs in `f32`, in the order the paper's equations are written.
//!
//! One file per stage: `sample.rs`, `cast_ipe.rs`, `view_enc.rs`, `render.rs`, `adam.rs`, named
//! after their kernels.

mod adam;
mod cast_ipe;
mod render;
mod sample;
mod view_enc;

pub use adam::{AdamStep, adam_step};
pub use cast_ipe::{CastIpe, cast_and_encode, encode_gaussian};
pub use render::{
    DensityNoise, LevelRays, RawGradients, RawOutputs, RenderedSamples, add_density_noise, distortion_loss,
    normalised_distance, render_rays, render_rays_backward,
};
pub use sample::{Resample, Sample, resample_intervals, sample_intervals, sample_occupied_intervals};
pub use view_enc::encode_view_directions;
