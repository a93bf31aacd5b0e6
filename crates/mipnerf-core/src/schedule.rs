//! The learning-rate schedule of the official code: log-linear decay with a delayed warm-up.

/// The learning-rate schedule's settings (official defaults in [`LrSchedule::default`]).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LrSchedule {
    /// Learning rate at step 0 (before the warm-up factor).
    pub lr_init: f32,
    /// Learning rate at `max_steps`.
    pub lr_final: f32,
    /// Steps over which the rate decays log-linearly from `lr_init` to `lr_final`.
    pub max_steps: u64,
    /// Length of the warm-up (0 for none).
    pub lr_delay_steps: u64,
    /// Factor on the rate at step 0; it rises to 1 along a quarter sine over `lr_delay_steps`.
    pub lr_delay_mult: f32,
    /// At most this many steps of decay: the rate reaches `lr_final` by step
    /// `min(max_steps, decay_steps)` and stays there, however far a time budget stretches
    /// `max_steps` (none: `max_steps`). The hash grid's recipe holds its rate down this way.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub decay_steps: Option<u64>,
}

impl Default for LrSchedule {
    fn default() -> Self {
        Self {
            lr_init: 5e-4,
            lr_final: 5e-6,
            max_steps: 1_000_000,
            lr_delay_steps: 2500,
            lr_delay_mult: 0.01,
            decay_steps: None,
        }
    }
}

impl LrSchedule {
    /// The learning rate at `step`:
    /// `[m + (1 - m) sin(π/2 clip(step / delay, 0, 1))] exp((1 - t) ln lr_init + t ln lr_final)`
    /// with `t = clip(step / min(max_steps, decay_steps), 0, 1)`.
    #[must_use]
    pub fn lr(&self, step: u64) -> f32 {
        let delay_rate = if self.lr_delay_steps > 0 {
            let frac = (step as f64 / self.lr_delay_steps as f64).clamp(0.0, 1.0) as f32;
            self.lr_delay_mult + (1.0 - self.lr_delay_mult) * (0.5 * std::f32::consts::PI * frac).sin()
        } else {
            1.0
        };
        let horizon = self.max_steps.min(self.decay_steps.unwrap_or(u64::MAX)).max(1);
        let t = (step as f64 / horizon as f64).clamp(0.0, 1.0) as f32;
        let log_lerp = ((1.0 - t) * self.lr_init.ln() + t * self.lr_final.ln()).exp();
        delay_rate * log_lerp
    }

    /// This schedule with its decay stretched over the steps a time budget allows, from step
    /// `step`: `budget_left` seconds of training left at `seconds_per_step` each, so that the
    /// rate reaches `lr_final` as the budget runs out (the warm-up keeps its step count). Before
    /// a step has been timed (`seconds_per_step` `None`) the decay has not started: a horizon
    /// of `u32::MAX` steps. What `mipnerf train --time-budget` and the library's
    /// `Nerf::train_for` train with, recomputed at every step as the speed becomes known.
    #[must_use]
    pub fn stretched_to_budget(self, step: u64, budget_left: f64, seconds_per_step: Option<f64>) -> Self {
        let total = match seconds_per_step.filter(|s| s.is_finite() && *s > 0.0) {
            Some(per_step) => step + (budget_left / per_step).max(0.0).ceil() as u64,
            None => u64::from(u32::MAX),
        };
        Self { max_steps: total.max(step + 1), ..self }
    }
}

#[cfg(test)]
mod tests {
    use super::LrSchedule;

    /// The stretched decay ends with the budget: at the budget's last step the rate is
    /// `lr_final`, half-way it is the log-midpoint; untimed, the decay has not started.
    #[test]
    fn a_budget_stretches_the_decay_to_end_with_it() {
        let base = LrSchedule { lr_delay_steps: 0, ..LrSchedule::default() };
        // 100 s left at 0.5 s a step from step 10: 200 more steps, the horizon at 210.
        let s = base.stretched_to_budget(10, 100.0, Some(0.5));
        assert_eq!(s.max_steps, 210);
        assert!((s.lr(210) - base.lr_final).abs() <= 1e-9, "{}", s.lr(210));
        let mid = (base.lr_init * base.lr_final).sqrt();
        assert!((s.lr(105) - mid).abs() <= 1e-3 * mid, "{} against {mid}", s.lr(105));
        assert_eq!(base.stretched_to_budget(10, 100.0, None).max_steps, u64::from(u32::MAX));
        // A spent budget: the horizon is the next step, the rate the final one.
        assert_eq!(base.stretched_to_budget(10, -5.0, Some(0.5)).max_steps, 11);
    }

    /// A decay held to `decay_steps` reaches `lr_final` there and stays, however far a budget
    /// stretches the horizon; a cap past the horizon changes nothing.
    #[test]
    fn a_decay_cap_ends_the_decay_early_and_keeps_the_final_rate() {
        let base = LrSchedule { lr_delay_steps: 0, max_steps: 1000, ..LrSchedule::default() };
        let capped = LrSchedule { decay_steps: Some(100), ..base };
        // exp(ln lr_final) in f32: within a few ulps of lr_final.
        let at_final = |lr: f32| (lr - base.lr_final).abs() <= 1e-6 * base.lr_final;
        assert!(at_final(capped.lr(100)) && capped.lr(500) == capped.lr(100));
        assert!((capped.lr(50) - (base.lr_init * base.lr_final).sqrt()).abs() <= 1e-6 * base.lr_init);
        let stretched = capped.stretched_to_budget(10, 1e6, Some(0.01));
        assert!(stretched.decay_steps == Some(100) && at_final(stretched.lr(200)));
        let far = LrSchedule { decay_steps: Some(5000), ..base };
        for step in [0, 10, 500, 1000, 2000] {
            assert_eq!(far.lr(step), base.lr(step), "step {step}");
        }
    }
}
