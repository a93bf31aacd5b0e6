//! What the workspace's tests share: the report of tests skipped for a CPU feature this machine
//! lacks. Behind the `test-support` feature (on for the workspace's tests); not for apps.
//!
//! A test that needs a CPU feature (AMX-BF16, AVX-512 BF16) calls [`skipped_for_cpu_feature`]
//! where the machine lacks it, and returns: the call prints one line naming the feature and, where
//! [`SKIP_LOG_ENV`] names a file, appends the line to it, so that `scripts/test.sh` ends with how
//! many tests were skipped and for which feature (cargo hides a passing test's output).

use std::io::Write;

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
