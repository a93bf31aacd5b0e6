//! Bad inputs are errors that name their cause, never panics or quiet reads: a render never replaces
//! a user's files, extreme numbers are errors or run (never a panic), nonsense cameras are
//! refused naming the file, field and index, `--resume` refuses flags that change the run,
//! explicitly given LPIPS weights and unverifiable checkpoints are not read quietly, memory is
//! checked before it is taken, and an experiment never reports another dataset's rows as done.
#![allow(clippy::unwrap_used, missing_docs)]

mod common;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use common::*;

/// Exit code and standard error of a run that must fail without panicking.
fn fails(args: &[&str]) -> (Option<i32>, String) {
    let out = mipnerf(args);
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(!out.status.success(), "mipnerf {args:?} should have failed:\n{err}");
    assert_no_panic(&out, args);
    (out.status.code(), err)
}

fn assert_no_panic(out: &std::process::Output, args: &[&str]) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.code() != Some(101) && out.status.code().is_some() && !err.contains("panicked"),
        "mipnerf {args:?} panicked or was killed ({:?}):\n{err}",
        out.status.code()
    );
}

/// Every file under `dir` with its bytes.
fn snapshot(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.extend(snapshot(&p));
        } else {
            out.insert(p.clone(), std::fs::read(&p).unwrap());
        }
    }
    out
}

/// Trains the tiny preset for `steps` steps of 32 rays on the CPU.
fn train(data: &Path, run: &Path, steps: &str) {
    run_ok(&[
        "train",
        "--data",
        data.to_str().unwrap(),
        "--out",
        run.to_str().unwrap(),
        "--steps",
        steps,
        "--batch-rays",
        "32",
        "--backend",
        "cpu",
    ]);
}

/// A copy of the multiscale scene `data` whose `metadata.json` has `split[key][index]` replaced
/// by `value` (every entry when `index` is `None`).
fn edited(data: &Path, to: &Path, key: &str, index: Option<usize>, value: &serde_json::Value) -> PathBuf {
    copy_dir(data, to);
    let path = to.join("metadata.json");
    let mut m: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    for split in ["train", "test"] {
        let list = m[split][key].as_array_mut().unwrap();
        match index {
            Some(i) => list[i] = value.clone(),
            None => list.iter_mut().for_each(|x| *x = value.clone()),
        }
    }
    std::fs::write(&path, serde_json::to_string(&m).unwrap()).unwrap();
    to.to_path_buf()
}

/// `render --out DATASET/images_test` once wrote over the ground truth.
#[test]
fn a_render_never_replaces_files_mipnerf_did_not_write() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 2);
    let run = dir.path().join("run");
    train(&data, &run, "2");
    let r = run.to_str().unwrap();
    let before = snapshot(&data);
    assert!(before.len() > 4);
    // Into the dataset's own folders: refused, naming a file and the way out; not a byte changed.
    let images = data.join("images_test");
    assert!(images.join("000_d0.png").is_file(), "the demo scene's layout changed");
    for out in [&images, &data] {
        let (code, err) = fails(&["render", "--run", r, "--out", out.to_str().unwrap(), "--backend", "cpu"]);
        assert_eq!(code, Some(1));
        assert!(err.contains("did not write") && err.contains("--overwrite"), "{err}");
    }
    assert!(snapshot(&data) == before, "a refused render changed the dataset");
    // A folder of its own is written, and written again (its manifest lists every file).
    let renders = dir.path().join("renders");
    let o = renders.to_str().unwrap();
    run_ok(&["render", "--run", r, "--out", o, "--backend", "cpu"]);
    run_ok(&["render", "--run", r, "--out", o, "--backend", "cpu"]);
    // A user's file put among them makes it theirs again.
    std::fs::write(renders.join("notes.txt"), b"mine").unwrap();
    let (_, err) = fails(&["render", "--run", r, "--out", o, "--backend", "cpu"]);
    assert!(err.contains("notes.txt"), "{err}");
    // --overwrite writes there anyway and keeps files of other names.
    run_ok(&["render", "--run", r, "--out", o, "--backend", "cpu", "--overwrite"]);
    assert_eq!(std::fs::read(renders.join("notes.txt")).unwrap(), b"mine");
    // figure: an existing file mipnerf did not write is refused; its own output is replaced.
    run_ok(&["eval", "--run", r, "--backend", "cpu", "--no-lpips"]);
    let photo = dir.path().join("photo.png");
    std::fs::write(&photo, b"a user's picture").unwrap();
    let (_, err) = fails(&["figure", "--run", r, "--out", photo.to_str().unwrap()]);
    assert!(err.contains("photo.png") && err.contains("--overwrite"), "{err}");
    assert_eq!(std::fs::read(&photo).unwrap(), b"a user's picture");
    let fig = dir.path().join("fig.png");
    run_ok(&["figure", "--run", r, "--out", fig.to_str().unwrap()]);
    run_ok(&["figure", "--run", r, "--out", fig.to_str().unwrap()]);
}

/// Extreme finite numbers once panicked (far >= 3e38) or were accepted (focal 0,
/// negative or 1e-30, cam2world entries of 1e20, lossmult 1e30); RAYON_NUM_THREADS=100000
/// panicked. Property: over extreme values of every numeric field, `train` either refuses with
/// an error naming metadata.json, the field and the entry, or trains, and then eval and render
/// run; nothing panics.
#[test]
fn extreme_numbers_in_the_data_are_errors_naming_the_field_or_run_and_never_panic() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 2);
    let pose = |s: f64, t: f64| serde_json::json!([[s, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, t]]);
    // (key, entry or every entry, value, must be refused)
    let cases: Vec<(&str, Option<usize>, serde_json::Value, bool)> = vec![
        ("far", None, serde_json::json!(3e38), true),
        ("far", None, serde_json::json!(f64::MAX), true),
        ("far", None, serde_json::json!(1e30), true),
        ("far", None, serde_json::json!(1e6), false),
        ("near", None, serde_json::json!(1e-30), false),
        ("near", Some(0), serde_json::json!(0.0), true),
        ("focal", Some(0), serde_json::json!(0.0), true),
        ("focal", Some(1), serde_json::json!(-5.0), true),
        ("focal", Some(0), serde_json::json!(1e-30), true),
        ("focal", Some(0), serde_json::json!(1e30), true),
        ("pix2cam", Some(0), serde_json::json!([[1e-30, 0.0, 0.0], [0.0, -1e-30, 0.0], [0.0, 0.0, -1.0]]), true),
        ("cam2world", Some(0), pose(1e20, 4.0), true),
        ("cam2world", Some(0), pose(1.0, 1e20), true),
        ("cam2world", Some(0), pose(1.0, 1e6), false),
        ("lossmult", Some(0), serde_json::json!(1e30), true),
        ("lossmult", None, serde_json::json!(1_048_576.0), false),
    ];
    for (n, (key, index, value, refused)) in cases.into_iter().enumerate() {
        let case = format!("{key}[{index:?}] = {value}");
        let bad = edited(&data, &dir.path().join(format!("d{n}")), key, index, &value);
        let run = dir.path().join(format!("r{n}"));
        let args = [
            "train",
            "--data",
            bad.to_str().unwrap(),
            "--out",
            run.to_str().unwrap(),
            "--steps",
            "1",
            "--batch-rays",
            "32",
            "--backend",
            "cpu",
        ];
        let out = mipnerf(&args);
        assert_no_panic(&out, &args);
        let err = String::from_utf8_lossy(&out.stderr);
        if refused {
            assert!(!out.status.success(), "{case}: accepted");
            assert!(err.contains("metadata.json") && err.contains("entry"), "{case}: {err}");
            assert!(err.contains(key) || (key == "pix2cam" && err.contains("field of view")), "{case}: {err}");
            continue;
        }
        // Accepted values at the edge of the ranges: training may stop on a non-finite loss (a
        // clear error, exit 1), but when it trains, eval and render run too.
        if !out.status.success() {
            assert!(err.contains("non-finite") || err.contains("NaN"), "{case}: {err}");
            continue;
        }
        let r = run.to_str().unwrap();
        for args in [
            vec!["eval", "--run", r, "--backend", "cpu", "--no-lpips"],
            vec!["render", "--run", r, "--out", &format!("{r}/renders"), "--backend", "cpu"],
        ] {
            let out = mipnerf(&args);
            assert_no_panic(&out, &args);
            assert!(out.status.success(), "{case}: {args:?}: {}", String::from_utf8_lossy(&out.stderr));
        }
    }
    // A Blender scene whose camera_angle_x is 1e-30.
    let blender = dir.path().join("blender");
    copy_dir(&PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/lego_tiny"), &blender);
    let t = blender.join("transforms_train.json");
    let mut m: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&t).unwrap()).unwrap();
    m["camera_angle_x"] = serde_json::json!(1e-30);
    std::fs::write(&t, m.to_string()).unwrap();
    let o = dir.path().join("rb");
    let (_, err) = fails(&["train", "--data", blender.to_str().unwrap(), "--out", o.to_str().unwrap(), "--steps", "1"]);
    assert!(err.contains("transforms_train.json") && err.contains("camera_angle_x"), "{err}");
    // A thread count far beyond the machine is capped with a message; a word is an error.
    let run = dir.path().join("threads");
    let out = command()
        .args(["train", "--data", data.to_str().unwrap(), "--out", run.to_str().unwrap(), "--steps", "1"])
        .args(["--batch-rays", "32", "--backend", "cpu"])
        .env("RAYON_NUM_THREADS", "100000")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success() && err.contains("RAYON_NUM_THREADS=100000") && err.contains("threads"), "{err}");
    let out = command().arg("info").env("RAYON_NUM_THREADS", "many").output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.code() == Some(1) && err.contains("RAYON_NUM_THREADS"), "{err}");
}

/// `--resume --model nerf` once continued a Mip-NeRF run as NeRF; `--resume --data OTHER`
/// resumed on other data.
#[test]
fn resume_refuses_flags_that_change_what_the_run_is() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 2);
    let other = small_demo_scene(&dir.path().join("elsewhere"), 3);
    let run = dir.path().join("run");
    train(&data, &run, "2");
    let r = run.to_str().unwrap();
    let ckpt = std::fs::read(run.join("checkpoint.safetensors")).unwrap();
    for (flag, value, says) in [
        ("--model", "nerf", "--model nerf"),
        ("--preset", "small", "--preset small"),
        ("--seed", "7", "--seed 7"),
        ("--num-samples", "8", "--num-samples 8"),
        ("--num-levels", "1", "--num-levels 1"),
        ("--data", other.to_str().unwrap(), "is not this run's dataset"),
    ] {
        let (code, err) = fails(&["train", "--out", r, "--resume", "--steps", "4", flag, value]);
        assert_eq!(code, Some(1));
        assert!(err.contains(says) && err.contains("start a new run") && err.contains("--steps"), "{flag}: {err}");
    }
    assert_eq!(std::fs::read(run.join("checkpoint.safetensors")).unwrap(), ckpt, "a refused resume wrote");
    // Flags that may change, and the same data named another way, resume.
    let same = format!("{}/../data", data.to_str().unwrap());
    let out = run_ok(&["train", "--out", r, "--resume", "--steps", "4", "--lr-init", "1e-3", "--data", &same]);
    assert!(out.contains("step 4"), "{out}");
    // train --help lists them.
    let help = run_ok(&["train", "--help"]);
    for flag in ["--steps", "--time-budget", "--batch-rays", "--lr-init", "--log-every", "--checkpoint-every"] {
        assert!(help.contains(flag), "{flag} missing from train --help");
    }
    assert!(help.contains("Flags that may change on resume"), "{help}");
}

/// Corrupt LPIPS weights given explicitly once gave `"lpips": null` and exit 0; a
/// checkpoint without its checksum was read with only a note.
#[test]
fn explicit_lpips_weights_that_do_not_work_and_unverifiable_checkpoints_are_errors() {
    use safetensors::tensor::{Dtype, TensorView};
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 2);
    let run = dir.path().join("run");
    train(&data, &run, "2");
    let r = run.to_str().unwrap();
    // A checkpoint without its checksum: refused by eval, render and resume unless
    // --allow-unverified.
    let path = run.join("checkpoint.safetensors");
    let bytes = std::fs::read(&path).unwrap();
    let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let (_, header) = safetensors::SafeTensors::read_metadata(&bytes).unwrap();
    let mut meta = header.metadata().clone().unwrap();
    assert!(meta.remove(mipnerf_core::checkpoint::CHECKSUM_KEY).is_some());
    let views: Vec<(String, TensorView<'_>)> = st
        .tensors()
        .into_iter()
        .map(|(name, t)| (name, TensorView::new(Dtype::F32, t.shape().to_vec(), t.data()).unwrap()))
        .collect();
    safetensors::serialize_to_file(views, Some(meta), &path).unwrap();
    let renders = dir.path().join("renders");
    for args in [
        vec!["eval", "--run", r, "--backend", "cpu", "--no-lpips"],
        vec!["render", "--run", r, "--out", renders.to_str().unwrap(), "--backend", "cpu"],
        vec!["train", "--out", r, "--resume", "--steps", "3"],
    ] {
        let (_, err) = fails(&args);
        assert!(err.contains("no checksum") && err.contains("--allow-unverified"), "{args:?}: {err}");
    }
    let out = run_ok(&["eval", "--run", r, "--backend", "cpu", "--no-lpips", "--allow-unverified"]);
    assert!(out.contains("unverified"), "{out}");
    // LPIPS weights that load but overflow, or whose linear layers are negative.
    let shared = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/models/lpips/alexnet.safetensors");
    if !shared.is_file() {
        eprintln!("SKIPPED the LPIPS half of this test: {} is absent", shared.display());
        return;
    }
    let bytes = std::fs::read(&shared).unwrap();
    let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    // A scene large enough for AlexNet (31 px a side) at its two finer scales.
    let big = dir.path().join("big");
    let cfg = mipnerf_data::demo::DemoConfig { size: 64, train_views: 2, test_views: 1, supersample: 1 };
    mipnerf_data::demo::write_demo_scene(&big.join("data"), &cfg).unwrap();
    let run64 = big.join("run");
    train(&big.join("data"), &run64, "2");
    for (name, edit) in [("huge", 1e30f32), ("negative", -1.0)] {
        let weights = dir.path().join(name);
        std::fs::create_dir_all(&weights).unwrap();
        let data: Vec<(String, Vec<u8>, Vec<usize>)> = st
            .tensors()
            .into_iter()
            .map(|(n, t)| {
                let mut v: Vec<f32> = t.data().chunks(4).map(|b| f32::from_le_bytes(b.try_into().unwrap())).collect();
                let hit = if edit > 0.0 {
                    n.contains("Conv_0/kernel") && !n.contains("NetLin")
                } else {
                    n.contains("NetLin")
                };
                if hit {
                    v.iter_mut().for_each(|x| *x *= edit);
                }
                (n, v.iter().flat_map(|x| x.to_le_bytes()).collect(), t.shape().to_vec())
            })
            .collect();
        let views: Vec<(String, TensorView<'_>)> =
            data.iter().map(|(n, b, s)| (n.clone(), TensorView::new(Dtype::F32, s.clone(), b).unwrap())).collect();
        safetensors::serialize_to_file(views, None, &weights.join("alexnet.safetensors")).unwrap();
        let golden = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../mipnerf-core/tests/data/lpips");
        let (a, b) = (golden.join("ref_64.png"), golden.join("blur_64.png"));
        let w = weights.to_str().unwrap();
        let (code, err) =
            fails(&["compare", a.to_str().unwrap(), b.to_str().unwrap(), "--net", "alex", "--lpips-weights", w]);
        assert!(code == Some(1) && err.contains("alexnet.safetensors"), "{name}: {err}");
        let (_, err) = fails(&[
            "eval",
            "--run",
            run64.to_str().unwrap(),
            "--backend",
            "cpu",
            "--net",
            "alex",
            "--lpips-weights",
            w,
        ]);
        assert!(err.contains("alexnet.safetensors"), "{name}: {err}");
    }
}

/// A batch or a metadata.json too large for a memory limit once aborted in the allocator
/// (exit 134); a failed write of metrics.json must keep the previous one.
#[test]
fn memory_is_checked_before_it_is_taken_and_a_failed_eval_keeps_the_previous_results() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 2);
    // Under a 400 MB address-space limit (the process itself maps under 150 MB).
    let limited = |args: &[&str]| {
        std::process::Command::new("bash")
            .arg("-c")
            .arg("ulimit -v 400000 && exec \"$0\" \"$@\"")
            .arg(env!("CARGO_BIN_EXE_mipnerf"))
            .args(args)
            .env("XDG_RUNTIME_DIR", "/tmp")
            .env_remove("MIPNERF_LPIPS_WEIGHTS")
            .output()
            .unwrap()
    };
    let run = dir.path().join("big-batch");
    let args = ["train", "--data", data.to_str().unwrap(), "--out", run.to_str().unwrap(), "--steps", "1"];
    let args = [&args[..], &["--batch-rays", "1000000", "--backend", "cpu"]].concat();
    let out = limited(&args);
    assert_no_panic(&out, &args);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.code() == Some(1) && err.contains("--batch-rays") && err.contains("ulimit -v"), "{err}");
    // 10^5 entries in metadata.json (47 MB): refused before parsing, naming the file.
    let big = dir.path().join("big");
    copy_dir(&data, &big);
    let path = big.join("metadata.json");
    let mut m: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    for list in m["train"].as_object_mut().unwrap().values_mut() {
        let first = list[0].clone();
        *list = serde_json::Value::Array(vec![first; 100_000]);
    }
    std::fs::write(&path, m.to_string()).unwrap();
    let run = dir.path().join("big-data");
    let args = ["train", "--data", big.to_str().unwrap(), "--out", run.to_str().unwrap(), "--steps", "1"];
    let out = limited(&args);
    assert_no_panic(&out, &args);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.code() == Some(1) && err.contains("metadata.json") && err.contains("memory"), "{err}");
    // eval whose results cannot be put in place (here a file where the previous results would be
    // moved aside; a full disk fails earlier, inside eval.partial/): the previous eval/ is kept
    // whole, and the error says so.
    let run = dir.path().join("run");
    train(&data, &run, "2");
    let r = run.to_str().unwrap();
    run_ok(&["eval", "--run", r, "--backend", "cpu", "--no-lpips"]);
    let before = snapshot(&run.join("eval"));
    std::fs::write(run.join("eval.old"), b"in the way").unwrap();
    let (_, err) = fails(&["eval", "--run", r, "--backend", "cpu", "--no-lpips"]);
    assert!(err.contains("previous results) is unchanged"), "{err}");
    assert!(snapshot(&run.join("eval")) == before, "the previous eval/ changed");
    std::fs::remove_file(run.join("eval.old")).unwrap();
    run_ok(&["eval", "--run", r, "--backend", "cpu", "--no-lpips"]);
    assert!(!run.join("eval.partial").exists() && !run.join("eval.old").exists());
}

/// `mipnerf experiment --data OTHER` once reported every row done from the old JSON.
#[test]
fn an_experiment_never_reports_rows_of_another_dataset_as_done() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 2);
    let other = small_demo_scene(&dir.path().join("other"), 3);
    let exp = dir.path().join("exp");
    std::fs::create_dir_all(&exp).unwrap();
    std::fs::write(
        exp.join("experiment.toml"),
        "title = \"t\"\ndata = \"demo 16 px\"\ndata_width = 16\nresults = \"results\"\ntable = \"RESULTS.md\"\n\
         rows = [\"a\"]\n[protocol]\npreset = \"tiny\"\nsteps = 3\nbatch_rays = 32\nbackend = \"cpu\"\n",
    )
    .unwrap();
    std::fs::write(exp.join("a.toml"), "label = \"A\"\n[settings]\n").unwrap();
    let out = dir.path().join("runs");
    let (e, o) = (exp.to_str().unwrap(), out.to_str().unwrap());
    run_ok(&["experiment", e, "--data", data.to_str().unwrap(), "--out", o, "--no-lpips"]);
    let json = std::fs::read(exp.join("results/a.json")).unwrap();
    let (code, err) = fails(&["experiment", e, "--data", other.to_str().unwrap(), "--out", o, "--no-lpips"]);
    assert_eq!(code, Some(1));
    assert!(err.contains("trained on") && err.contains("not on --data"), "{err}");
    assert_eq!(std::fs::read(exp.join("results/a.json")).unwrap(), json, "the row's JSON changed");
    // The same data again: done, from the same JSON.
    let text = run_ok(&["experiment", e, "--data", data.to_str().unwrap(), "--out", o, "--no-lpips"]);
    assert!(text.contains("done"), "{text}");
}
