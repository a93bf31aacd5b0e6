//! Shared helpers for the core crate's tests: golden-file loading and tolerant comparison that
//! reports every mismatch at once.
#![allow(dead_code, clippy::unwrap_used, missing_docs)]

pub mod scene;

use serde_json::Value;
use std::path::PathBuf;

/// Element-wise functions (sin, exp, ...): XLA and libm differ by about 1 ulp.
pub const TOL_ELEMENTWISE: Tol = Tol { rel: 2e-6, abs: 2e-7 };
/// Functions that accumulate (sums, cumulative sums, CDF inversion).
pub const TOL_ACCUMULATED: Tol = Tol { rel: 1e-5, abs: 1e-6 };
/// Rays: ours are computed in f64 and rounded once, the official Blender loader in f32.
pub const TOL_RAYS: Tol = Tol { rel: 1e-6, abs: 1e-7 };

/// The workspace's one tolerance type (`|got - want| <= abs + rel |want|`).
pub use mipnerf_core::compare::Tolerance as Tol;

/// The central difference of `loss` in parameter `i` of `p` with step `h`, divided by the step
/// as `f32` actually took it (`p` is left as it was).
pub fn central_difference(loss: impl Fn(&[f32]) -> f64, p: &mut [f32], i: usize, h: f32) -> f64 {
    let x0 = p[i];
    p[i] = x0 + h;
    let up = loss(p);
    p[i] = x0 - h;
    let down = loss(p);
    p[i] = x0;
    (up - down) / (f64::from(x0 + h) - f64::from(x0 - h))
}

/// The default optimiser with a learning rate decaying from `lr_init` to `lr_final` over
/// `steps` steps, without warm-up.
pub fn optim_decaying(lr_init: f32, lr_final: f32, steps: u64) -> mipnerf_core::train::OptimConfig {
    mipnerf_core::train::OptimConfig {
        lr: mipnerf_core::schedule::LrSchedule {
            lr_init,
            lr_final,
            max_steps: steps,
            lr_delay_steps: 0,
            lr_delay_mult: 1.0,
        },
        ..mipnerf_core::train::OptimConfig::default()
    }
}

/// `steps` training steps of `trainer`, each on 256 rays drawn at random (from `seed`) from
/// `rays` and their `colours`; the losses, every one checked finite.
pub fn train_on_random_batches(
    trainer: &mut mipnerf_core::train::Trainer,
    rays: &[mipnerf_core::cone::Ray],
    colours: &[[f32; 3]],
    steps: usize,
    seed: u64,
) -> Vec<f32> {
    use rand::{Rng, SeedableRng};
    let mut rng = rand::rngs::SmallRng::seed_from_u64(seed);
    (0..steps)
        .map(|_| {
            let idx: Vec<usize> = (0..256).map(|_| rng.random_range(0..rays.len())).collect();
            let r: Vec<_> = idx.iter().map(|&i| rays[i]).collect();
            let c: Vec<_> = idx.iter().map(|&i| colours[i]).collect();
            let rep = trainer.train_step(&r, &c);
            assert!(rep.stats.loss.is_finite(), "step {}: loss {}", rep.step, rep.stats.loss);
            rep.stats.loss
        })
        .collect()
}

pub fn golden(name: &str) -> Value {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/golden").join(name);
    let s = std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
    serde_json::from_str(&s).unwrap()
}

/// A float from the golden encoding (numbers, or "NaN"/"Infinity"/"-Infinity"), as f32.
pub fn f(v: &Value) -> f32 {
    match v {
        Value::Number(n) => n.as_f64().unwrap() as f32,
        Value::String(s) if s == "NaN" => f32::NAN,
        Value::String(s) if s == "Infinity" => f32::INFINITY,
        Value::String(s) if s == "-Infinity" => f32::NEG_INFINITY,
        other => panic!("not a float: {other}"),
    }
}

/// All floats of a nested array, flattened in row-major order.
pub fn flat(v: &Value) -> Vec<f32> {
    match v {
        Value::Array(a) => a.iter().flat_map(flat).collect(),
        other => vec![f(other)],
    }
}

pub fn v3(v: &Value) -> glam::Vec3 {
    let x = flat(v);
    assert_eq!(x.len(), 3);
    glam::Vec3::new(x[0], x[1], x[2])
}

/// Collects mismatches so a test reports all of them in one message.
#[derive(Default)]
pub struct Mismatches {
    lines: Vec<String>,
    checked: usize,
}

impl Mismatches {
    pub fn check(&mut self, what: &str, got: &[f32], want: &[f32], tol: Tol) {
        if got.len() != want.len() {
            self.lines.push(format!("{what}: length {} != {}", got.len(), want.len()));
            return;
        }
        for (i, (&g, &w)) in got.iter().zip(want).enumerate() {
            self.checked += 1;
            let ok = tol.accepts(g, w);
            if !ok {
                self.lines.push(format!("{what}[{i}]: got {g:e}, want {w:e}, diff {:e}", g - w));
            }
        }
    }

    pub fn finish(self, test: &str) {
        assert!(self.checked > 0, "{test}: nothing was compared");
        assert!(
            self.lines.is_empty(),
            "{test}: {} of {} values differ:\n{}",
            self.lines.len(),
            self.checked,
            self.lines.join("\n")
        );
    }
}

/// Replaces, inserts, deletes or truncates bytes of `bytes` as `ops` say (each op: kind, position
/// as a fraction of the length, byte).
pub fn mutate(mut bytes: Vec<u8>, ops: &[(u8, f64, u8)]) -> Vec<u8> {
    for &(kind, at, b) in ops {
        let i = ((at * bytes.len() as f64) as usize).min(bytes.len().saturating_sub(1));
        match kind % 4 {
            0 if !bytes.is_empty() => bytes[i] = b,
            1 => bytes.insert(i, b),
            2 if !bytes.is_empty() => drop(bytes.remove(i)),
            _ => bytes.truncate(i),
        }
    }
    bytes
}

/// Cases of each fuzzing proptest: 48 in the suite, `PROPTEST_CASES` for a long run.
#[must_use]
pub fn fuzz_cases() -> u32 {
    std::env::var("PROPTEST_CASES").ok().and_then(|c| c.parse().ok()).unwrap_or(48)
}
