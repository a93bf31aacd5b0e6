//! Every long phase stops on Ctrl-C or SIGTERM with exit code 130, and leaves nothing that looks
//! complete and is not (a user kills a long phase and must trust what is left): eval, render, convert, demo (in training and after
//! it), and a second signal stops at once. Training's own signal handling (the checkpoint, the
//! byte-identical resume) is in `long_runs.rs`; the experiment's in `cli.rs`.
#![allow(clippy::unwrap_used, missing_docs)]

mod common;
use std::path::Path;
use std::process::{Child, Stdio};
use std::time::{Duration, Instant};

use common::*;

fn spawn(args: &[&str]) -> Child {
    command().args(args).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap()
}

/// Waits until `ready()` (the phase under test has begun), failing after two minutes or when the
/// child ends first.
fn wait_until(child: &mut Child, what: &str, ready: impl Fn() -> bool) {
    let t = Instant::now();
    while !ready() {
        if let Some(status) = child.try_wait().unwrap() {
            panic!("the command ended ({status}) before {what}");
        }
        assert!(t.elapsed() < Duration::from_secs(120), "{what} did not happen in two minutes");
        std::thread::sleep(Duration::from_millis(10));
    }
}

fn signal(child: &Child, sig: &str) {
    let ok = std::process::Command::new("kill").args([&format!("-{sig}"), &child.id().to_string()]).status().unwrap();
    assert!(ok.success());
}

/// How long a command may take to stop after a signal. It stops between images (or steps), so
/// this is one image's time: a second on a quiet 2-core machine. Ten seconds failed twice while an
/// LPIPS evaluation ran beside the test suite, so the bound leaves room for a busy machine.
const STOP_WITHIN_SECS: u64 = 30;

/// Exit code and standard error, failing if the child takes more than `secs` to end.
fn finish_within(mut child: Child, secs: u64) -> (Option<i32>, String) {
    let t = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if t.elapsed() > Duration::from_secs(secs) {
            child.kill().unwrap();
            panic!("the command did not stop within {secs} s of the signal");
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let out = child.wait_with_output().unwrap();
    (out.status.code(), String::from_utf8_lossy(&out.stderr).to_string())
}

fn pngs(dir: &Path) -> Vec<std::path::PathBuf> {
    std::fs::read_dir(dir).map_or_else(
        |_| Vec::new(),
        |d| d.map(|e| e.unwrap().path()).filter(|p| p.extension().is_some_and(|x| x == "png")).collect(),
    )
}

/// A trained run on a 128-pixel demo scene with 6 test views (24 test images over 4 scales), of
/// the tiny preset, so that eval and render take seconds (the small preset's eval took a minute
/// and a half here).
fn trained(dir: &Path) -> std::path::PathBuf {
    let data = dir.join("data");
    let cfg = mipnerf_data::demo::DemoConfig { size: 128, train_views: 2, test_views: 6, supersample: 1 };
    mipnerf_data::demo::write_demo_scene(&data, &cfg).unwrap();
    let run = dir.join("run");
    let (d, r) = (data.to_str().unwrap(), run.to_str().unwrap());
    run_ok(&[
        "train",
        "--data",
        d,
        "--out",
        r,
        "--steps",
        "2",
        "--batch-rays",
        "32",
        "--backend",
        "cpu",
        "--preset",
        "tiny",
    ]);
    run
}

#[test]
fn eval_and_render_stop_on_a_signal_and_leave_only_whole_outputs() {
    let dir = tempfile::tempdir().unwrap();
    let run = trained(dir.path());
    let r = run.to_str().unwrap();
    // A finished eval, then one interrupted part-way: the first stays exactly as it was, and the
    // unfinished one is in eval.partial/ without scores.
    run_ok(&["eval", "--run", r, "--backend", "cpu", "--no-lpips"]);
    let before = std::fs::read(run.join("eval/metrics.json")).unwrap();
    let mut child = spawn(&["eval", "--run", r, "--backend", "cpu", "--no-lpips"]);
    wait_until(&mut child, "eval wrote an image", || !pngs(&run.join("eval.partial")).is_empty());
    signal(&child, "INT");
    let (code, err) = finish_within(child, STOP_WITHIN_SECS);
    assert_eq!(code, Some(130), "{err}");
    assert!(err.contains("interrupted") && !err.contains("panicked"), "{err}");
    assert_eq!(std::fs::read(run.join("eval/metrics.json")).unwrap(), before);
    assert!(!run.join("eval.partial/metrics.json").exists());
    // render: stops between images (SIGTERM), says how many it wrote, and each file is whole.
    let out = dir.path().join("renders");
    let o = out.to_str().unwrap();
    let mut child =
        spawn(&["render", "--run", r, "--out", o, "--backend", "cpu", "--path", "orbit", "--frames", "200"]);
    wait_until(&mut child, "render wrote an image", || !pngs(&out).is_empty());
    signal(&child, "TERM");
    let (code, err) = finish_within(child, STOP_WITHIN_SECS);
    assert_eq!(code, Some(130), "{err}");
    assert!(err.contains("of 200 images rendered"), "{err}");
    assert!(!out.join("preview.gif").exists());
    // The video, written frame by frame under a temporary name, is gone with it.
    let names: Vec<String> =
        std::fs::read_dir(&out).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().to_string()).collect();
    assert!(!names.iter().any(|n| n.contains("video") || n.contains("partial")), "{names:?}");
    for p in pngs(&out) {
        image::open(&p).unwrap_or_else(|e| panic!("{} is not whole: {e}", p.display()));
    }
    // The same command again renders into its own folder.
    run_ok(&["render", "--run", r, "--out", o, "--backend", "cpu", "--path", "orbit", "--frames", "3"]);
    // A signal inside an image that takes minutes (16.7 million rays) stops it at once, not when
    // the image is done; the message says what is left.
    let big = dir.path().join("big");
    let b = big.to_str().unwrap();
    let args = ["render", "--run", r, "--out", b, "--backend", "cpu", "--path", "orbit", "--frames", "1"];
    let mut child = spawn(&[&args[..], &["--width", "4096", "--height", "4096"]].concat());
    wait_until(&mut child, "render drew its depth scale", || big.join("depth_scale.png").is_file());
    std::thread::sleep(std::time::Duration::from_millis(500));
    signal(&child, "TERM");
    let (code, err) = finish_within(child, STOP_WITHIN_SECS);
    assert_eq!(code, Some(130), "{err}");
    assert!(err.contains("0 of 1 images rendered") && !err.contains("panicked"), "{err}");
    assert!(!big.join("frame_0000.png").exists() && !big.join("video.mp4").exists());
}

#[test]
fn convert_stops_on_a_signal_without_leaving_a_dataset_that_looks_complete() {
    let lego = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/nerf_synthetic/lego");
    if !lego.is_dir() {
        eprintln!("SKIPPED convert_stops_on_a_signal...: {} is absent", lego.display());
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("lego64");
    // A dataset there before, converted over (--overwrite) and interrupted: the old dataset is
    // left as it was (its index and no image of the new one beside it), the new images only in
    // their temporary folder, so nothing reads a half-written folder as a dataset.
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("metadata.json"), "{}").unwrap();
    let args = ["convert", "--input", lego.to_str().unwrap(), "--output", out.to_str().unwrap(), "--size", "64"];
    let mut child = spawn(&[&args[..], &["--overwrite"]].concat());
    let partial = out.join(".mipnerf-partial-images_train");
    wait_until(&mut child, "convert wrote an image", || !pngs(&partial).is_empty());
    signal(&child, "INT");
    let (code, err) = finish_within(child, STOP_WITHIN_SECS);
    assert_eq!(code, Some(130), "{err}");
    assert_eq!(std::fs::read_to_string(out.join("metadata.json")).unwrap(), "{}", "the old index is kept");
    assert!(!out.join("images_train").exists(), "an interrupted convert moved half a split in");
}

#[test]
fn the_demo_stops_in_training_and_after_it_and_a_second_signal_stops_at_once() {
    let dir = tempfile::tempdir().unwrap();
    // In training: exit 130 (not 0), saying how to continue.
    let out = dir.path().join("demo");
    let o = out.to_str().unwrap();
    let args = ["demo", "--out", o, "--steps", "100000", "--size", "32", "--views", "4", "--backend", "cpu"];
    let mut child = spawn(&args);
    let csv = out.join("metrics.csv");
    wait_until(&mut child, "training started", || std::fs::read_to_string(&csv).is_ok_and(|s| s.lines().count() > 3));
    signal(&child, "INT");
    let (code, err) = finish_within(child, 60);
    assert_eq!(code, Some(130), "{err}");
    assert!(err.contains("run the same command again"), "{err}");
    // After training, in the evaluation: stops at once.
    let out = dir.path().join("demo2");
    let o = out.to_str().unwrap();
    let args = ["demo", "--out", o, "--steps", "2", "--size", "128", "--views", "10", "--backend", "cpu"];
    let mut child = spawn(&args);
    wait_until(&mut child, "the evaluation started", || !pngs(&out.join("eval.partial")).is_empty());
    signal(&child, "INT");
    let (code, err) = finish_within(child, STOP_WITHIN_SECS);
    assert_eq!(code, Some(130), "{err}");
    assert!(!out.join("nerf").join("checkpoint.safetensors").exists(), "the demo went on to train NeRF");
    // A second signal while the first is being acted on (a slow step of the paper preset) stops
    // at once, and the last checkpoint on disk is whole.
    let run = dir.path().join("slow");
    let data = out.join("data");
    let args = [
        "train",
        "--data",
        data.to_str().unwrap(),
        "--out",
        run.to_str().unwrap(),
        "--preset",
        "paper",
        "--batch-rays",
        "1024",
        "--steps",
        "1000",
        "--checkpoint-every",
        "1",
        "--log-every",
        "1",
        "--backend",
        "cpu",
    ];
    let mut child = spawn(&args);
    let csv = run.join("metrics.csv");
    wait_until(&mut child, "training started", || std::fs::read_to_string(&csv).is_ok_and(|s| s.lines().count() > 2));
    // The signals go in 300 ms after a checkpoint lands, so that they meet a step being computed
    // (over a second of the paper preset) and not the moment between a save and the check for a
    // stop, where the first one alone ends the run before the second arrives.
    let ckpt = run.join("checkpoint.safetensors");
    let saved_at = || std::fs::metadata(&ckpt).and_then(|m| m.modified()).ok();
    let before = saved_at();
    wait_until(&mut child, "a checkpoint was saved", || saved_at() != before);
    std::thread::sleep(Duration::from_millis(300));
    signal(&child, "INT");
    std::thread::sleep(Duration::from_millis(100));
    let t = Instant::now();
    signal(&child, "INT");
    let (code, err) = finish_within(child, 30);
    assert_eq!(code, Some(130), "{err}");
    assert!(err.contains("interrupted again"), "{err}");
    assert!(t.elapsed() < Duration::from_secs(2), "the second signal took {:?}", t.elapsed());
    let model = mipnerf_core::model::Model::new(mipnerf_core::model::Preset::Paper.config()).unwrap();
    mipnerf_core::checkpoint::load(&run.join("checkpoint.safetensors"), &model).unwrap();
}

/// What users hit when they stop a run, each shown.
#[test]
fn resume_with_nothing_to_do_convert_of_a_colmap_folder_and_help_defaults_say_what_to_do() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 2);
    let run = dir.path().join("run");
    let (d, r) = (data.to_str().unwrap(), run.to_str().unwrap());
    run_ok(&["train", "--data", d, "--out", r, "--steps", "3", "--batch-rays", "32", "--backend", "cpu"]);
    let text = run_ok(&["train", "--out", r, "--resume"]);
    assert!(text.contains("nothing to do") && text.contains("--steps 6"), "{text}");
    let text = run_ok(&["train", "--out", r, "--resume", "--steps", "3"]);
    assert!(text.contains("nothing to do"), "{text}");
    // convert of a COLMAP workspace without --to llff points to it.
    let colmap = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/colmap_lego");
    let out = dir.path().join("converted");
    let o = mipnerf(&["convert", "--input", colmap.to_str().unwrap(), "--output", out.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.code() == Some(1) && err.contains("COLMAP") && err.contains("--to llff"), "{err}");
    // Every help text shows each default once.
    for cmd in ["train", "eval", "render", "demo", "bench", "convert", "experiment", "figure", "compare"] {
        let help = run_ok(&[cmd, "--help"]);
        for line in help.lines() {
            assert!(line.matches("[default:").count() <= 1, "{cmd} --help repeats a default: {line}");
        }
        let defaults: Vec<&str> = help.split("[default:").skip(1).collect();
        let frames = defaults.iter().filter(|d| d.trim_start().starts_with("60]")).count();
        assert!(frames <= 1, "{cmd} --help shows [default: 60] {frames} times");
    }
}
