//! Comparing numbers under a named tolerance: the one way every test in the workspace (GPU against
//! the CPU reference, the CPU against the official golden numbers, resumed runs against straight
//! ones) says "close enough", and reports every mismatch at once.
//!
//! ```
//! use mipnerf_core::compare::{Tolerance, assert_close};
//! /// Two summation orders of the same f32 sum: a few ulp of the result.
//! const TOL_SUM: Tolerance = Tolerance::new(0.0, 1e-6);
//! assert_close("sum", &[1.0, 2.000_000_2], &[1.0, 2.0], TOL_SUM);
//! ```

use std::fmt::Write as _;

/// How far `got` may be from `want`: `|got - want| <= abs + rel * |want|`. NaN in `got` never
/// passes; NaN in both passes (both paths agree that the value is undefined).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tolerance {
    /// Absolute part.
    pub abs: f32,
    /// Part relative to the expected value's magnitude.
    pub rel: f32,
}

impl Tolerance {
    /// Bit for bit: only identical values pass (`-0.0` and `0.0` differ).
    pub const EXACT: Self = Self { abs: 0.0, rel: 0.0 };

    /// `abs + rel * |want|`.
    #[must_use]
    pub const fn new(abs: f32, rel: f32) -> Self {
        Self { abs, rel }
    }

    /// Only an absolute bound.
    #[must_use]
    pub const fn abs(abs: f32) -> Self {
        Self { abs, rel: 0.0 }
    }

    /// Only a relative bound.
    #[must_use]
    pub const fn rel(rel: f32) -> Self {
        Self { abs: 0.0, rel }
    }

    /// Whether `got` is within this tolerance of `want`.
    #[must_use]
    pub fn accepts(&self, got: f32, want: f32) -> bool {
        if *self == Self::EXACT {
            return got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan());
        }
        if got.is_nan() || want.is_nan() {
            return got.is_nan() && want.is_nan();
        }
        // In f64, so that the difference and the bound are exact for any f32 inputs.
        let (g, w) = (f64::from(got), f64::from(want));
        got == want || (g - w).abs() <= f64::from(self.abs) + f64::from(self.rel) * w.abs()
    }
}

/// Every index where `got` is not within `tol` of `want`, as `what[i]: got G want W (off D)`.
///
/// # Panics
/// If the lengths differ.
#[must_use]
pub fn mismatches(what: &str, got: &[f32], want: &[f32], tol: Tolerance) -> Vec<String> {
    assert_eq!(got.len(), want.len(), "{what}: {} values, expected {}", got.len(), want.len());
    got.iter()
        .zip(want)
        .enumerate()
        .filter(|(_, (g, w))| !tol.accepts(**g, **w))
        .map(|(i, (g, w))| mismatch_line(what, i, *g, *w))
        .collect()
}

/// One mismatch as [`mismatches`] words it.
fn mismatch_line(what: &str, i: usize, got: f32, want: f32) -> String {
    format!("{what}[{i}]: got {got:e} want {want:e} (off {:e})", (got - want).abs())
}

/// A kernel's outputs, each named, in a fixed order: what both sides of [`check_kernel`] return.
pub type Outputs = Vec<(&'static str, Vec<f32>)>;

/// What [`check_kernel`] found: the largest difference of each output and every mismatch.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct KernelCheck {
    /// The check's label.
    pub label: String,
    /// Each output's largest `|gpu - cpu|` (infinite where the GPU wrote NaN and the CPU did not).
    pub max_abs_diff: Vec<(&'static str, f32)>,
    /// Every value out of tolerance, as [`mismatches`] words it, and any output missing on one
    /// side, of another length, or a kernel that failed.
    pub mismatches: Vec<String>,
    /// For [`check_kernel_conditioned`]: each output's count of values outside the tolerance
    /// that the reference's own spread under perturbed inputs admits.
    pub widened: Vec<(&'static str, usize)>,
    /// For [`check_kernel_conditioned`] with perturbed inputs: each output's largest widening
    /// (`factor` times the reference's largest move under them).
    pub max_spread: Vec<(&'static str, f32)>,
}

impl KernelCheck {
    /// One line: the label and each output's largest difference.
    #[must_use]
    pub fn summary(&self) -> String {
        let diffs: Vec<String> = self.max_abs_diff.iter().map(|(name, d)| format!("{name} {d:.1e}")).collect();
        let mut line = format!("{}: max |gpu - cpu|: {}", self.label, diffs.join(", "));
        if !self.max_spread.is_empty() {
            let spread: Vec<String> = self.max_spread.iter().map(|(name, d)| format!("{name} {d:.1e}")).collect();
            let _ = write!(line, "; widened by up to: {}", spread.join(", "));
        }
        let widened: Vec<String> =
            self.widened.iter().filter(|(_, n)| *n > 0).map(|(name, n)| format!("{name} {n}")).collect();
        if !widened.is_empty() {
            let _ =
                write!(line, " (within the reference's spread under perturbed inputs only: {})", widened.join(", "));
        }
        line
    }

    /// The mismatches, after printing [`summary`](Self::summary) to stderr (what a test collects
    /// over its cases and hands to [`assert_none`]).
    #[must_use]
    pub fn into_mismatches(self) -> Vec<String> {
        eprintln!("{}", self.summary());
        self.mismatches
    }
}

/// A GPU kernel against its CPU reference, the one check every kernel test uses: runs `cpu` and
/// `gpu` on the same `inputs` and compares each output the CPU names with the GPU's output of
/// that name under `tolerance(name)`.
///
/// Never panics on a disagreement: a failed kernel, an output the GPU lacks and a length that
/// differs are mismatches like any value out of tolerance, so a test reports everything at once.
pub fn check_kernel<I: ?Sized, E: std::fmt::Display>(
    label: &str,
    cpu: impl FnOnce(&I) -> Outputs,
    gpu: impl FnOnce(&I) -> Result<Outputs, E>,
    inputs: &I,
    tolerance: impl Fn(&str) -> Tolerance,
) -> KernelCheck {
    let want = cpu(inputs);
    compare_outputs(label, &want, gpu(inputs), None, tolerance)
}

/// [`check_kernel`] for outputs that are ill-conditioned in the kernel's inputs, on an adapter
/// whose arithmetic is not the CPU's operation for operation (a hardware GPU: multiply-adds fused
/// where its compiler likes, division and `sqrt` within the spec's few ulps). Such a GPU computes
/// the CPU's function of inputs a few roundings away from the given ones, so each value may be as
/// far from the CPU's as the CPU's own result moves under such changes: `cpu` runs again on each
/// of `perturbed` (the inputs moved by rounding-sized amounts), and each value's tolerance is
/// widened by `factor` times the largest move seen there. Where the reference is well
/// conditioned the check stays as strict as `tolerance`; where a value jumps with its inputs (a
/// walk deciding which cell a ray enters), a jump the perturbed inputs also make is admitted.
/// With no `perturbed` inputs this is [`check_kernel`]. The summary counts the values that only
/// the widened bound admits.
pub fn check_kernel_conditioned<I: ?Sized, P: std::borrow::Borrow<I>, E: std::fmt::Display>(
    label: &str,
    cpu: impl Fn(&I) -> Outputs,
    gpu: impl FnOnce(&I) -> Result<Outputs, E>,
    (inputs, perturbed, factor): (&I, &[P], f32),
    tolerance: impl Fn(&str) -> Tolerance,
) -> KernelCheck {
    let want = cpu(inputs);
    let mut spread: Vec<Vec<f32>> = want.iter().map(|(_, v)| vec![0.0; v.len()]).collect();
    for p in perturbed {
        let moved = cpu(p.borrow());
        for ((name, w), s) in want.iter().zip(&mut spread) {
            if let Some((_, m)) = moved.iter().find(|(n, m)| n == name && m.len() == w.len()) {
                for ((s, &m), &w) in s.iter_mut().zip(m).zip(w) {
                    // A NaN where the given inputs give a number widens nothing.
                    *s = s.max((m - w).abs() * factor);
                }
            }
        }
    }
    let mut check = compare_outputs(label, &want, gpu(inputs), Some(&spread), tolerance);
    if !perturbed.is_empty() {
        check.max_spread =
            want.iter().zip(&spread).map(|((name, _), s)| (*name, s.iter().copied().fold(0.0f32, f32::max))).collect();
    }
    check
}

/// The comparison of [`check_kernel`] and [`check_kernel_conditioned`]: `spread`, when given,
/// holds for each of `want`'s outputs how far each value may move beyond `tolerance`.
fn compare_outputs<E: std::fmt::Display>(
    label: &str,
    want: &Outputs,
    got: Result<Outputs, E>,
    spread: Option<&[Vec<f32>]>,
    tolerance: impl Fn(&str) -> Tolerance,
) -> KernelCheck {
    let mut check = KernelCheck { label: label.to_owned(), ..KernelCheck::default() };
    let got = match got {
        Ok(got) => got,
        Err(e) => {
            check.mismatches.push(format!("{label}: the kernel failed: {e}"));
            return check;
        }
    };
    for (k, (name, want)) in want.iter().enumerate() {
        let what = format!("{label} {name}");
        let Some((_, got)) = got.iter().find(|(n, _)| n == name) else {
            check.mismatches.push(format!("{what}: the kernel gave no such output"));
            continue;
        };
        if got.len() != want.len() {
            check.mismatches.push(format!("{what}: {} values, expected {}", got.len(), want.len()));
            continue;
        }
        let max = got
            .iter()
            .zip(want)
            .map(|(g, w)| {
                if g.is_nan() != w.is_nan() {
                    f32::INFINITY
                } else if g.is_nan() {
                    0.0
                } else {
                    (g - w).abs()
                }
            })
            .fold(0.0f32, f32::max);
        check.max_abs_diff.push((name, max));
        let tol = tolerance(name);
        let mut widened = 0;
        for (i, (&g, &w)) in got.iter().zip(want).enumerate() {
            if tol.accepts(g, w) {
                continue;
            }
            let allowed = spread.map_or(0.0, |s| s[k][i]);
            if !g.is_nan()
                && f64::from(g - w).abs()
                    <= f64::from(tol.abs) + f64::from(tol.rel) * f64::from(w).abs() + f64::from(allowed)
            {
                widened += 1;
            } else {
                check.mismatches.push(mismatch_line(&what, i, g, w));
            }
        }
        if spread.is_some() {
            check.widened.push((name, widened));
        }
    }
    check
}

/// Panics with every mismatch (the first 40 listed, and the count) when `bad` is not empty.
///
/// # Panics
/// When `bad` is not empty.
pub fn assert_none(bad: &[String]) {
    if bad.is_empty() {
        return;
    }
    let mut msg = format!("{} values out of tolerance:\n", bad.len());
    for line in bad.iter().take(40) {
        let _ = writeln!(msg, "{line}");
    }
    if bad.len() > 40 {
        let _ = writeln!(msg, "... and {} more", bad.len() - 40);
    }
    panic!("{msg}");
}

/// Asserts that `got` is within `tol` of `want` everywhere, naming every mismatch in one message.
///
/// # Panics
/// When the lengths differ or any value is out of tolerance.
#[track_caller]
pub fn assert_close(what: &str, got: &[f32], want: &[f32], tol: Tolerance) {
    assert_none(&mismatches(what, got, want, tol));
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_bound_is_abs_plus_rel_times_want_and_nan_never_passes_alone() {
        let t = Tolerance::new(1e-3, 1e-2);
        assert!(t.accepts(101.0, 100.0)); // 1 <= 1e-3 + 1
        assert!(!t.accepts(101.1, 100.0));
        assert!(t.accepts(0.0005, 0.0));
        assert!(!t.accepts(0.002, 0.0));
        assert!(!t.accepts(f32::NAN, 1.0));
        assert!(!t.accepts(1.0, f32::NAN));
        assert!(t.accepts(f32::NAN, f32::NAN));
        assert!(Tolerance::EXACT.accepts(1.5, 1.5));
        assert!(!Tolerance::EXACT.accepts(0.0, -0.0));
        assert!(!Tolerance::EXACT.accepts(1.0, 1.0 + f32::EPSILON));
        assert!(Tolerance::abs(f32::INFINITY).accepts(1e30, -1e30));
    }

    #[test]
    fn every_mismatch_is_reported_in_one_message() {
        let bad = mismatches("x", &[0.0, 5.0, 2.0, 9.0], &[0.0, 1.0, 2.0, 1.0], Tolerance::abs(0.5));
        assert_eq!(bad.len(), 2, "{bad:?}");
        assert!(bad[0].starts_with("x[1]: got 5e0 want 1e0") && bad[1].starts_with("x[3]:"), "{bad:?}");
        let r = std::panic::catch_unwind(|| assert_close("y", &[1.0, 7.0, 8.0], &[1.0, 1.0, 1.0], Tolerance::EXACT));
        let msg = r.unwrap_err().downcast::<String>().unwrap();
        assert!(msg.contains("2 values out of tolerance") && msg.contains("y[1]") && msg.contains("y[2]"), "{msg}");
    }

    #[test]
    fn a_conditioned_check_admits_only_what_the_reference_itself_does_under_perturbed_inputs() {
        // A step (a walk deciding a cell) and a smooth output; 0.5 sits on the step's edge.
        let cpu = |x: &[f32]| -> Outputs {
            vec![("step", x.iter().map(|v| v.floor()).collect()), ("smooth", x.iter().map(|v| 2.0 * v).collect())]
        };
        let tol = |_: &str| Tolerance::abs(1e-6);
        let inputs = [0.999_999_9f32, 2.5];
        let moved = [vec![1.000_000_1f32, 2.500_000_2], vec![0.999_999_8, 2.499_999_8]];
        // A GPU that steps the other way at the edge and rounds the smooth output a little.
        let gpu =
            |_: &[f32]| Ok::<_, String>(vec![("step", vec![1.0, 2.0]), ("smooth", vec![1.999_999_9, 5.000_000_5])]);
        let ok = check_kernel_conditioned("k", cpu, gpu, (&inputs[..], &moved[..], 2.0), tol);
        assert!(ok.mismatches.is_empty(), "{ok:?}");
        assert_eq!(ok.widened, [("step", 1), ("smooth", 0)]);
        assert!(
            ok.summary().contains("within the reference's spread under perturbed inputs only: step 1"),
            "{}",
            ok.summary()
        );
        // The same GPU with the step wrong where the reference does not jump, and the smooth
        // output off by far more than the reference moves: both caught.
        let bad = |_: &[f32]| Ok::<_, String>(vec![("step", vec![1.0, 3.0]), ("smooth", vec![1.999_999_9, 5.01])]);
        let caught = check_kernel_conditioned("k", cpu, bad, (&inputs[..], &moved[..], 2.0), tol);
        assert_eq!(caught.mismatches.len(), 2, "{caught:?}");
        assert!(caught.mismatches[0].starts_with("k step[1]") && caught.mismatches[1].starts_with("k smooth[1]"));
        // No perturbed inputs: as strict as check_kernel.
        let strict = check_kernel_conditioned("k", cpu, gpu, (&inputs[..], &[] as &[Vec<f32>], 2.0), tol);
        assert_eq!(strict.mismatches.len(), 1, "{strict:?}");
    }

    #[test]
    fn check_kernel_reports_values_missing_outputs_lengths_and_failures() {
        let cpu = |x: &[f32]| -> Outputs {
            vec![("doubled", x.iter().map(|v| 2.0 * v).collect()), ("sum", vec![x.iter().sum()])]
        };
        let tol = |name: &str| if name == "sum" { Tolerance::EXACT } else { Tolerance::abs(0.1) };
        let inputs = [1.0f32, 2.0, 3.0];
        // A kernel that agrees everywhere.
        let ok = check_kernel("k", cpu, |x: &[f32]| Ok::<_, String>(cpu(x)), &inputs[..], tol);
        assert!(ok.mismatches.is_empty() && ok.max_abs_diff == [("doubled", 0.0), ("sum", 0.0)], "{ok:?}");
        // One value off, NaN where the CPU has a number, and the second output missing.
        let off = check_kernel(
            "k",
            cpu,
            |_: &[f32]| Ok::<_, String>(vec![("doubled", vec![2.0, 4.5, f32::NAN])]),
            &inputs[..],
            tol,
        );
        assert_eq!(off.mismatches.len(), 3, "{off:?}");
        assert!(
            off.mismatches[0].starts_with("k doubled[1]") && off.mismatches[1].starts_with("k doubled[2]"),
            "{off:?}"
        );
        assert_eq!(off.mismatches[2], "k sum: the kernel gave no such output");
        assert_eq!(off.max_abs_diff, [("doubled", f32::INFINITY)]);
        // Another length, and a kernel that failed.
        let short = check_kernel(
            "k",
            cpu,
            |_: &[f32]| Ok::<_, String>(vec![("doubled", vec![2.0]), ("sum", vec![6.0])]),
            &inputs[..],
            tol,
        );
        assert_eq!(short.mismatches, ["k doubled: 1 values, expected 3"]);
        let failed = check_kernel("k", cpu, |_: &[f32]| Err::<Outputs, _>("device lost"), &inputs[..], tol);
        assert_eq!(failed.mismatches, ["k: the kernel failed: device lost"]);
        assert!(failed.summary().starts_with("k: max |gpu - cpu|"));
    }
}
