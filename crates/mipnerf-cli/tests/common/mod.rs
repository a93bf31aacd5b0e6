//! Helpers shared by the binary's test files: run it, and make small scenes.
#![allow(clippy::unwrap_used, missing_docs, dead_code)]

use std::process::Command;

/// Runs the binary with `args` and returns what it did.
pub fn mipnerf(args: &[&str]) -> std::process::Output {
    command().args(args).output().unwrap()
}

/// The binary as a new user on a clean machine has it: no LPIPS weights in the per-user cache
/// (it points to an empty folder) and none named by the environment.
pub fn command() -> Command {
    let empty_cache = std::env::temp_dir().join("mipnerf-tests-empty-cache");
    let mut c = Command::new(env!("CARGO_BIN_EXE_mipnerf"));
    c.env("XDG_RUNTIME_DIR", "/tmp").env("XDG_CACHE_HOME", empty_cache).env_remove("MIPNERF_LPIPS_WEIGHTS");
    c
}

/// The committed forward-facing fixture (`tests/data/llff_fern_tiny`: fern's photos at 1/64),
/// trained with `--llff-factor 64`.
pub fn fern_tiny() -> std::path::PathBuf {
    std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/llff_fern_tiny")
}

/// `train` of the fern fixture with the fast preset for `steps` steps into `dir/run`, and `extra`
/// flags; the run's folder and the command's output.
pub fn train_fern_fast(dir: &std::path::Path, steps: &str, extra: &[&str]) -> (std::path::PathBuf, String) {
    let (data, run) = (fern_tiny(), dir.join("run"));
    let (d, r) = (data.to_str().unwrap(), run.to_str().unwrap());
    let args = ["train", "--data", d, "--llff-factor", "64", "--out", r, "--preset", "fast", "--steps", steps];
    let text = run_ok(&[&args[..], extra].concat());
    (run, text)
}

/// A 16-pixel demo scene of `train_views` training views and one test view in `dir/data`.
pub fn small_demo_scene(dir: &std::path::Path, train_views: usize) -> std::path::PathBuf {
    demo_scene(dir, 16, train_views)
}

/// A `size`-pixel demo scene of `train_views` training views and one test view in `dir/data`.
pub fn demo_scene(dir: &std::path::Path, size: u32, train_views: usize) -> std::path::PathBuf {
    let data = dir.join("data");
    let cfg = mipnerf_data::demo::DemoConfig { size, train_views, test_views: 1, supersample: 1 };
    mipnerf_data::demo::write_demo_scene(&data, &cfg).unwrap();
    data
}

/// A demo run of a few steps on the CPU (one ray per pixel) in `dir/run`, its scene in `dir/data`.
pub fn trained_demo_run(dir: &std::path::Path) -> std::path::PathBuf {
    let data = small_demo_scene(dir, 4);
    let run = dir.join("run");
    let (d, r) = (data.to_str().unwrap(), run.to_str().unwrap());
    run_ok(&["train", "--data", d, "--out", r, "--steps", "10", "--backend", "cpu", "--quiet"]);
    run
}

/// Separates standard output from standard error in what [`run_ok`] returns.
pub const STDERR_FOLLOWS: &str = "\n--- stderr ---\n";

/// Runs the binary, asserts success, and returns its standard output, [`STDERR_FOLLOWS`] and its
/// standard error.
pub fn run_ok(args: &[&str]) -> String {
    let out = mipnerf(args);
    let text =
        String::from_utf8_lossy(&out.stdout).to_string() + STDERR_FOLLOWS + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "mipnerf {args:?} failed:\n{text}");
    text
}

/// Headless Chromium's command, for the tests that open a page in a real browser; `None` (and a
/// line saying that `what` was not checked) where none is installed. CI installs it
/// (`scripts/ensure-chromium.sh`), so there its absence fails the test.
pub fn chromium(what: &str) -> Option<&'static str> {
    let found = ["chromium", "chromium-browser", "google-chrome"]
        .into_iter()
        .find(|c| Command::new(c).arg("--version").output().is_ok_and(|o| o.status.success()));
    if found.is_none() {
        assert!(std::env::var("CI").is_err(), "CI installs Chromium (scripts/ensure-chromium.sh)");
        eprintln!("SKIPPED the browser check of {what}: no chromium (Debian: apt-get install chromium)");
    }
    found
}

/// Runs the binary, asserts that it fails with exit code 1 and without a panic, and returns its
/// standard output, [`STDERR_FOLLOWS`] and its standard error.
pub fn run_err(args: &[&str]) -> String {
    let out = mipnerf(args);
    let text =
        String::from_utf8_lossy(&out.stdout).to_string() + STDERR_FOLLOWS + &String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "mipnerf {args:?} should fail:\n{text}");
    assert!(!text.contains("panicked"), "{text}");
    text
}

/// Copies the folder `from` to `to`, recursively.
pub fn copy_dir(from: &std::path::Path, to: &std::path::Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let dest = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &dest);
        } else {
            std::fs::copy(e.path(), dest).unwrap();
        }
    }
}
