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
}

impl Default for LrSchedule {
    fn default() -> Self {
        Self { lr_init: 5e-4, lr_final: 5e-6, max_steps: 1_000_000, lr_delay_steps: 2500, lr_delay_mult: 0.01 }
    }
}

impl LrSchedule {
    /// The learning rate at `step`:
    /// `[m + (1 - m) sin(π/2 clip(step / delay, 0, 1))] exp((1 - t) ln lr_init + t ln lr_final)`
    /// with `t = clip(step / max_steps, 0, 1)`.
    #[must_use]
    pub fn lr(&self, step: u64) -> f32 {
        let delay_rate = if self.lr_delay_steps > 0 {
            let frac = (step as f64 / self.lr_delay_steps as f64).clamp(0.0, 1.0) as f32;
            self.lr_delay_mult + (1.0 - self.lr_delay_mult) * (0.5 * std::f32::consts::PI * frac).sin()
        } else {
            1.0
        };
        let t = (step as f64 / self.max_steps.max(1) as f64).clamp(0.0, 1.0) as f32;
        let log_lerp = ((1.0 - t) * self.lr_init.ln() + t * self.lr_final.ln()).exp();
        delay_rate * log_lerp
    }
}
