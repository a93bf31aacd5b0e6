//! `train --field`: the hash grid trains, evaluates and renders on the CPU and is refused by name
//! on the GPU; the Tri-Mip field trains, is recorded with its planes' cube and recipe,
//! evaluates, renders and exports on the CPU, over NDC's cube on forward-facing photos and the
//! contracted space in an unbounded scene, and on the GPU backend; what it does not run (the
//! NeRF model) and settings out of range are refused by name; a Mip-NeRF run records no field.
#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

mod common;

use std::path::Path;

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
    // The field's recipe: 256² planes in levels down to 4 texels, the small MLP, the planes'
    // learning rate, all recorded.
    assert!(text.contains("field: tri-mip, planes 3 x 256^2 x 16 features in 7 levels over the cube"), "{text}");
    let config = std::fs::read_to_string(run.join("config.toml")).unwrap();
    for key in ["field = \"tri-mip\"", "tri_mip_bound = ", "tri_mip_resolution = 256", "tri_mip_lr_mult = 10"] {
        assert!(config.contains(key), "{key} in {config}");
    }
    // A scene seen from all round: no total variation (recorded only when on).
    assert!(!config.contains("tri_mip_tv"), "{config}");
    assert!(config.contains("tri_mip_mlp = [2, 64, 1, 64]"), "{config}");
    // The planes are a tensor of the checkpoint.
    let bytes = std::fs::read(run.join("checkpoint.safetensors")).unwrap();
    let tensors = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    assert_eq!(tensors.tensor("tri_mip/planes").unwrap().shape(), [3, 256, 256, 16]);
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
fn a_tri_mip_run_trains_on_the_gpu_and_evaluates_on_both_backends() {
    if mipnerf_gpu::test_support::context_or_skip("a_tri_mip_run_trains_on_the_gpu_and_evaluates_on_both_backends")
        .is_none()
    {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 2);
    let run = dir.path().join("gpu");
    let cfg = dir.path().join("small.toml");
    std::fs::write(&cfg, "tri_mip_resolution = 32\n").unwrap();
    let args = ["train", "--data", s(&data), "--out", s(&run), "--steps", "4", "--preset", "fast"];
    let text = run_ok(&[&args[..], &["--backend", "gpu", "--field", "tri-mip", "--config", s(&cfg)]].concat());
    assert!(text.contains("field: tri-mip, planes 3 x 32^2"), "{text}");
    // The same checkpoint evaluated on the device and on the CPU: the same images to rounding.
    let psnr = |backend: &str| -> f64 {
        run_ok(&["eval", "--run", s(&run), "--backend", backend]);
        let metrics: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(run.join("eval/metrics.json")).unwrap()).unwrap();
        metrics["per_scale"][0]["psnr"].as_f64().unwrap()
    };
    let (gpu, cpu) = (psnr("gpu"), psnr("cpu"));
    assert!((gpu - cpu).abs() < 0.01, "eval on the GPU {gpu} dB, on the CPU {cpu} dB");
    // And renders a camera path on the device.
    let frames = dir.path().join("frames");
    run_ok(&["render", "--run", s(&run), "--out", s(&frames), "--path", "orbit", "--frames", "2", "--backend", "gpu"]);
    image::open(frames.join("frame_0001.png")).unwrap();
}

#[test]
fn what_the_tri_mip_field_does_not_run_is_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 2);
    let out = |name: &str| dir.path().join(name);
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
    // The field's own settings: only with the field, and within range.
    let config = |name: &str, text: &str| {
        let path = out(&format!("{name}.toml"));
        std::fs::write(&path, text).unwrap();
        path
    };
    let train_with = |cfg: &Path, field: &[&str]| {
        let run = out("refused");
        let mut args = vec!["train", "--data", s(&data), "--out", s(&run), "--steps", "2", "--config", s(cfg)];
        args.extend_from_slice(field);
        run_err(&args)
    };
    let text = train_with(&config("without", "tri_mip_resolution = 64\n"), &[]);
    assert!(text.contains("`tri_mip_resolution` (a config-file key) sets the Tri-Mip field's planes"), "{text}");
    let text = train_with(&config("odd", "tri_mip_resolution = 100\n"), &["--field", "tri-mip"]);
    assert!(text.contains("`tri_mip_resolution` must be a power of two from 16 to 2048"), "{text}");
    let text = train_with(&config("mlp", "tri_mip_mlp = [2, 0, 1, 64]\n"), &["--field", "tri-mip"]);
    assert!(text.contains("`tri_mip_mlp` is [trunk depth, trunk width, colour depth, colour width]"), "{text}");
    let text = train_with(&config("lr", "tri_mip_lr_mult = -1.0\n"), &["--field", "tri-mip"]);
    assert!(text.contains("`tri_mip_lr_mult` must be a positive number"), "{text}");
    let text = train_with(&config("decay", "hash_grid_decay = 0.1\n"), &["--field", "tri-mip"]);
    assert!(text.contains("`hash_grid_decay` (a config-file key) sets the hash grid's weight decay"), "{text}");
    let text = train_with(&config("decay-neg", "hash_grid_decay = -1.0\n"), &["--field", "hash-grid"]);
    assert!(text.contains("`hash_grid_decay` must be a number from 0 (off) to 1000"), "{text}");
    let text = train_with(&config("eps", "grid_adam_eps = 0.0\n"), &["--field", "hash-grid"]);
    assert!(text.contains("`grid_adam_eps` must be a positive number"), "{text}");
    let text = train_with(&config("eps-mip", "grid_adam_eps = 1e-8\n"), &[]);
    assert!(text.contains("`grid_adam_eps` (a config-file key)"), "{text}");
    let text = train_with(&config("skip-mip", "grid_adam_skip_untouched = true\n"), &[]);
    assert!(text.contains("`grid_adam_skip_untouched` (a config-file key)"), "{text}");
    let text = train_with(&config("beta2", "adam_beta2 = 1.0\n"), &[]);
    assert!(text.contains("`adam_beta2` (a config-file key) must be a number between 0 and 1"), "{text}");
    let text = train_with(&config("l2", "mlp_l2 = -1e-6\n"), &[]);
    assert!(text.contains("`mlp_l2` (a config-file key) must be a number from 0 (off) to 1"), "{text}");
    let text = train_with(&config("c2f-mip", "coarse_to_fine_steps = 100\n"), &[]);
    assert!(text.contains("`coarse_to_fine_steps` (a config-file key) sets a grid field's"), "{text}");
    let text =
        train_with(&config("c2f-gpu", "coarse_to_fine_steps = 100\n"), &["--field", "tri-mip", "--backend", "gpu"]);
    assert!(text.contains("coarse_to_fine_steps runs on the CPU backend only"), "{text}");
    // The demo scene is an object on white: no density noise to fade.
    let text = train_with(&config("noise-steps-quiet", "density_noise_steps = 100\n"), &[]);
    assert!(
        text.contains("`density_noise_steps` (a config-file key) fades the density noise, which is 0 here"),
        "{text}"
    );
    assert!(!out("refused").exists(), "a refused run leaves no folder");
    // A Mip-NeRF run records no field: its configuration is what it was.
    let run = out("mip");
    run_ok(&["train", "--data", s(&data), "--out", s(&run), "--steps", "2", "--backend", "cpu"]);
    let config = std::fs::read_to_string(run.join("config.toml")).unwrap();
    assert!(!config.contains("field") && !config.contains("tri_mip") && !config.contains("adam_beta2"), "{config}");
}

#[test]
fn forward_facing_photos_train_the_planes_over_ndc_and_an_unbounded_scene_over_its_contraction() {
    let dir = tempfile::tempdir().unwrap();
    let out = |name: &str| dir.path().join(name);
    let fern = common::fern_tiny();
    let cfg = out("small.toml");
    std::fs::write(&cfg, "tri_mip_resolution = 32\n").unwrap();
    let train = |run: &Path, more: &[&str]| {
        let mut args = vec!["train", "--data", s(&fern), "--llff-factor", "64", "--out", s(run), "--steps", "3"];
        args.extend_from_slice(&["--preset", "fast", "--backend", "cpu", "--field", "tri-mip", "--config", s(&cfg)]);
        args.extend_from_slice(more);
        run_ok(&args)
    };
    let text = train(&out("fern"), &[]);
    // NDC space: the occupancy grid's cube, which holds every training ray's samples.
    let planes = text.lines().find(|l| l.starts_with("field: ")).unwrap();
    let grid = text.lines().find(|l| l.starts_with("occupancy: ")).unwrap();
    let cube = |line: &str| line[line.find('[').unwrap()..=line.find(']').unwrap()].to_owned();
    assert!(planes.contains("planes 3 x 32^2 x 16 features in 4 levels"), "{text}");
    assert_eq!(cube(planes), cube(grid), "{text}");
    assert!(grid.contains("in NDC space"), "{text}");
    // Forward-facing photos take the recipe's total variation of the planes, recorded.
    let config = std::fs::read_to_string(out("fern").join("config.toml")).unwrap();
    assert!(config.contains("tri_mip_tv = 0.1"), "{config}");
    let text = run_ok(&["eval", "--run", s(&out("fern")), "--backend", "cpu"]);
    assert!(text.contains("PSNR"), "{text}");
    let text = train(&out("unbounded"), &["--unbounded"]);
    assert!(text.contains("over the cube [-2.000, 2.000]^3"), "{text}");
    // The recipe's total variation for an unbounded scene, recorded.
    let config = std::fs::read_to_string(out("unbounded").join("config.toml")).unwrap();
    assert!(config.contains("tri_mip_tv = 1.0"), "{config}");
    let text = run_ok(&["eval", "--run", s(&out("unbounded")), "--backend", "cpu"]);
    assert!(text.contains("PSNR"), "{text}");
}

#[test]
fn bench_measures_the_tri_mip_field_beside_the_mlp() {
    let args = ["bench", "--backend", "both", "--batch-rays", "16", "--steps", "1", "--render-side", "8"];
    let text = run_ok(&[&args[..], &["--field", "mip-nerf,tri-mip"]].concat());
    let rows: Vec<&str> = text.lines().filter(|l| l.starts_with("| tiny, ")).collect();
    let cpu = |field: &str| rows.iter().find(|r| r.starts_with(&format!("| tiny, {field} (")) && r.contains("CPU"));
    for field in ["mip-nerf", "tri-mip"] {
        let row = cpu(field).unwrap_or_else(|| panic!("no CPU row of {field}: {text}"));
        let cells: Vec<&str> = row.split('|').map(str::trim).filter(|c| !c.is_empty()).collect();
        let numbers: Vec<f64> = cells[2..].iter().map(|c| c.parse().unwrap()).collect();
        assert!(numbers.len() == 3 && numbers.iter().all(|&x| x > 0.0), "{row}");
    }
    // The recipe's planes: 3 x 256² x 16 parameters besides the MLP.
    let params = |row: &str| -> usize { row.split(" (").nth(1).unwrap().split(' ').next().unwrap().parse().unwrap() };
    assert!(params(cpu("tri-mip").unwrap()) > 3 * 256 * 256 * 16, "{text}");
    // Where an adapter is (CI's lavapipe), a GPU row of each field with its dispatches a step.
    if rows.iter().any(|r| r.starts_with("| tiny, mip-nerf") && !r.contains("CPU")) {
        let gpu = rows.iter().find(|r| r.starts_with("| tiny, tri-mip") && !r.contains("CPU"));
        assert!(gpu.is_some(), "no GPU row of the Tri-Mip field: {text}");
        assert!(text.matches("device work of").count() >= 2, "{text}");
    }
}

#[test]
fn a_hash_grid_run_trains_evaluates_and_renders_on_the_cpu_and_the_gpu_refuses_it_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let data = small_demo_scene(dir.path(), 2);
    let run = dir.path().join("hash-grid");
    let args = ["train", "--data", s(&data), "--out", s(&run), "--steps", "20", "--field", "hash-grid"];
    let text = run_ok(&[&args[..], &["--backend", "cpu"]].concat());
    // The field's recipe: 16 levels from 16 to 512 cells, tables of 2^17, recorded with the cube.
    assert!(
        text.contains("field: hash-grid, 16 levels of 2 features from 16 to 512 cells a side (tables of 2^17)"),
        "{text}"
    );
    let config = std::fs::read_to_string(run.join("config.toml")).unwrap();
    for key in ["field = \"hash-grid\"", "tri_mip_bound = ", "tri_mip_lr_mult = 2", "tri_mip_mlp = [2, 64, 1, 64]"] {
        assert!(config.contains(key), "{key} in {config}");
    }
    // The planes' own settings are not the grid's; on a bounded scene its recipe has no weight
    // decay and the rate decays over the whole run (forward-facing photos: config's tests).
    for key in ["tri_mip_resolution", "tri_mip_tv", "hash_grid_decay", "lr_decay_steps", "adam_beta2"] {
        assert!(!config.contains(key), "{key} in {config}");
    }
    let bytes = std::fs::read(run.join("checkpoint.safetensors")).unwrap();
    let tensors = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let tables = mipnerf_core::model::HashGridRecipe::RECIPE.grid.num_params();
    assert_eq!(tensors.tensor("hash_grid/tables").unwrap().shape(), [tables / 2, 2]);
    let text = run_ok(&["eval", "--run", s(&run), "--backend", "cpu"]);
    assert!(text.contains("PSNR"), "{text}");
    let frames = dir.path().join("frames");
    run_ok(&["render", "--run", s(&run), "--out", s(&frames), "--path", "orbit", "--frames", "2", "--backend", "cpu"]);
    image::open(frames.join("frame_0001.png")).unwrap();
    // The grid's densities export as points, and the run resumes where it stopped.
    let ply = dir.path().join("points.ply");
    run_ok(&["export", "--run", s(&run), "--points", s(&ply), "--min-opacity", "0.000001"]);
    assert!(std::fs::read(&ply).unwrap().starts_with(b"ply"), "a PLY file");
    let text =
        run_ok(&["train", "--data", s(&data), "--out", s(&run), "--steps", "25", "--backend", "cpu", "--resume"]);
    assert!(text.contains("resuming from step 20"), "{text}");
    // The planes' settings are refused with the grid, by name.
    let cfg = dir.path().join("planes.toml");
    std::fs::write(&cfg, "tri_mip_resolution = 64\n").unwrap();
    let other = dir.path().join("refused");
    let text = run_err(&[
        "train",
        "--data",
        s(&data),
        "--out",
        s(&other),
        "--steps",
        "2",
        "--field",
        "hash-grid",
        "--config",
        s(&cfg),
    ]);
    assert!(text.contains("`tri_mip_resolution` (a config-file key) sets the Tri-Mip field's planes"), "{text}");
    // The GPU backend says it does not run the grid, where an adapter is to ask.
    if mipnerf_gpu::test_support::context_or_skip("the hash grid on the GPU").is_some() {
        let gpu = dir.path().join("gpu");
        let text = run_err(&[
            "train",
            "--data",
            s(&data),
            "--out",
            s(&gpu),
            "--steps",
            "2",
            "--field",
            "hash-grid",
            "--backend",
            "gpu",
        ]);
        assert!(text.contains("the hash-grid field runs on the CPU backend only (--backend cpu)"), "{text}");
    }
}
