//! How much memory this process may still take, so that a dataset or a batch too large for it is
//! a clear error before loading or allocating, not an abort in the allocator.
//!
//! The limit is the smallest of what applies: the system's available memory (`MemAvailable` in
//! `/proc/meminfo`), the cgroup's (`memory.max` less `memory.current`, cgroup v2), and the
//! address-space limit (`ulimit -v`, less what the process has mapped). Where none can be read
//! (not Linux), nothing is refused.

use std::path::Path;

/// The memory this process may still allocate, in bytes, and where that figure comes from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Available {
    /// Bytes.
    pub bytes: u64,
    /// The limit that gives it (`MemAvailable`, `the cgroup's memory.max`, `ulimit -v`).
    pub source: &'static str,
}

fn read_kib(text: &str, key: &str) -> Option<u64> {
    let line = text.lines().find(|l| l.starts_with(key))?;
    line[key.len()..].split_whitespace().next()?.parse::<u64>().ok().map(|k| k * 1024)
}

fn cgroup_room() -> Option<u64> {
    // The process's cgroup (v2: one line "0::/path").
    let cg = std::fs::read_to_string("/proc/self/cgroup").ok()?;
    let rel = cg.lines().find_map(|l| l.strip_prefix("0::"))?;
    let dir = Path::new("/sys/fs/cgroup").join(rel.trim_start_matches('/'));
    let max: u64 = std::fs::read_to_string(dir.join("memory.max")).ok()?.trim().parse().ok()?;
    let current: u64 = std::fs::read_to_string(dir.join("memory.current")).ok()?.trim().parse().ok()?;
    Some(max.saturating_sub(current))
}

fn address_space_room() -> Option<u64> {
    let limits = std::fs::read_to_string("/proc/self/limits").ok()?;
    let line = limits.lines().find(|l| l.starts_with("Max address space"))?;
    let soft: u64 = line["Max address space".len()..].split_whitespace().next()?.parse().ok()?;
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let mapped = read_kib(&status, "VmSize:")?;
    Some(soft.saturating_sub(mapped))
}

/// The memory this process may still allocate (see the module docs); `None` where no limit can
/// be read.
#[must_use]
pub fn available() -> Option<Available> {
    let meminfo = std::fs::read_to_string("/proc/meminfo").ok();
    let candidates = [
        (meminfo.as_deref().and_then(|m| read_kib(m, "MemAvailable:")), "the system's available memory (MemAvailable)"),
        (cgroup_room(), "the cgroup's memory limit (memory.max)"),
        (address_space_room(), "the address-space limit (ulimit -v)"),
    ];
    candidates.into_iter().filter_map(|(b, source)| b.map(|bytes| Available { bytes, source })).min_by_key(|a| a.bytes)
}

/// Bytes in GiB, for messages.
#[must_use]
pub fn gib(bytes: u64) -> f64 {
    bytes as f64 / f64::from(1u32 << 30)
}

/// `Err(message)` when `need` bytes for `what` exceed what this process may still allocate;
/// the message says both figures and the limit that applies.
///
/// # Errors
/// The message, for the caller to wrap with the file or flag to blame.
pub fn check(need: u64, what: &str) -> Result<(), String> {
    match available() {
        Some(a) if need > a.bytes => Err(format!(
            "{what} may need up to {:.2} GiB of memory, but this process can take only about {:.2} GiB more ({})",
            gib(need),
            gib(a.bytes),
            a.source
        )),
        _ => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn the_limit_is_read_here_and_an_absurd_need_is_refused_with_both_figures() {
        // This project builds and tests on Linux, where /proc/meminfo always exists.
        let a = available().unwrap();
        assert!(a.bytes > 0, "{a:?}");
        check(1 << 20, "a mebibyte").unwrap();
        let e = check(u64::MAX / 2, "the test's allocation").unwrap_err();
        assert!(e.contains("the test's allocation") && e.contains("GiB"), "{e}");
        assert_eq!(read_kib("MemAvailable:   1024 kB\n", "MemAvailable:"), Some(1 << 20));
    }
}
