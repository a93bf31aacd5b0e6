//! Gradient clipping and Adam over the parameters. Kernel: `adam.wgsl`.

use crate::optim::{AdamConfig, AdamState, FieldAdam, clip_gradients};

/// One optimiser step's settings, as [`adam_step`] and its kernel (`adam.wgsl`) take them:
/// Adam's settings, the learning rate, the clipping and the field's own Adam settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdamStep {
    /// Adam's settings.
    pub cfg: AdamConfig,
    /// Learning rate.
    pub lr: f32,
    /// Clip each entry to `±max_val` (0: off).
    pub max_val: f32,
    /// Clip the norm to `max_norm` (0: off).
    pub max_norm: f32,
    /// The field's own parameters (the first ones) and their learning-rate multiplier and
    /// epsilon ([`AdamState::update_split`]).
    pub split: Option<(usize, FieldAdam)>,
}

/// One optimiser step: the gradient clipped by value then by norm ([`clip_gradients`], as the
/// official `train_step`), then the bias-corrected Adam update ([`AdamState::update`]) at
/// learning rate `lr` (the first `split.0` parameters, a field's own, at its settings
/// [`FieldAdam`]: [`AdamState::update_split`]). Returns the gradient norm after value clipping,
/// the quantity the official code logs. Kernel: `adam.wgsl`.
///
/// # Panics
/// If the lengths differ.
pub fn adam_step(step: &AdamStep, state: &mut AdamState, params: &mut [f32], grads: &mut [f32]) -> f32 {
    let norm = clip_gradients(grads, step.max_val, step.max_norm);
    state.update_split(&step.cfg, step.lr, step.split, params, grads);
    norm
}
