//! What a long run can meet: signals, a diverging loss, a damaged checkpoint, a second process,
//! absurd sizes, bad numbers in the data, and the smaller traps. Each case asserts the error names
//! the cause, the exit code is non-zero, and the last good checkpoint is byte-for-byte intact.
#![allow(clippy::unwrap_used, missing_docs)]

mod common;
use std::path::Path;
use std::process::{Child, Command, Stdio};

use common::*;

/// `mipnerf train` on `data` into `run` with `extra` flags, on the CPU, 32 rays a step, a
/// metrics row every step.
fn train_args<'a>(data: &'a str, run: &'a str, steps: &'a str, extra: &[&'a str]) -> Vec<&'a str> {
    let mut v = vec!["train", "--data", data, "--out", run, "--steps", steps, "--batch-rays", "32", "--log-every", "1"];
    v.extend_from_slice(extra);
    v
}

fn spawn(args: &[&str]) -> Child {
    Command::new(env!("CARGO_BIN_EXE_mipnerf"))
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// Waits until `run/metrics.csv` has `rows` rows (training is under way).
fn wait_for_rows(run: &Path, rows: usize) {
    let csv = run.join("metrics.csv");
    let t = std::time::Instant::now();
    while std::fs::read_to_string(&csv).map_or(0, |s| s.lines().count()) < rows + 1 {
        assert!(t.elapsed().as_secs() < 300, "training did not start");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
}

fn signal(child: &Child, sig: &str) {
    assert!(Command::new("kill").args([&format!("-{sig}"), &child.id().to_string()]).status().unwrap().success());
}

/// Exit code and standard error of a finished child.
fn finish(child: Child) -> (Option<i32>, String) {
    let out = child.wait_with_output().unwrap();
    (out.status.code(), String::from_utf8_lossy(&out.stderr).to_string())
}

/// Exit code and standard error of a run of the binary.
fn fails(args: &[&str]) -> (Option<i32>, String) {
    let out = mipnerf(args);
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(!out.status.success(), "mipnerf {args:?} should have failed:\n{err}");
    assert!(!err.contains("panicked") && !err.contains("RUST_BACKTRACE"), "mipnerf {args:?} panicked:\n{err}");
    (out.status.code(), err)
}

fn ckpt(run: &Path) -> Vec<u8> {
    std::fs::read(run.join("checkpoint.safetensors")).unwrap()
}

fn tiny_model() -> mipnerf_core::model::Model {
    mipnerf_core::model::Model::new(mipnerf_core::model::Preset::Tiny.config()).unwrap()
}

#[test]
fn sigterm_sighup_and_ctrl_c_checkpoint_and_resuming_ends_byte_identical_to_an_uninterrupted_run() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 2);
    let d = data.to_str().unwrap();
    let steps = "200";
    let reference = dir.path().join("reference");
    run_ok(&train_args(d, reference.to_str().unwrap(), steps, &["--backend", "cpu"]));
    // An identical run gives an identical file.
    let again = dir.path().join("again");
    run_ok(&train_args(d, again.to_str().unwrap(), steps, &["--backend", "cpu"]));
    assert_eq!(ckpt(&reference), ckpt(&again), "two identical runs wrote different checkpoints");
    for sig in ["TERM", "HUP", "INT"] {
        let run = dir.path().join(format!("run-{sig}"));
        let r = run.to_str().unwrap();
        let child = spawn(&train_args(d, r, steps, &["--backend", "cpu"]));
        wait_for_rows(&run, 3);
        signal(&child, sig);
        let (code, err) = finish(child);
        assert_eq!(code, Some(130), "SIG{sig}: {err}");
        assert!(err.contains("interrupted at step") && err.contains("--resume"), "SIG{sig}: {err}");
        let stopped = mipnerf_core::checkpoint::load(&run.join("checkpoint.safetensors"), &tiny_model()).unwrap();
        assert!(stopped.step >= 3 && stopped.step < 200, "SIG{sig}: checkpoint at step {}", stopped.step);
        assert!(run.join("loss.png").is_file(), "SIG{sig}: no plots");
        let before: f64 = std::fs::read_to_string(run.join("train_seconds.txt")).unwrap().trim().parse().unwrap();
        run_ok(&["train", "--out", r, "--resume"]);
        // The training time adds up over the two segments.
        let after: f64 = std::fs::read_to_string(run.join("train_seconds.txt")).unwrap().trim().parse().unwrap();
        assert!(before > 0.0 && after > before, "SIG{sig}: train_seconds {before} then {after}");
        assert_eq!(ckpt(&run), ckpt(&reference), "SIG{sig} at step {}: the resumed run ends elsewhere", stopped.step);
    }
}

/// A learning rate that drives the state to infinity within a few steps.
const EXPLODE: [&str; 4] = ["--lr-init", "1e30", "--lr-final", "1e30"];

fn non_finite_state_keeps_the_last_good_checkpoint(backend: &str) {
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 2);
    let d = data.to_str().unwrap();
    let run = dir.path().join("run");
    let r = run.to_str().unwrap();
    run_ok(&train_args(d, r, "10", &["--checkpoint-every", "5", "--backend", backend]));
    let good = ckpt(&run);
    let mut args = vec!["train", "--out", r, "--resume", "--steps", "40", "--checkpoint-every", "5"];
    args.extend(EXPLODE);
    let (code, err) = fails(&args);
    assert_eq!(code, Some(1), "{err}");
    assert!(err.contains("non-finite") || err.contains("the loss became"), "{err}");
    assert!(err.contains("the checkpoint of step 10") && err.contains("is kept"), "{err}");
    assert_eq!(ckpt(&run), good, "the last good checkpoint was overwritten");
    // A fresh run that breaks before (or at) its first checkpoint exits non-zero and leaves no
    // non-finite file.
    let fresh = dir.path().join("fresh");
    let f = fresh.to_str().unwrap();
    // Losses are checked on logged steps only (every 10th here): the check before each save
    // is what stops this one.
    let mut args = vec!["train", "--data", d, "--out", f, "--steps", "11", "--batch-rays", "32"];
    args.extend(["--checkpoint-every", "1", "--log-every", "10", "--backend", backend]);
    args.extend(EXPLODE);
    let (code, err) = fails(&args);
    assert_eq!(code, Some(1), "{err}");
    assert!(err.contains("non-finite") || err.contains("the loss became"), "{err}");
    if fresh.join("checkpoint.safetensors").exists() {
        mipnerf_core::checkpoint::load(&fresh.join("checkpoint.safetensors"), &tiny_model()).unwrap();
    }
}

#[test]
fn a_non_finite_state_never_overwrites_the_last_good_checkpoint_cpu() {
    non_finite_state_keeps_the_last_good_checkpoint("cpu");
}

#[test]
fn a_non_finite_state_never_overwrites_the_last_good_checkpoint_gpu() {
    // The binary opens its own device; this only decides whether the machine has one (CI: always).
    if mipnerf_gpu::test_support::context_or_skip("a_non_finite_state_never_overwrites_the_last_good_checkpoint_gpu")
        .is_none()
    {
        return;
    }
    non_finite_state_keeps_the_last_good_checkpoint("gpu");
}

#[test]
fn a_damaged_checkpoint_is_refused_by_eval_render_and_resume() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 2);
    let run = dir.path().join("run");
    let r = run.to_str().unwrap();
    run_ok(&train_args(data.to_str().unwrap(), r, "5", &["--backend", "cpu"]));
    let mut bytes = ckpt(&run);
    let mid = bytes.len() - 4000;
    for b in &mut bytes[mid..mid + 16] {
        *b ^= 0x01;
    }
    std::fs::write(run.join("checkpoint.safetensors"), &bytes).unwrap();
    let render_out = dir.path().join("renders");
    for args in [
        &["eval", "--run", r, "--backend", "cpu"][..],
        &["render", "--run", r, "--out", render_out.to_str().unwrap(), "--backend", "cpu"][..],
        &["train", "--out", r, "--resume", "--steps", "10"][..],
    ] {
        let (code, err) = fails(args);
        assert_eq!(code, Some(1), "{args:?}: {err}");
        assert!(err.contains("checkpoint.safetensors") && err.contains("damaged"), "{args:?}: {err}");
    }
    assert_eq!(ckpt(&run), bytes, "a refused resume must not touch the file");
    assert!(!render_out.exists(), "render created its output before failing");
}

/// A run whose dataset has moved: eval, render, view and resume each say which folder is
/// missing and where the run names it, and write nothing.
#[test]
fn a_run_whose_dataset_moved_says_where_to_point_it() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 2);
    let run = dir.path().join("run");
    let r = run.to_str().unwrap();
    run_ok(&train_args(data.to_str().unwrap(), r, "3", &["--backend", "cpu"]));
    let moved = dir.path().join("moved");
    std::fs::rename(&data, &moved).unwrap();
    let render_out = dir.path().join("renders");
    for args in [
        &["eval", "--run", r, "--backend", "cpu", "--no-lpips"][..],
        &["render", "--run", r, "--out", render_out.to_str().unwrap(), "--backend", "cpu"][..],
        &["view", "--run", r, "--port", "0"][..],
        &["train", "--out", r, "--resume", "--steps", "6"][..],
    ] {
        let (code, err) = fails(args);
        assert_eq!(code, Some(1), "{args:?}: {err}");
        let missing = data.display().to_string();
        assert!(err.contains(&missing) && err.contains("no such dataset folder"), "{args:?}: {err}");
        assert!(err.contains("config.toml") && err.contains("`data`"), "{args:?}: says where to point it: {err}");
    }
    assert!(!render_out.exists() && !run.join("eval").exists(), "a refused command wrote output");
    // Pointed at the new place, the run evaluates again.
    let config = run.join("config.toml");
    let text = std::fs::read_to_string(&config).unwrap();
    std::fs::write(&config, text.replace(&data.display().to_string(), &moved.display().to_string())).unwrap();
    run_ok(&["eval", "--run", r, "--backend", "cpu", "--no-lpips"]);
}

/// A damaged record of the training time would have a resumed `--time-budget` run train its
/// whole budget again and overwrite the record: refused, naming the file, which is left as it
/// was. An absent record (a run from before it was written) still resumes from 0 s.
#[test]
fn a_damaged_training_time_is_refused_by_resume() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 2);
    let run = dir.path().join("run");
    let r = run.to_str().unwrap();
    run_ok(&train_args(data.to_str().unwrap(), r, "5", &["--backend", "cpu"]));
    let seconds = run.join("train_seconds.txt");
    for damaged in ["abc\n", "-3\n", "NaN\n", ""] {
        std::fs::write(&seconds, damaged).unwrap();
        for extra in [&["--steps", "10"][..], &["--time-budget", "1h"][..]] {
            let mut args = vec!["train", "--out", r, "--resume"];
            args.extend_from_slice(extra);
            let (code, err) = fails(&args);
            assert_eq!(code, Some(1), "{damaged:?} {extra:?}: {err}");
            assert!(err.contains("train_seconds.txt") && err.contains("damaged"), "{damaged:?}: {err}");
            assert_eq!(std::fs::read_to_string(&seconds).unwrap(), damaged, "the refused resume wrote the record");
        }
    }
    std::fs::remove_file(&seconds).unwrap();
    run_ok(&["train", "--out", r, "--resume", "--steps", "7"]);
    let after: f64 = std::fs::read_to_string(&seconds).unwrap().trim().parse().unwrap();
    assert!(after > 0.0, "{after}");
}

#[test]
fn two_trains_cannot_share_a_run_directory_and_a_killed_runs_lock_is_not_stale() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 2);
    let d = data.to_str().unwrap();
    let run = dir.path().join("run");
    let r = run.to_str().unwrap();
    let first = spawn(&train_args(d, r, "1000000", &["--checkpoint-every", "2", "--backend", "cpu"]));
    wait_for_rows(&run, 4);
    for args in [
        &["train", "--out", r, "--resume", "--steps", "2000000"][..],
        &["train", "--data", d, "--out", r, "--steps", "5"][..],
    ] {
        let (code, err) = fails(args);
        assert_eq!(code, Some(1), "{args:?}: {err}");
        assert!(err.contains("in use by another `mipnerf train`") && err.contains("process"), "{args:?}: {err}");
    }
    // Readers are not blocked: every file they read is replaced atomically.
    run_ok(&["eval", "--run", r, "--backend", "cpu"]);
    signal(&first, "KILL");
    let (code, _) = finish(first);
    assert_eq!(code, None, "killed by a signal");
    let ck = mipnerf_core::checkpoint::load(&run.join("checkpoint.safetensors"), &tiny_model()).unwrap();
    let text = run_ok(&["train", "--out", r, "--resume", "--steps", &(ck.step + 2).to_string()]);
    assert!(text.contains(&format!("resuming from step {}", ck.step)), "{text}");
}

#[test]
fn sizes_are_checked_before_anything_is_allocated() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 2);
    let d = data.to_str().unwrap();
    let run = dir.path().join("run");
    let r = run.to_str().unwrap();
    let flag_cases: &[(&[&str], &str)] = &[
        (&["--batch-rays", "4294967297"], "--batch-rays (`batch_rays` in a config file) must be between 1 and 4194304"),
        (&["--batch-rays", "4294967296"], "--batch-rays"),
        (&["--batch-rays", "1000000000000"], "GiB"),
        (&["--batch-rays", "0"], "--batch-rays"),
        (&["--steps", "0"], "--steps (`steps` in a config file) must be at least 1"),
        (&["--steps", "4294967296"], "--steps"),
        (&["--checkpoint-every", "0"], "--checkpoint-every"),
        (&["--log-every", "0"], "--log-every"),
        (&["--grad-max-norm", "NaN"], "--grad-max-norm"),
        (&["--grad-max-val=-1"], "--grad-max-val"),
        (&["--lr-delay-mult", "0"], "--lr-delay-mult"),
        (&["--num-levels", "0"], "--num-levels must be between 1 and 2, got 0"),
        (&["--num-levels", "3"], "--num-levels must be between 1 and 2, got 3"),
    ];
    for (flags, needle) in flag_cases {
        let mut args = vec!["train", "--data", d, "--out", r, "--backend", "cpu"];
        args.extend_from_slice(flags);
        let (code, err) = fails(&args);
        assert_eq!(code, Some(1), "{flags:?}: {err}");
        assert!(err.contains(needle), "{flags:?}: {err}");
        assert!(!run.join("checkpoint.safetensors").exists(), "{flags:?}: a checkpoint was written");
    }
    let file_cases = [
        ("batch_rays = 1000000000000", "--batch-rays"),
        ("grad_max_norm = nan", "--grad-max-norm"),
        ("steps = 0", "--steps"),
        ("checkpoint_every = 0", "--checkpoint-every"),
        ("num_levels = 3", "--num-levels"),
    ];
    for (line, needle) in file_cases {
        let cfg = dir.path().join("settings.toml");
        std::fs::write(&cfg, format!("{line}\n")).unwrap();
        let (code, err) = fails(&["train", "--data", d, "--out", r, "--config", cfg.to_str().unwrap()]);
        assert_eq!(code, Some(1), "{line}: {err}");
        assert!(err.contains(needle), "{line}: {err}");
    }
    // So is the benchmark.
    let (code, err) = fails(&["bench", "--backend", "cpu", "--batch-rays", "4294967297", "--steps", "1"]);
    assert_eq!(code, Some(1), "{err}");
    assert!(err.contains("--batch-rays must be between 1 and 4194304"), "{err}");
    // The GPU backend is guarded by the same check, before a device is opened.
    let (code, err) = fails(&["train", "--data", d, "--out", r, "--backend", "gpu", "--batch-rays", "4294967297"]);
    assert_eq!(code, Some(1), "{err}");
    assert!(err.contains("--batch-rays"), "{err}");
}

#[test]
fn bad_numbers_in_the_data_are_errors_naming_the_file_key_and_index() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 2);
    let d = data.to_str().unwrap();
    let run = dir.path().join("run");
    let r = run.to_str().unwrap();
    run_ok(&train_args(d, r, "3", &["--backend", "cpu"]));
    let meta = data.join("metadata.json");
    let mut v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&meta).unwrap()).unwrap();
    v["train"]["near"][1] = serde_json::json!(9.0);
    v["test"]["near"][2] = serde_json::json!(9.0);
    std::fs::write(&meta, v.to_string()).unwrap();
    for args in [
        &["train", "--out", r, "--resume", "--steps", "6"][..],
        &["eval", "--run", r, "--backend", "cpu"][..],
        &["render", "--run", r, "--out", dir.path().join("x").to_str().unwrap(), "--backend", "cpu"][..],
    ] {
        let (code, err) = fails(args);
        assert_eq!(code, Some(1), "{args:?}: {err}");
        assert!(err.contains("metadata.json") && err.contains("need 0 < near < far"), "{args:?}: {err}");
        assert!(err.contains("train entry 1") || err.contains("test entry 2"), "{args:?}: {err}");
    }
}

#[test]
fn the_smaller_traps() {
    let dir = tempfile::tempdir().unwrap();
    small_demo_scene(dir.path(), 2);
    // A dataset given relative to the working directory is stored absolute: eval, render and
    // --resume work from anywhere.
    let out = Command::new(env!("CARGO_BIN_EXE_mipnerf"))
        .current_dir(dir.path())
        .args(["train", "--data", "data", "--out", "run", "--steps", "4", "--batch-rays", "32", "--backend", "cpu"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let run = dir.path().join("run");
    let r = run.to_str().unwrap();
    let config = std::fs::read_to_string(run.join("config.toml")).unwrap();
    let data_abs = std::path::absolute(dir.path().join("data")).unwrap();
    assert!(config.contains(&format!("data = \"{}\"", data_abs.display())), "{config}");
    run_ok(&["eval", "--run", r, "--backend", "cpu"]);
    // --resume with --config is refused (the run keeps its own config.toml).
    let cfg = dir.path().join("more.toml");
    std::fs::write(&cfg, "steps = 8\n").unwrap();
    let (code, err) = fails(&["train", "--out", r, "--resume", "--config", cfg.to_str().unwrap()]);
    assert_eq!(code, Some(1), "{err}");
    assert!(err.contains("more.toml") && err.contains("--resume"), "{err}");
    // render checks its arguments before it creates anything.
    let render_out = dir.path().join("never");
    let (code, err) =
        fails(&["render", "--run", r, "--out", render_out.to_str().unwrap(), "--path", "orbit", "--frames", "0"]);
    assert_eq!(code, Some(1), "{err}");
    assert!(!render_out.exists(), "{err}");
    // A missing file's error is said once.
    let (_, err) = fails(&["train", "--data", "/nonexistent/scene", "--out", dir.path().join("r2").to_str().unwrap()]);
    assert_eq!(err.matches("os error 2").count(), 1, "{err}");
    // A temporary file that a kill during a save left behind is removed by the next run.
    std::fs::write(run.join("checkpoint.safetensors.tmp"), b"half a checkpoint").unwrap();
    run_ok(&["train", "--out", r, "--resume", "--steps", "6"]);
    assert!(!run.join("checkpoint.safetensors.tmp").exists());
    let names: Vec<String> =
        std::fs::read_dir(&run).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().to_string()).collect();
    assert!(names.iter().all(|n| !n.contains("tmp")), "{names:?}");
}
