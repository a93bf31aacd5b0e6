//! Optimisation: Adam, gradient clipping, and the training step on the CPU.

use rayon::prelude::*;

use crate::cone::Ray;
use crate::model::{GradScratch, LossStats, Mode, Model};
use crate::occupancy::OccupancyGrid;
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

/// What one training step reports.
#[derive(Clone, Debug, PartialEq)]
pub struct StepReport {
    /// The step's number (0 for the first).
    pub step: u64,
    /// The learning rate used.
    pub lr: f32,
    /// Losses before the update.
    pub stats: LossStats,
    /// Gradient norm (after value clipping, before norm clipping), where the backend computes it
    /// (the GPU backend does only when clipping by norm).
    pub grad_norm: Option<f32>,
}

/// A model, its parameters and its optimiser state: everything a CPU training run holds.
#[derive(Clone, Debug)]
pub struct Trainer {
    /// The model.
    pub model: Model,
    /// Its parameters.
    pub params: Vec<f32>,
    /// Adam's state.
    pub adam: AdamState,
    /// Optimisation settings.
    pub optim: OptimConfig,
    /// The next step's number.
    pub step: u64,
    /// Seed of the run's random numbers.
    pub seed: u32,
    /// The occupancy grid that guides sampling, updated from the model as it trains (`None`: the
    /// paper's sampler).
    pub occupancy: Option<OccupancyGrid>,
    grads: Vec<f32>,
    scratch: GradScratch,
}

impl Trainer {
    /// A trainer with fresh parameters drawn from `seed`.
    #[must_use]
    pub fn new(model: Model, optim: OptimConfig, seed: u32) -> Self {
        let params = model.init_params(u64::from(seed));
        let n = model.num_params();
        Self {
            model,
            params,
            adam: AdamState::new(n),
            optim,
            step: 0,
            seed,
            occupancy: None,
            grads: vec![0.0; n],
            scratch: GradScratch::default(),
        }
    }

    /// One training step on a batch: the occupancy grid's update when one is due (before the
    /// step, from the current parameters), loss, gradient, clipping, Adam update.
    ///
    /// # Panics
    /// If the batch's lengths disagree (see [`Model::loss_and_grad`]).
    pub fn train_step(&mut self, rays: &[Ray], targets: &[[f32; 3]]) -> StepReport {
        if let Some(grid) = &mut self.occupancy
            && grid.updates_at(self.step)
        {
            grid.update(&self.model, &self.params, self.seed, self.step);
        }
        self.grads.fill(0.0);
        let mode = Mode::Train { seed: self.seed, step: self.step as u32 };
        let (params, grads, scratch) = (&self.params, &mut self.grads, &mut self.scratch);
        let grid = self.occupancy.as_ref();
        let stats = self.model.loss_and_grad_guided(params, rays, targets, mode, grads, scratch, grid);
        let lr = self.optim.lr.lr(self.step);
        let clip = (self.optim.grad_max_val, self.optim.grad_max_norm);
        let grad_norm =
            crate::stages::adam_step(&self.optim.adam, lr, clip, &mut self.adam, &mut self.params, &mut self.grads);
        let report = StepReport { step: self.step, lr, stats, grad_norm: Some(grad_norm) };
        self.step += 1;
        report
    }
}
