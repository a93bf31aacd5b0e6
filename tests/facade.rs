//! The facade's small API (`Nerf`, `Options`, `Device`): what an embedder writes, on the CPU (and
//! the same calls on whatever `Device::Auto` finds), and the CPU-only build without the `gpu`
//! feature.
#![allow(clippy::unwrap_used, missing_docs)]

use std::path::{Path, PathBuf};

use mipnerf::{Camera, Device, Error, Nerf, Options, Precision, Preset, demo};

fn cpu_tiny() -> Options {
    Options::preset(Preset::Tiny).with_device(Device::Cpu).with_batch_rays(64)
}

/// The default options (no model chosen: a checkpoint's is taken) on the CPU in f32, so that
/// renders compare bit for bit with an f32 run's.
fn cpu_default() -> Options {
    Options::default().with_device(Device::Cpu).with_precision(Precision::F32)
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

/// A time budget takes at least one step and stops soon after the budget, its learning rate
/// decayed to the schedule's final rate as the budget runs out (as `--time-budget`), where
/// steps follow the schedule by step.
#[test]
fn training_for_a_budget_takes_steps_until_it_is_spent_and_ends_the_decay_with_it() {
    use mipnerf::{LrSchedule, OptimConfig};
    let lr = LrSchedule { lr_delay_steps: 0, ..LrSchedule::default() };
    let options = cpu_tiny().with_optim(OptimConfig { lr, ..OptimConfig::default() });
    let mut nerf = Nerf::new(demo::dataset(2, 8).unwrap(), options.clone()).unwrap();
    let first = nerf.train(1).unwrap();
    let report = nerf.train_for(std::time::Duration::from_millis(400)).unwrap();
    let steps = nerf.step() - 1;
    assert!(steps >= 5 && report.step == nerf.step() - 1, "{steps} steps, last {}", report.step);
    // The last step's rate has decayed at least three quarters of the way (in log) to the final
    // rate (the schedule's horizon is an estimate from the steps' times, which jitter: exactly
    // the final rate is not promised). Without the stretch it would still be near `lr_init`.
    let three_quarters = lr.lr_final * (lr.lr_init / lr.lr_final).powf(0.25);
    assert!(report.lr <= three_quarters, "the last rate {} of {steps} steps, over {three_quarters}", report.lr);
    assert!(first.lr >= 0.99 * lr.lr_init, "{}", first.lr);
    // By steps alone, the schedule's own million-step decay: the rate barely moves.
    let mut by_steps = Nerf::new(demo::dataset(2, 8).unwrap(), options).unwrap();
    assert!(by_steps.train(steps + 1).unwrap().lr >= 0.99 * lr.lr_init);
}

/// The fast preset guides sampling with an occupancy grid carved from the images' alpha (the
/// demo's empty space is not full), saved with the parameters.
#[test]
fn the_fast_preset_trains_with_an_occupancy_grid() {
    let options = Options::preset(Preset::Fast).with_device(Device::Cpu).with_batch_rays(256);
    assert!(options.occupancy());
    let mut nerf = Nerf::new(demo::dataset(6, 16).unwrap(), options).unwrap();
    nerf.train(2).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("fast.safetensors");
    nerf.save(&path).unwrap();
    let ck = mipnerf_core::checkpoint::load(&path, nerf.backend().model()).unwrap();
    let grid = ck.occupancy.expect("the grid is saved with the parameters");
    assert!(!grid.is_full(), "the carved grid leaves empty space");
}

/// Without the `gpu` feature: `Device::Gpu` is a clear error, `Device::Auto` runs on the CPU
/// and says why.
#[cfg(not(feature = "gpu"))]
#[test]
fn without_the_gpu_feature_auto_is_the_cpu_and_gpu_an_error() {
    let data = || demo::dataset(2, 8).unwrap();
    let err = Nerf::new(data(), cpu_tiny().with_device(Device::Gpu)).unwrap_err();
    assert!(matches!(err, Error::NoGpuBackend) && err.to_string().contains("`gpu` feature is off"), "{err}");
    let mut auto = Nerf::new(data(), cpu_tiny().with_device(Device::Auto)).unwrap();
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
        (cpu_tiny().with_batch_rays(0), "`Options::with_batch_rays` takes 1 to"),
        (cpu_tiny().with_batch_rays(mipnerf::MAX_BATCH_RAYS + 1), "`Options::with_batch_rays`"),
        (cpu_tiny().with_render_bounds(6.0, 2.0), "`Options::with_render_bounds`"),
        (cpu_tiny().with_render_bounds(f32::NAN, 2.0), "`Options::with_render_bounds`"),
    ] {
        let err = Nerf::new(data(), options).unwrap_err();
        assert!(matches!(err, Error::Options(_)) && err.to_string().contains(words), "{err}");
    }
}

/// A COLMAP capture (forward-facing, in NDC) trains with the official LLFF settings the data
/// implies, as the CLI's `train` takes them (`DataFit`): cylinders, no white background, density
/// noise 1; occupancy-guided sampling runs on it with its grid over the NDC cube.
#[test]
fn forward_facing_data_trains_with_cylinders_and_occupancy_in_ndc() {
    let colmap = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/colmap_lego");
    let mut nerf = Nerf::from_dir(&colmap, cpu_tiny()).unwrap();
    let config = nerf.backend().model().config().clone();
    let fitted = (config.ray_shape, config.white_bkgd, config.density_noise, config.random_bkgd);
    assert_eq!(fitted, (mipnerf_core::RayShape::Cylinder, false, 1.0, false));
    assert!(nerf.train(1).unwrap().stats.loss.is_finite());
    let mut guided = Nerf::from_dir(&colmap, cpu_tiny().with_occupancy(true)).unwrap();
    assert!(guided.train(1).unwrap().stats.loss.is_finite());
    let grid = guided.backend().checkpoint().unwrap().occupancy.expect("the run keeps its grid");
    let data = mipnerf_data::load(&colmap, mipnerf_core::dataset::Split::Train, &Default::default());
    let bound = data.ok().and_then(|d| mipnerf_core::occupancy::ndc_bound(&d));
    assert_eq!(Some(grid.config.bound), bound, "the grid covers the NDC cube");
}

/// A grid field's recipe is fitted to the data as the CLI's `--field` fits it (`GridFit`): on
/// forward-facing photos the planes take their total variation (0.1) and the hash grid its
/// weight decay (0.01) and a learning rate whose decay ends at 10,000 steps; on Blender data
/// neither; a model given whole (`with_model`) is kept as given.
#[test]
fn a_grid_fields_recipe_is_fitted_to_the_data_as_the_clis() {
    use mipnerf_core::model::{GridFit, HashGridRecipe};
    let colmap = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/colmap_lego");
    let forward_facing =
        GridFit::of(mipnerf_core::config::DataFit { forward_facing: true, white_bkgd: false, masked: false }, false);
    assert_eq!((forward_facing.planes_tv, forward_facing.hash_grid_decay), (0.1, 0.01));
    let config =
        |dir: &Path, options: Options| Nerf::from_dir(dir, options).unwrap().backend().model().config().clone();
    let planes = config(&colmap, cpu_tiny().tri_mip(1.5));
    assert_eq!(planes.planes_tv_mult, forward_facing.planes_tv);
    let grid = config(&colmap, cpu_tiny().hash_grid(1.5));
    assert_eq!(grid.grid_decay_mult, forward_facing.hash_grid_decay);
    assert_eq!(forward_facing.hash_grid_lr_decay_steps, Some(HashGridRecipe::RECIPE.lr_decay_steps_forward_facing));
    // Blender data: the bounded recipe's (no total variation, no decay).
    let blender = config(&lego_tiny(), cpu_tiny().tri_mip(1.5));
    assert_eq!(blender.planes_tv_mult, 0.0);
    // A model given whole is not refitted.
    let given = cpu_tiny().tri_mip(1.5);
    let model = mipnerf::ModelConfig { planes_tv_mult: 0.5, ..given.model().clone() };
    assert_eq!(config(&colmap, given.with_model(model)).planes_tv_mult, 0.5);
}

/// A model saved by `Nerf::save` and loaded without its data renders as before: the checkpoint
/// holds its configuration (background, ray shape) and how its pixels become rays (bounds, pixel
/// centres, NDC), for forward-facing COLMAP data and for Blender data. Loaded with
/// `Options::default()` it is the checkpoint's model; options that chose another model are an
/// error naming both, not a silent swap.
#[test]
fn a_saved_model_loaded_without_data_renders_as_before_on_any_data() {
    let colmap = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/colmap_lego");
    let dir = tempfile::tempdir().unwrap();
    for (name, data) in [("colmap", colmap), ("blender", lego_tiny())] {
        let mut nerf = Nerf::from_dir(&data, cpu_tiny()).unwrap();
        nerf.train(2).unwrap();
        let camera = {
            let ds = mipnerf_data::load(&data, mipnerf_core::dataset::Split::Train, &Default::default()).unwrap();
            let c = ds.views()[0].camera.clone();
            Camera::from_camera_angle_x(16, 12, 0.8, c.cam2world).unwrap()
        };
        let before = nerf.render(&camera).unwrap();
        let path = dir.path().join(format!("{name}.safetensors"));
        nerf.save(&path).unwrap();
        // The default options (the fast preset's settings, no model chosen): the stored model
        // and bounds win.
        let mut loaded = Nerf::load(&path, cpu_default(), None).unwrap();
        assert_eq!(loaded.backend().model().config(), nerf.backend().model().config(), "{name}");
        assert_eq!(loaded.render(&camera).unwrap(), before, "{name}: the loaded model renders otherwise");
        // The preset it was trained with loads it too; another preset is refused.
        assert!(Nerf::load(&path, cpu_tiny(), None).is_ok(), "{name}");
        let err = Nerf::load(&path, Options::preset(Preset::Small).with_device(Device::Cpu), None).unwrap_err();
        let words = [
            "not the Mip-NeRF MLP with a 4x128 trunk and 64 samples on 2 levels as `Options` asks",
            "holds the Mip-NeRF MLP with a",
            "Options::default()",
        ];
        assert!(matches!(err, Error::Options(_)), "{name}: {err}");
        for w in words {
            assert!(err.to_string().contains(w), "{name}: `{w}` not in: {err}");
        }
    }
}

/// `Options::preset(Preset::Fast)` is the CLI's fast preset: the same recipe from core; the
/// default options are the fast preset's, sized for a CPU.
#[test]
fn the_fast_preset_of_the_library_is_the_clis() {
    use mipnerf_core::model::FastRecipe;
    let fast = Options::preset(Preset::Fast);
    let recipe = FastRecipe::RECIPE;
    assert!(fast.occupancy() && recipe.bf16_where_available);
    assert_eq!(fast.precision(), Precision::Bf16WhereAvailable);
    assert_eq!(fast.batch_rays(), recipe.batch_rays);
    assert_eq!(fast.optim().lr, recipe.schedule(fast.optim().lr.max_steps));
    assert_eq!((fast.optim().lr.lr_init, fast.optim().lr.lr_final), (5e-3, 5e-4), "not the paper's rates");
    // Subnormals: flushed where the CLI flushes them by default, kept by the faithful presets.
    for preset in [Preset::Tiny, Preset::Small, Preset::Fast, Preset::Paper] {
        assert_eq!(Options::preset(preset).flush_subnormals(), preset.flushes_subnormals(), "{preset:?}");
    }
    assert!(!Options::preset(Preset::Small).flush_subnormals() && !Options::preset(Preset::Paper).flush_subnormals());
    // The default: the fast preset's model and settings, not the paper's 612K-parameter model.
    let default = Options::default();
    assert_eq!(default.model(), fast.model());
    assert_eq!(
        (default.occupancy(), default.batch_rays(), default.precision()),
        (true, recipe.batch_rays, fast.precision())
    );
}

/// Precision is what was asked or an error: `Precision::Bf16` runs bf16 where the CPU has a
/// kernel and is an error naming it elsewhere; `Bf16WhereAvailable` says which it runs.
#[test]
fn bf16_is_run_or_refused_never_dropped() {
    let available = mipnerf_core::bf16::Bf16Support::detect().available();
    let data = || demo::dataset(2, 8).unwrap();
    match Nerf::new(data(), cpu_tiny().with_precision(Precision::Bf16)) {
        Ok(mut nerf) => {
            assert!(available, "bf16 accepted on a CPU without a kernel");
            assert_eq!(nerf.precision(), Precision::Bf16);
            assert!(nerf.train(1).unwrap().stats.loss.is_finite());
        }
        Err(err) => {
            assert!(!available, "bf16 refused on a CPU with a kernel: {err}");
            assert!(matches!(err, Error::Options(_)) && err.to_string().contains("`Precision::Bf16` on CPU"), "{err}");
        }
    }
    let nerf = Nerf::new(data(), cpu_tiny().with_precision(Precision::Bf16WhereAvailable)).unwrap();
    assert_eq!(nerf.precision(), if available { Precision::Bf16 } else { Precision::F32 });
    assert_eq!(Nerf::new(data(), cpu_tiny()).unwrap().precision(), Precision::F32);
}

/// A `Nerf` moves to another thread (an app trains it off its UI thread).
#[test]
fn a_nerf_is_send() {
    fn send<T: Send>(t: T) -> T {
        t
    }
    let mut nerf = send(Nerf::new(demo::dataset(2, 8).unwrap(), cpu_tiny()).unwrap());
    let step = std::thread::spawn(move || nerf.train(1).map(|r| r.step)).join().unwrap().unwrap();
    assert_eq!(step, 0);
}

/// A rendered image made by hand with too few pixels is an error, not an empty picture.
#[test]
fn an_inconsistent_rendered_image_is_an_error_not_an_empty_picture() {
    let mut nerf = Nerf::new(demo::dataset(2, 8).unwrap(), cpu_tiny()).unwrap();
    let mut image = nerf.render(&novel_camera()).unwrap();
    let picture: mipnerf::RgbImage = image.to_rgb_image().unwrap();
    assert_eq!(picture.dimensions(), (12, 8));
    image.fine.pop();
    let err = image.to_rgb_image().unwrap_err();
    assert!(err.to_string().contains("12x8 pixels holds 95"), "{err}");
}

/// The Tri-Mip field through the facade: chosen with `Options::with_model`, it trains, saves
/// and loads back as the same model, rendering the same picture bit for bit.
#[test]
fn a_tri_mip_nerf_saves_and_loads_as_it_was() {
    use mipnerf::{Field, ModelConfig, TriMipConfig};
    let base = cpu_tiny();
    let field = Field::TriMip {
        planes: TriMipConfig { resolution: 16, features: 4, levels: 3 },
        half_side: 1.5,
        pre_filtered: true,
    };
    let options = base.clone().with_model(ModelConfig { field, ..base.model().clone() });
    let mut nerf = Nerf::new(demo::dataset(3, 12).unwrap(), options.clone()).unwrap();
    nerf.train(3).unwrap();
    let before = nerf.render(&novel_camera()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("tri-mip.safetensors");
    nerf.save(&path).unwrap();
    // Loaded with the default options, or the ones it was made with: the checkpoint says
    // which field it is.
    for options in [cpu_default(), options] {
        let mut loaded = Nerf::load(&path, options, None).unwrap();
        assert_eq!(loaded.render(&novel_camera()).unwrap(), before);
    }
    // Options of the plain tiny model name the field the checkpoint holds.
    let err = Nerf::load(&path, cpu_tiny(), None).unwrap_err();
    assert!(err.to_string().contains("holds the Tri-Mip field (16² planes)"), "{err}");
}

/// `Options::tri_mip` brings the field's recipe (its planes, its MLP, the planes' own Adam
/// settings, f32), and a few steps of it cut the loss on the demo scene.
#[test]
fn options_tri_mip_brings_the_fields_recipe_and_trains() {
    use mipnerf::{Field, ModelConfig, OptimConfig};
    use mipnerf_core::model::TriMipRecipe;
    let options = cpu_tiny().tri_mip(1.5);
    let recipe = TriMipRecipe::RECIPE;
    let model = options.model().clone();
    let Field::TriMip { planes, half_side, pre_filtered } = model.field else { panic!("not the Tri-Mip field") };
    assert_eq!((planes, half_side, pre_filtered), (TriMipRecipe::planes(recipe.resolution), 1.5, true));
    assert_eq!([model.net_depth, model.net_width, model.net_depth_condition, model.net_width_condition], recipe.mlp);
    assert_eq!(options.optim().field, Some(recipe.adam));
    assert_eq!(options.precision(), Precision::F32);
    // Trained small and at the fast recipe's rate: 32² planes, 200 steps.
    let field = Field::TriMip { planes: TriMipRecipe::planes(32), half_side, pre_filtered };
    let optim = OptimConfig { lr: mipnerf_core::model::FastRecipe::RECIPE.schedule(200), ..options.optim().clone() };
    let options = options.with_model(ModelConfig { field, ..model }).with_optim(optim);
    let mut nerf = Nerf::new(demo::dataset(3, 12).unwrap(), options).unwrap();
    let losses: Vec<f32> = (0..200).map(|_| nerf.train(1).unwrap().stats.loss).collect();
    let (first, last) = (losses[..10].iter().sum::<f32>(), losses[190..].iter().sum::<f32>());
    assert!(last < 0.7 * first, "the loss fell only from {first} to {last}: {losses:?}");
}

/// `Options::hash_grid` brings the field's recipe (its grid, its MLP, the grid's own Adam
/// settings, f32); a small grid trains, cuts the loss, saves and loads back as the same model.
#[test]
fn options_hash_grid_brings_the_fields_recipe_trains_and_loads_back() {
    use mipnerf::{Field, HashGridConfig, ModelConfig, OptimConfig};
    use mipnerf_core::model::HashGridRecipe;
    let options = cpu_tiny().hash_grid(1.5);
    let recipe = HashGridRecipe::RECIPE;
    let model = options.model().clone();
    assert_eq!(model.field, Field::HashGrid { grid: recipe.grid, half_side: 1.5 });
    assert_eq!([model.net_depth, model.net_width, model.net_depth_condition, model.net_width_condition], recipe.mlp);
    assert_eq!(options.optim().field, Some(recipe.adam));
    assert_eq!(model.grid_decay_mult, recipe.decay);
    assert_eq!(options.optim().lr.decay_steps, None);
    assert_eq!(options.precision(), Precision::F32);
    // Trained small and at the fast recipe's rate: 8 levels to 64 cells, tables of 2^12.
    let grid = HashGridConfig { levels: 8, features: 2, log2_table: 12, coarsest: 8, finest: 64 };
    let optim = OptimConfig { lr: mipnerf_core::model::FastRecipe::RECIPE.schedule(200), ..options.optim().clone() };
    let options =
        options.with_model(ModelConfig { field: Field::HashGrid { grid, half_side: 1.5 }, ..model }).with_optim(optim);
    let mut nerf = Nerf::new(demo::dataset(3, 12).unwrap(), options).unwrap();
    let losses: Vec<f32> = (0..200).map(|_| nerf.train(1).unwrap().stats.loss).collect();
    let (first, last) = (losses[..10].iter().sum::<f32>(), losses[190..].iter().sum::<f32>());
    assert!(last < 0.7 * first, "the loss fell only from {first} to {last}: {losses:?}");
    let before = nerf.render(&novel_camera()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("hash-grid.safetensors");
    nerf.save(&path).unwrap();
    let mut loaded = Nerf::load(&path, cpu_default(), None).unwrap();
    assert_eq!(loaded.render(&novel_camera()).unwrap(), before);
    let err = Nerf::load(&path, cpu_tiny(), None).unwrap_err();
    assert!(err.to_string().contains("holds the hash grid (8 levels to 64 cells a side)"), "{err}");
}
