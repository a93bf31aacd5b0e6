//! Gradient clipping and Adam over the parameters. Kernel: `adam.wgsl`.

use crate::optim::{AdamConfig, AdamState, FieldAdam, clip_gradients};

/// One optimiser step: the gradient clipped by value then by norm ([`clip_gradients`], as the
/// official `train_step`), then the bias-corrected Adam update ([`AdamState::update`]) at
/// learning rate `lr` (the first `split.0` parameters, a field's own, at its settings
/// [`FieldAdam`]: [`AdamState::update_split`]). Returns the gradient norm after value clipping, the quantity the official
/// code logs. Kernel: `adam.wgsl`.
///
/// # Panics
/// If the lengths differ.
pub fn adam_step(
    cfg: &AdamConfig,
    lr: f32,
    (max_val, max_norm): (f32, f32),
    split: Option<(usize, FieldAdam)>,
    state: &mut AdamState,
    params: &mut [f32],
    grads: &mut [f32],
) -> f32 {
    let norm = clip_gradients(grads, max_val, max_norm);
    state.update_split(cfg, lr, split, params, grads);
    norm
}
