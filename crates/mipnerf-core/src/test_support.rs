//! What the workspace's tests share: the report of tests skipped for a CPU feature this machine
//! lacks, the official code's golden numbers, and byte mutations for fuzzing file readers. Behind the `test-support` feature (on for the workspace's tests); not for apps.
//!
//! A test that needs a CPU feature (AMX-BF16, AVX-512 BF16) calls [`skipped_for_cpu_feature`]
//! where the machine lacks it, and returns: the call prints one line naming the feature and, where
//! [`SKIP_LOG_ENV`] names a file, appends the line to it, so that `scripts/test.sh` ends with how
//! many tests were skipped and for which feature (cargo hides a passing test's output).

use std::io::Write;
use std::path::PathBuf;

use serde_json::Value;

use crate::compare::Tolerance;

/// The environment variable naming the file skipped tests append their line to.
pub const SKIP_LOG_ENV: &str = "MIPNERF_SKIP_LOG";

/// Says that `test` did not run its checks because this CPU lacks `feature` (as
/// `/proc/cpuinfo` spells it), and why: one line on standard error, and one line
/// `feature<TAB>test<TAB>why` appended to the file [`SKIP_LOG_ENV`] names.
///
/// # Panics
/// If the skip log is named but cannot be written: a skip that is not reported is silent.
pub fn skipped_for_cpu_feature(test: &str, feature: &str, why: &str) {
    eprintln!("SKIPPED {test}: needs the CPU feature {feature} ({why})");
    if let Some(path) = std::env::var_os(SKIP_LOG_ENV) {
        let path = std::path::Path::new(&path);
        if let Err(e) = append_skip(path, feature, test, why) {
            panic!("{test}: cannot report its skip to {} ({SKIP_LOG_ENV}): {e}", path.display());
        }
    }
}

/// Appends `feature<TAB>test<TAB>why` to the skip log (tabs and newlines in `why` become spaces).
fn append_skip(path: &std::path::Path, feature: &str, test: &str, why: &str) -> std::io::Result<()> {
    let line = format!("{feature}\t{test}\t{}\n", why.replace(['\t', '\n'], " "));
    std::fs::OpenOptions::new().create(true).append(true).open(path)?.write_all(line.as_bytes())
}

/// The golden file `name` (numbers the official JAX code produced, `crates/mipnerf-core/tests/data/golden/`), parsed.
///
/// # Panics
/// If the file is missing or not JSON.
#[must_use]
pub fn golden(name: &str) -> Value {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/golden").join(name);
    let s = std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
    serde_json::from_str(&s).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

/// A float from the golden encoding (numbers, or "NaN"/"Infinity"/"-Infinity"), as f32.
///
/// # Panics
/// If `v` is neither.
#[must_use]
pub fn f(v: &Value) -> f32 {
    match v {
        Value::Number(n) => n.as_f64().unwrap_or(f64::NAN) as f32,
        Value::String(s) if s == "NaN" => f32::NAN,
        Value::String(s) if s == "Infinity" => f32::INFINITY,
        Value::String(s) if s == "-Infinity" => f32::NEG_INFINITY,
        other => panic!("not a float: {other}"),
    }
}

/// All floats of a nested array, flattened in row-major order.
///
/// # Panics
/// As [`f`].
#[must_use]
pub fn flat(v: &Value) -> Vec<f32> {
    match v {
        Value::Array(a) => a.iter().flat_map(flat).collect(),
        other => vec![f(other)],
    }
}

/// Replaces, inserts, deletes or truncates bytes of `bytes` as `ops` say (each op: kind, position
/// as a fraction of the length, byte).
#[must_use]
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

/// Element-wise functions (sin, exp, ...): XLA and libm differ by about 1 ulp.
pub const TOL_ELEMENTWISE: Tolerance = Tolerance { rel: 2e-6, abs: 2e-7 };

/// Collects mismatches so a test reports all of them in one message.
#[derive(Default)]
pub struct Mismatches {
    lines: Vec<String>,
    checked: usize,
}

impl Mismatches {
    /// Records every element of `got` that `tol` does not accept against `want`.
    pub fn check(&mut self, what: &str, got: &[f32], want: &[f32], tol: Tolerance) {
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

    /// Fails with every recorded mismatch, or when nothing was compared.
    ///
    /// # Panics
    /// As said.
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn skips_are_appended_to_the_log_one_line_each() {
        let dir = std::env::temp_dir().join(format!("mipnerf-skip-log-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("{e}"));
        let log = dir.join("skips.tsv");
        append_skip(&log, "amx_bf16", "some_test", "no\ttabs\nhere").unwrap_or_else(|e| panic!("{e}"));
        append_skip(&log, "avx512_bf16", "other_test", "missing").unwrap_or_else(|e| panic!("{e}"));
        let text = std::fs::read_to_string(&log).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(text, "amx_bf16\tsome_test\tno tabs here\navx512_bf16\tother_test\tmissing\n");
        std::fs::remove_dir_all(&dir).ok();
    }
}
