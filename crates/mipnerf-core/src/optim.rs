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
    /// Instant-NGP's L2 regularisation of the network: `l2 · p` added to the (clipped) gradient
    /// of every parameter after a field's own (the MLP's), before the moments; 0: off, the
    /// official code's. Instant-NGP's 1e-6, "to prevent divergence after long training periods".
    /// Not written when 0.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub l2: f32,
}

/// Whether `v` is 0 (an L2 that is off, not written). `config.rs` has its twin: this module may
/// not import that one (`config` imports the optimiser's settings; tests/module_graph.rs).
#[allow(clippy::trivially_copy_pass_by_ref)]
fn is_zero(v: &f32) -> bool {
    *v == 0.0
}

impl Default for AdamConfig {
    fn default() -> Self {
        Self { beta1: 0.9, beta2: 0.999, eps: 1e-8, l2: 0.0 }
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
        self.update_split(cfg, lr, None, params, grads);
    }

    /// [`update`](Self::update) with the first `split.0` parameters (a field's own, the Tri-Mip
    /// planes) taking the learning rate `lr · split.1.lr_mult` and epsilon `split.1.eps`; one
    /// step count for both.
    ///
    /// # Panics
    /// If the lengths differ, or the split is longer than the parameters.
    pub fn update_split(
        &mut self,
        cfg: &AdamConfig,
        lr: f32,
        split: Option<(usize, FieldAdam)>,
        params: &mut [f32],
        grads: &[f32],
    ) {
        assert!(params.len() == grads.len() && params.len() == self.m.len(), "adam: lengths");
        let (first, field) = split.unwrap_or((0, FieldAdam::mlp(cfg)));
        assert!(first <= params.len(), "adam: split");
        self.t += 1;
        let t = self.t as i32;
        let c1 = 1.0 - cfg.beta1.powi(t);
        let c2 = 1.0 - cfg.beta2.powi(t);
        const BLOCK: usize = 16 * 1024;
        let part = |lr: f32, adam: FieldAdam, l2: f32, p: &mut [f32], m: &mut [f32], v: &mut [f32], g: &[f32]| {
            let eps = adam.eps;
            p.par_chunks_mut(BLOCK)
                .zip(m.par_chunks_mut(BLOCK))
                .zip(v.par_chunks_mut(BLOCK))
                .zip(g.par_chunks(BLOCK))
                .for_each(|(((p, m), v), g)| {
                    let step = |((p, m), v): ((&mut f32, &mut f32), &mut f32), g: f32| {
                        let g = if l2 == 0.0 { g } else { g + l2 * *p };
                        *m = cfg.beta1 * *m + (1.0 - cfg.beta1) * g;
                        *v = cfg.beta2 * *v + (1.0 - cfg.beta2) * g * g;
                        *p -= lr * (*m / c1) / ((*v / c2).sqrt() + eps);
                    };
                    let entries = p.iter_mut().zip(m.iter_mut()).zip(v.iter_mut()).zip(g.iter().copied());
                    if adam.skip_untouched {
                        entries.filter(|&(_, g)| g != 0.0).for_each(|(e, g)| step(e, g));
                    } else {
                        // Vectors as wide as the CPU's (the same bits: no operation fused or
                        // reordered): a dense step over a grid's millions of entries.
                        crate::wide::wide(
                            #[inline(always)]
                            || entries.for_each(|(e, g)| step(e, g)),
                        );
                    }
                });
        };
        let (p0, p1) = params.split_at_mut(first);
        let (m0, m1) = self.m.split_at_mut(first);
        let (v0, v1) = self.v.split_at_mut(first);
        let (g0, g1) = grads.split_at(first);
        part(lr * field.lr_mult, field, 0.0, p0, m0, v0, g0);
        part(lr, FieldAdam::mlp(cfg), cfg.l2, p1, m1, v1, g1);
    }
}

/// Adam's learning rate and epsilon for a field's own parameters (the Tri-Mip planes) where they
/// differ from the MLP's: grid methods train their grids with a larger rate and a tiny epsilon
/// (Tri-MipRF: 10 times the networks' rate, epsilon 1e-15), so that texels few rays reach
/// still move at the full rate.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FieldAdam {
    /// The field's learning rate over the MLP's.
    pub lr_mult: f32,
    /// Added to the square root of the field's second moments.
    pub eps: f32,
    /// Leave an entry whose gradient is exactly 0 as it is, its moments included (Instant-NGP's
    /// rule for its hash tables), instead of moving it on its momentum and decaying its second
    /// moment: an entry that rays reach once in a while then steps by its gradient over the
    /// moments it had, not by about three learning rates whatever its gradient (the first moment
    /// of one gradient over the square root of a second moment decayed towards that gradient's
    /// square alone: `0.1 / sqrt(0.001)`).
    #[serde(default, skip_serializing_if = "is_false")]
    pub skip_untouched: bool,
}

#[allow(clippy::trivially_copy_pass_by_ref)] // serde's `skip_serializing_if` passes a reference
fn is_false(b: &bool) -> bool {
    !*b
}

impl FieldAdam {
    /// The MLP's own settings (the rate as given, `cfg`'s epsilon, every entry updated).
    #[must_use]
    pub fn mlp(cfg: &AdamConfig) -> Self {
        Self { lr_mult: 1.0, eps: cfg.eps, skip_untouched: false }
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
    /// Adam's settings for the field's own parameters, where they differ (none: the MLP's).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub field: Option<FieldAdam>,
}

impl Default for OptimConfig {
    fn default() -> Self {
        Self {
            lr: LrSchedule::default(),
            adam: AdamConfig::default(),
            grad_max_val: 0.0,
            grad_max_norm: 0.0,
            field: None,
        }
    }
}

/// The sum of the squares of `values` in f64, in 8 lanes (vectorised), then the lanes and the
/// remainder in order.
fn sum_of_squares(values: &[f32]) -> f64 {
    crate::wide::wide(
        #[inline(always)]
        || {
            let mut lanes = [0.0f64; 8];
            let chunks = values.chunks_exact(8);
            let rest = chunks.remainder();
            for c in chunks {
                for (lane, &v) in lanes.iter_mut().zip(c) {
                    *lane += f64::from(v) * f64::from(v);
                }
            }
            lanes.iter().sum::<f64>() + rest.iter().map(|&v| f64::from(v) * f64::from(v)).sum::<f64>()
        },
    )
}

/// Clips `grads` by value then by norm, as the official `train_step` does, and returns the norm
/// after value clipping (before norm clipping), the quantity the official code logs.
pub fn clip_gradients(grads: &mut [f32], max_val: f32, max_norm: f32) -> f32 {
    if max_val > 0.0 {
        grads.iter_mut().for_each(|g| *g = g.clamp(-max_val, max_val));
    }
    // Blocks summed in parallel, then in block order: the same sum whatever the thread count.
    const BLOCK: usize = 64 * 1024;
    let blocks: Vec<f64> = grads.par_chunks(BLOCK).map(sum_of_squares).collect();
    let norm = blocks.iter().sum::<f64>().sqrt() as f32;
    if max_norm > 0.0 {
        let mult = (max_norm / (1e-7 + norm)).min(1.0);
        if mult < 1.0 {
            grads.iter_mut().for_each(|g| *g *= mult);
        }
    }
    norm
}
