//! The training step on the CPU: the model's loss and gradient, the optimiser ([`crate::optim`],
//! re-exported here) and the occupancy grid's updates.

use crate::model::{GradWith, TrainBatch};
use rayon::prelude::*;

use crate::cone::Ray;
use crate::model::{GradScratch, LossStats, Mode, Model};
use crate::occupancy::OccupancyGrid;

pub use crate::optim::{AdamConfig, AdamState, FieldAdam, OptimConfig, clip_gradients};

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
            grid.update(&self.model.density_field(&self.params), self.seed, self.step);
        }
        self.grads.par_chunks_mut(64 * 1024).for_each(|g| g.fill(0.0));
        let mode = Mode::Train { seed: self.seed, step: self.step as u32 };
        let (params, grads, scratch) = (&self.params, &mut self.grads, &mut self.scratch);
        let grid = self.occupancy.as_ref();
        let stats = self.model.loss_and_grad(
            params,
            TrainBatch { rays, targets },
            mode,
            grads,
            GradWith { scratch: Some(scratch), grid },
        );
        let lr = self.optim.lr.lr(self.step);
        let step = crate::stages::AdamStep {
            cfg: self.optim.adam,
            lr,
            max_val: self.optim.grad_max_val,
            max_norm: self.optim.grad_max_norm,
            split: self.optim.field.map(|f| (self.model.field_params(), f)),
        };
        let (params, grads) = (&mut self.params, &mut self.grads);
        let grad_norm = crate::stages::adam_step(&step, &mut self.adam, params, grads);
        let report = StepReport { step: self.step, lr, stats, grad_norm: Some(grad_norm) };
        self.step += 1;
        report
    }
}
