//! Optimisation: Adam, gradient clipping and the optimiser's settings, as the official
//! `train_step` applies them.

use rayon::prelude::*;

use crate::schedule::LrSchedule;

/// Adam's settings (the official defaults: 0.9, 0.999, 1e-8).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct AdamConfig {
    /// Decay of the first moment.
    pub beta1: f32,
    /// Decay of the second moment.
    pub beta2: f32,
    /// Added to the second moment's square root.
    pub eps: f32,
}

impl Default for AdamConfig {
    fn default() -> Self {
        Self { beta1: 0.9, beta2: 0.999, eps: 1e-8 }
    }
}

/// Adam's state: first and second moments per parameter, and the number of updates made.
#[derive(Clone, Debug, PartialEq)]
pub struct AdamState {
    /// First moments.
    pub m: Vec<f32>,
    /// Second moments.
    pub v: Vec<f32>,
    /// Updates applied so far.
    pub t: u64,
}

impl AdamState {
    /// Zero moments for `n` parameters.
    #[must_use]
    pub fn new(n: usize) -> Self {
        Self { m: vec![0.0; n], v: vec![0.0; n], t: 0 }
    }

    /// One bias-corrected Adam update (as flax's `optim.Adam`):
    /// `p -= lr m̂ / (sqrt(v̂) + eps)` with `m̂ = m / (1 - β1^t)`, `v̂ = v / (1 - β2^t)`.
    ///
    /// # Panics
    /// If the lengths differ.
    pub fn update(&mut self, cfg: &AdamConfig, lr: f32, params: &mut [f32], grads: &[f32]) {
        assert!(params.len() == grads.len() && params.len() == self.m.len(), "adam: lengths");
        self.t += 1;
        let t = self.t as i32;
        let c1 = 1.0 - cfg.beta1.powi(t);
        let c2 = 1.0 - cfg.beta2.powi(t);
        const BLOCK: usize = 16 * 1024;
        params
            .par_chunks_mut(BLOCK)
            .zip(self.m.par_chunks_mut(BLOCK))
            .zip(self.v.par_chunks_mut(BLOCK))
            .zip(grads.par_chunks(BLOCK))
            .for_each(|(((p, m), v), g)| {
                for i in 0..p.len() {
                    m[i] = cfg.beta1 * m[i] + (1.0 - cfg.beta1) * g[i];
                    v[i] = cfg.beta2 * v[i] + (1.0 - cfg.beta2) * g[i] * g[i];
                    p[i] -= lr * (m[i] / c1) / ((v[i] / c2).sqrt() + cfg.eps);
                }
            });
    }
}

/// Optimisation settings. Defaults are the official ones.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OptimConfig {
    /// Learning-rate schedule.
    pub lr: LrSchedule,
    /// Adam.
    pub adam: AdamConfig,
    /// Clip each gradient entry to `±grad_max_val` (0 = off).
    pub grad_max_val: f32,
    /// Scale the gradient down to this L2 norm if it is larger (0 = off).
    pub grad_max_norm: f32,
}

impl Default for OptimConfig {
    fn default() -> Self {
        Self { lr: LrSchedule::default(), adam: AdamConfig::default(), grad_max_val: 0.0, grad_max_norm: 0.0 }
    }
}

/// Clips `grads` by value then by norm, as the official `train_step` does, and returns the norm
/// after value clipping (before norm clipping), the quantity the official code logs.
pub fn clip_gradients(grads: &mut [f32], max_val: f32, max_norm: f32) -> f32 {
    if max_val > 0.0 {
        grads.iter_mut().for_each(|g| *g = g.clamp(-max_val, max_val));
    }
    let norm = grads.iter().map(|g| f64::from(*g) * f64::from(*g)).sum::<f64>().sqrt() as f32;
    if max_norm > 0.0 {
        let mult = (max_norm / (1e-7 + norm)).min(1.0);
        if mult < 1.0 {
            grads.iter_mut().for_each(|g| *g *= mult);
        }
    }
    norm
}
