//! `train --field`: the Tri-Mip field trains, is recorded with its planes' cube, evaluates,
//! renders and exports on the CPU; what it does not run yet (the GPU backend, the NeRF model,
//! forward-facing data in NDC) is refused by name; a Mip-NeRF run records no field.
#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

mod common;

use std::path::{Path, PathBuf};

use common::{run_err, run_ok, small_demo_scene};

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn a_tri_mip_run_trains_evaluates_renders_and_exports_on_the_cpu() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 4);
    let run = dir.path().join("tri-mip");
    let text = run_ok(&[
        "train",
        "--data",
        s(&data),
        "--out",
        s(&run),
        "--steps",
        "30",
        "--backend",
        "cpu",
        "--field",
        "tri-mip",
    ]);
    assert!(text.contains("field: tri-mip, planes 3 x 128^2 x 16 features in 6 levels over the cube"), "{text}");
    let config = std::fs::read_to_string(run.join("config.toml")).unwrap();
    assert!(config.contains("field = \"tri-mip\"") && config.contains("tri_mip_bound = "), "{config}");
    // The planes are a tensor of the checkpoint.
    let bytes = std::fs::read(run.join("checkpoint.safetensors")).unwrap();
    let tensors = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    assert_eq!(tensors.tensor("tri_mip/planes").unwrap().shape(), [3, 128, 128, 16]);
    // The saved run comes back as the same model: eval, render, export and --resume.
    let text = run_ok(&["eval", "--run", s(&run), "--backend", "cpu"]);
    assert!(text.contains("PSNR"), "{text}");
    let frames = dir.path().join("frames");
    run_ok(&["render", "--run", s(&run), "--out", s(&frames), "--path", "orbit", "--frames", "2", "--backend", "cpu"]);
    image::open(frames.join("frame_0001.png")).unwrap();
    run_ok(&["export", "--run", s(&run), "--points", s(&dir.path().join("points.ply")), "--min-opacity", "0.01"]);
    let text =
        run_ok(&["train", "--data", s(&data), "--out", s(&run), "--steps", "35", "--backend", "cpu", "--resume"]);
    assert!(text.contains("resuming from step 30"), "{text}");
}

#[test]
fn what_the_tri_mip_field_does_not_run_yet_is_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 2);
    let out = |name: &str| dir.path().join(name);
    let text = run_err(&[
        "train",
        "--data",
        s(&data),
        "--out",
        s(&out("gpu")),
        "--steps",
        "2",
        "--backend",
        "gpu",
        "--field",
        "tri-mip",
    ]);
    assert!(text.contains("the Tri-Mip field runs on the CPU backend only so far"), "{text}");
    assert!(!out("gpu").exists(), "a refused run leaves no folder");
    let text = run_err(&[
        "train",
        "--data",
        s(&data),
        "--out",
        s(&out("nerf")),
        "--steps",
        "2",
        "--model",
        "nerf",
        "--field",
        "tri-plane",
    ]);
    assert!(
        text.contains("--field tri-plane reads the planes into Mip-NeRF's model; leave out --model nerf"),
        "{text}"
    );
    let fern = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/llff_fern_tiny");
    let text = run_err(&[
        "train",
        "--data",
        s(&fern),
        "--llff-factor",
        "64",
        "--out",
        s(&out("fern")),
        "--steps",
        "2",
        "--backend",
        "cpu",
        "--field",
        "tri-mip",
    ]);
    assert!(text.contains("--field tri-mip: these forward-facing photos train in NDC space"), "{text}");
    // A Mip-NeRF run records no field: its configuration is what it was.
    let run = out("mip");
    run_ok(&["train", "--data", s(&data), "--out", s(&run), "--steps", "2", "--backend", "cpu"]);
    let config = std::fs::read_to_string(run.join("config.toml")).unwrap();
    assert!(!config.contains("field") && !config.contains("tri_mip"), "{config}");
}
