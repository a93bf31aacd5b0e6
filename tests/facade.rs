//! The facade's small API (`Nerf`, `Options`, `Device`): what an embedder writes, on the CPU (and
//! the same calls on whatever `Device::Auto` finds), and the CPU-only build without the `gpu`
//! feature.
#![allow(clippy::unwrap_used, missing_docs)]

use std::path::{Path, PathBuf};

use mipnerf::{Camera, Device, Error, Nerf, Options, Preset, demo};

fn cpu_tiny() -> Options {
    Options { device: Device::Cpu, batch_rays: 64, ..Options::preset(Preset::Tiny) }
}

fn novel_camera() -> Camera {
    Camera::from_camera_angle_x(12, 8, 0.69, demo::camera_pose(1.0, 0.4)).unwrap()
}

fn lego_tiny() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/lego_tiny")
}

/// Trains, renders, saves; the loaded model renders the same picture bit for bit and trains on
/// from the saved step when given the data again.
#[test]
fn a_nerf_trains_renders_saves_and_loads_as_it_was() {
    let mut nerf = Nerf::new(demo::dataset(3, 12).unwrap(), cpu_tiny()).unwrap();
    assert!(nerf.fallback().is_none(), "Device::Cpu falls back from nothing");
    let report = nerf.train(4).unwrap();
    assert_eq!((report.step, nerf.step()), (3, 4));
    assert!(report.stats.loss.is_finite() && report.stats.loss > 0.0);
    let before = nerf.render(&novel_camera()).unwrap();
    assert_eq!((before.width, before.height, before.fine.len()), (12, 8, 96));
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("nerf.safetensors");
    nerf.save(&path).unwrap();
    // For rendering only: the demo's bounds are the default render bounds (2 to 6).
    let mut loaded = Nerf::load(&path, cpu_tiny(), None).unwrap();
    assert_eq!(loaded.step(), 4);
    assert_eq!(loaded.render(&novel_camera()).unwrap(), before);
    assert!(matches!(loaded.train(1), Err(Error::NoData)));
    // No steps asked for is an error, not one step taken.
    let err = nerf.train(0).unwrap_err();
    assert!(matches!(err, Error::Options(_)) && err.to_string().contains("train(0)"), "{err}");
    assert_eq!(nerf.step(), 4, "train(0) took no step");
    // With data: it trains on from step 4, as the original does.
    let mut resumed = Nerf::load(&path, cpu_tiny(), Some(demo::dataset(3, 12).unwrap())).unwrap();
    assert_eq!(resumed.train(1).unwrap().stats, nerf.train(1).unwrap().stats);
}

/// A dataset folder: the training split of the committed lego subset trains a step; a folder
/// that is none is an error naming it.
#[test]
fn a_dataset_folder_trains_and_a_missing_one_is_named() {
    let mut nerf = Nerf::from_dir(lego_tiny(), cpu_tiny()).unwrap();
    assert!(nerf.train(1).unwrap().stats.loss.is_finite());
    let missing = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/no_such_scene");
    let err = Nerf::from_dir(&missing, cpu_tiny()).unwrap_err();
    assert!(matches!(err, Error::Data(_)) && err.to_string().contains("no_such_scene"), "{err}");
}

/// A time budget takes at least one step and stops soon after the budget.
#[test]
fn training_for_a_budget_takes_steps_until_it_is_spent() {
    let mut nerf = Nerf::new(demo::dataset(2, 8).unwrap(), cpu_tiny()).unwrap();
    let report = nerf.train_for(std::time::Duration::from_millis(200)).unwrap();
    assert!(nerf.step() >= 1 && report.step + 1 == nerf.step(), "{} steps, last {}", nerf.step(), report.step);
}

/// The fast preset guides sampling with an occupancy grid carved from the images' alpha (the
/// demo's empty space is not full), saved with the parameters.
#[test]
fn the_fast_preset_trains_with_an_occupancy_grid() {
    let options = Options { device: Device::Cpu, batch_rays: 256, ..Options::preset(Preset::Fast) };
    assert!(options.occupancy);
    let mut nerf = Nerf::new(demo::dataset(6, 16).unwrap(), options).unwrap();
    nerf.train(2).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("fast.safetensors");
    nerf.save(&path).unwrap();
    let ck = mipnerf::mipnerf_core::checkpoint::load(&path, nerf.backend().model()).unwrap();
    let grid = ck.occupancy.expect("the grid is saved with the parameters");
    assert!(!grid.is_full(), "the carved grid leaves empty space");
}

/// Without the `gpu` feature: `Device::Gpu` is a clear error, `Device::Auto` runs on the CPU
/// and says why.
#[cfg(not(feature = "gpu"))]
#[test]
fn without_the_gpu_feature_auto_is_the_cpu_and_gpu_an_error() {
    let data = || demo::dataset(2, 8).unwrap();
    let err = Nerf::new(data(), Options { device: Device::Gpu, ..cpu_tiny() }).unwrap_err();
    assert!(matches!(err, Error::NoGpuBackend) && err.to_string().contains("`gpu` feature is off"), "{err}");
    let mut auto = Nerf::new(data(), Options { device: Device::Auto, ..cpu_tiny() }).unwrap();
    assert!(auto.fallback().unwrap().contains("no GPU backend"), "{:?}", auto.fallback());
    assert!(auto.train(1).unwrap().stats.loss.is_finite());
}

/// The packages a build of the facade compiles (normal dependencies), from `cargo tree`.
fn normal_dependencies(features: &[&str]) -> Vec<String> {
    let out = std::process::Command::new(env!("CARGO"))
        .args(["tree", "-p", "mipnerf", "-e", "normal", "--prefix", "none", "--format", "{p}", "--offline"])
        .args(features)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    assert!(out.status.success(), "cargo tree: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout).unwrap().lines().map(|l| l.split(' ').next().unwrap_or("").to_owned()).collect()
}

/// A CPU-only embedder (`default-features = false`) compiles neither the GPU crate nor wgpu or
/// naga; the default build has them.
#[test]
fn a_cpu_only_build_compiles_nothing_of_wgpu() {
    let gpu_crates = ["mipnerf-gpu", "wgpu", "wgpu-core", "wgpu-hal", "naga"];
    let cpu_only = normal_dependencies(&["--no-default-features"]);
    assert!(cpu_only.iter().any(|p| p == "mipnerf-core"), "{cpu_only:?}");
    let found: Vec<&String> = cpu_only.iter().filter(|p| gpu_crates.contains(&p.as_str())).collect();
    assert!(found.is_empty(), "a CPU-only build compiles {found:?}");
    let default = normal_dependencies(&[]);
    for c in ["mipnerf-gpu", "wgpu"] {
        assert!(default.iter().any(|p| p == c), "the default build lacks {c}");
    }
}

/// The library guide's example (`docs/guide/library.md`) is the crate's doctest, line for line
/// (the doctest's hidden `# ` lines aside), so the guide shows code the test command runs.
#[test]
fn the_readme_example_is_the_doctest() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let readme = std::fs::read_to_string(root.join("docs/guide/library.md")).unwrap();
    let section = readme.split("# Use it as a library").nth(1).expect("the guide's library section");
    let readme_block: Vec<&str> =
        section.split("```rust\n").nth(1).unwrap().split("\n```").next().unwrap().lines().collect();
    let lib = std::fs::read_to_string(root.join("src/lib.rs")).unwrap();
    let doc: Vec<&str> =
        lib.lines().filter_map(|l| l.strip_prefix("//!")).map(|l| l.strip_prefix(' ').unwrap_or(l)).collect();
    let start = doc.iter().position(|l| *l == "```").unwrap() + 1;
    let len = doc[start..].iter().position(|l| *l == "```").unwrap();
    let doctest: Vec<&str> =
        doc[start..start + len].iter().copied().filter(|l| !l.starts_with("# ") && *l != "#").collect();
    assert_eq!(readme_block, doctest, "docs/guide/library.md's example differs from src/lib.rs's doctest");
    assert!(doctest.len() > 10, "{doctest:?}");
}

/// Options no run can use are errors naming the option, before anything is opened.
#[test]
fn options_out_of_range_are_errors_naming_the_option() {
    let data = || demo::dataset(2, 8).unwrap();
    for (options, words) in [
        (Options { batch_rays: 0, ..cpu_tiny() }, "`Options::batch_rays` must be between 1 and"),
        (Options { batch_rays: mipnerf::MAX_BATCH_RAYS + 1, ..cpu_tiny() }, "`Options::batch_rays`"),
        (Options { render_bounds: (6.0, 2.0), ..cpu_tiny() }, "`Options::render_bounds`"),
        (Options { render_bounds: (f32::NAN, 2.0), ..cpu_tiny() }, "`Options::render_bounds`"),
    ] {
        let err = Nerf::new(data(), options).unwrap_err();
        assert!(matches!(err, Error::Options(_)) && err.to_string().contains(words), "{err}");
    }
}

/// A COLMAP capture (forward-facing, in NDC) trains with the official LLFF settings the data
/// implies: cylinders, no white background; occupancy-guided sampling runs on it with its grid
/// over the NDC cube.
#[test]
fn forward_facing_data_trains_with_cylinders_and_occupancy_in_ndc() {
    let colmap = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/colmap_lego");
    let mut nerf = Nerf::from_dir(&colmap, cpu_tiny()).unwrap();
    let config = nerf.backend().model().config().clone();
    assert_eq!((config.ray_shape, config.white_bkgd), (mipnerf::mipnerf_core::RayShape::Cylinder, false));
    assert!(nerf.train(1).unwrap().stats.loss.is_finite());
    let mut guided = Nerf::from_dir(&colmap, Options { occupancy: true, ..cpu_tiny() }).unwrap();
    assert!(guided.train(1).unwrap().stats.loss.is_finite());
    let grid = guided.backend().checkpoint().unwrap().occupancy.expect("the run keeps its grid");
    let data =
        mipnerf::mipnerf_core::data::load(&colmap, mipnerf::mipnerf_core::data::Split::Train, &Default::default());
    let bound = data.ok().and_then(|d| mipnerf::mipnerf_core::occupancy::ndc_bound(&d));
    assert_eq!(Some(grid.config.bound), bound, "the grid covers the NDC cube");
}

/// A model saved by `Nerf::save` and loaded without its data renders as before: the checkpoint
/// holds its configuration (background, ray shape) and how its pixels become rays (bounds, pixel
/// centres, NDC), for forward-facing COLMAP data and for Blender data, whatever `Options` the
/// loader passes.
#[test]
fn a_saved_model_loaded_without_data_renders_as_before_on_any_data() {
    let colmap = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/colmap_lego");
    let dir = tempfile::tempdir().unwrap();
    for (name, data) in [("colmap", colmap), ("blender", lego_tiny())] {
        let mut nerf = Nerf::from_dir(&data, cpu_tiny()).unwrap();
        nerf.train(2).unwrap();
        let camera = {
            let ds = mipnerf::mipnerf_core::data::load(
                &data,
                mipnerf::mipnerf_core::data::Split::Train,
                &Default::default(),
            )
            .unwrap();
            let c = ds.views()[0].camera.clone();
            Camera::from_camera_angle_x(16, 12, 0.8, c.cam2world).unwrap()
        };
        let before = nerf.render(&camera).unwrap();
        let path = dir.path().join(format!("{name}.safetensors"));
        nerf.save(&path).unwrap();
        // Loaded with the default options (another model size, the default bounds): the stored
        // settings win.
        let options = Options { device: Device::Cpu, ..Options::preset(Preset::Small) };
        let mut loaded = Nerf::load(&path, options, None).unwrap();
        assert_eq!(loaded.backend().model().config(), nerf.backend().model().config(), "{name}");
        assert_eq!(loaded.render(&camera).unwrap(), before, "{name}: the loaded model renders otherwise");
    }
}

/// `Options::preset(Preset::Fast)` is the CLI's fast preset: the same recipe from core.
#[test]
fn the_fast_preset_of_the_library_is_the_clis() {
    use mipnerf::mipnerf_core::model::FastRecipe;
    let fast = Options::preset(Preset::Fast);
    let recipe = FastRecipe::RECIPE;
    assert!(fast.occupancy && fast.bf16 == recipe.bf16_where_available);
    assert_eq!(fast.batch_rays, recipe.batch_rays);
    assert_eq!(fast.optim.lr, recipe.schedule(fast.optim.lr.max_steps));
    assert_eq!((fast.optim.lr.lr_init, fast.optim.lr.lr_final), (5e-3, 5e-4), "not the paper's rates");
    // Subnormals: flushed where the CLI flushes them by default, kept by the faithful presets.
    for preset in [Preset::Tiny, Preset::Small, Preset::Fast, Preset::Paper] {
        assert_eq!(Options::preset(preset).flush_subnormals, preset.flushes_subnormals(), "{preset:?}");
    }
    assert!(!Options::preset(Preset::Small).flush_subnormals && !Options::preset(Preset::Paper).flush_subnormals);
    assert!(!Options::default().flush_subnormals);
}

/// The Tri-Mip field through the facade: chosen in `Options::model`, it trains, saves and loads
/// back as the same model, rendering the same picture bit for bit.
#[test]
fn a_tri_mip_nerf_saves_and_loads_as_it_was() {
    use mipnerf::mipnerf_core::model::Field;
    use mipnerf::mipnerf_core::tri_mip::TriMipConfig;
    let mut options = cpu_tiny();
    options.model.field = Field::TriMip {
        planes: TriMipConfig { resolution: 16, features: 4, levels: 3 },
        half_side: 1.5,
        pre_filtered: true,
    };
    let mut nerf = Nerf::new(demo::dataset(3, 12).unwrap(), options).unwrap();
    nerf.train(3).unwrap();
    let before = nerf.render(&novel_camera()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("tri-mip.safetensors");
    nerf.save(&path).unwrap();
    // Loaded with the default options: the checkpoint says which field it is.
    let mut loaded = Nerf::load(&path, cpu_tiny(), None).unwrap();
    assert_eq!(loaded.render(&novel_camera()).unwrap(), before);
}

/// `Options::tri_mip` brings the field's recipe (its planes, its MLP, the planes' own Adam
/// settings, f32), and a few steps of it cut the loss on the demo scene.
#[test]
fn options_tri_mip_brings_the_fields_recipe_and_trains() {
    use mipnerf::mipnerf_core::model::{Field, TriMipRecipe};
    let options = cpu_tiny().tri_mip(1.5);
    let recipe = TriMipRecipe::RECIPE;
    let Field::TriMip { planes, half_side, pre_filtered } = options.model.field else {
        panic!("not the Tri-Mip field")
    };
    assert_eq!((planes, half_side, pre_filtered), (TriMipRecipe::planes(recipe.resolution), 1.5, true));
    assert_eq!(
        [
            options.model.net_depth,
            options.model.net_width,
            options.model.net_depth_condition,
            options.model.net_width_condition
        ],
        recipe.mlp
    );
    assert_eq!(options.optim.field, Some(recipe.adam));
    assert!(!options.bf16);
    // Trained small and at the fast recipe's rate: 32² planes, 200 steps.
    let mut options = options;
    options.model.field = Field::TriMip { planes: TriMipRecipe::planes(32), half_side, pre_filtered };
    options.optim.lr = mipnerf::mipnerf_core::model::FastRecipe::RECIPE.schedule(200);
    let mut nerf = Nerf::new(demo::dataset(3, 12).unwrap(), options).unwrap();
    let losses: Vec<f32> = (0..200).map(|_| nerf.train(1).unwrap().stats.loss).collect();
    let (first, last) = (losses[..10].iter().sum::<f32>(), losses[190..].iter().sum::<f32>());
    assert!(last < 0.7 * first, "the loss fell only from {first} to {last}: {losses:?}");
}
