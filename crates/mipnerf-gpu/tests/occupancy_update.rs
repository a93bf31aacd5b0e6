//! An occupancy grid's update on the device (`occupancy_update.wgsl`, the fields' probe modes in
//! `cast_ipe.wgsl` and `tri_mip.wgsl`, the MLP's forward pass, and the occupied cells and their
//! dilations from `occupancy_refresh.wgsl`; for the Tri-Mip field with a fused MLP,
//! `occupancy_probe.wgsl` in one dispatch) against the CPU's `OccupancyGrid::update`, for both
//! fields, bounded and over an unbounded scene's contracted space, in several chunks of cells.
#![allow(clippy::unwrap_used, missing_docs)]

use mipnerf_core::backend::TrainState;
use mipnerf_core::model::{Field, Model, ModelConfig, Preset, TriMipRecipe};
use mipnerf_core::occupancy::{CARVED, CONTRACTED_BOUND, OccupancyConfig, OccupancyGrid};
use mipnerf_gpu::kernels::Recorder;
use mipnerf_gpu::kernels::occupancy::DeviceGrid;
use mipnerf_gpu::model::{GpuModel, ModelBuffers};
use mipnerf_gpu::test_support::context_or_skip;

/// A cell's opacity on the device against the CPU's: the density is the MLP's output through
/// the field's taps (or IPE), summed in the device's order, then `1 - exp(-σ h)`. Measured at
/// most 2.4e-7 on lavapipe; the bound leaves a hardware GPU's `exp` and `log` (softplus) a few
/// ulp more.
const TOL_OPACITY_ABS: f32 = 2e-5;

/// Rays the model's buffers hold: a chunk of `RAYS * num_samples` cells, so the grids below
/// take several chunks, the last one partial.
const RAYS: usize = 7;

/// The grid's update on both sides from the same starting opacities (some carved, the others
/// from a first update at step 0), at a step past the warm-up: the opacities agree within
/// [`TOL_OPACITY_ABS`], carved cells stay carved, and the occupied cells differ only where a
/// cell's opacity lies within the tolerance of the threshold.
fn update_agrees(what: &str, cfg: ModelConfig, grid: OccupancyConfig) {
    let Some(ctx) = context_or_skip(&format!("occupancy_update {what}")) else { return };
    let model = Model::new(cfg).unwrap();
    let params = TrainState::fresh(&model, 3).params;
    let n = grid.resolution.pow(3);
    let start: Vec<f32> = (0..n).map(|i| if i % 7 == 3 { CARVED } else { 0.0 }).collect();
    let mut host = OccupancyGrid::from_state(grid, start, false).unwrap();
    host.update(&model.density_field(&params), 9, 0);
    let mut device = host.clone();
    let step = grid.warmup_steps + 5;
    host.update(&model.density_field(&params), 9, step);

    let kernels = GpuModel::new(&ctx).unwrap();
    let mut work = ModelBuffers::new(&ctx, &model, RAYS).unwrap();
    let mut on_device = DeviceGrid::new(&ctx, &device).unwrap();
    let params_buf = ctx.storage_buffer("params", &params, true);
    let mut rec = Recorder::new(&ctx, "occupancy update");
    kernels.prepare_field(&mut rec, &model, &params_buf, &work, false).unwrap();
    kernels.update_grid(&mut rec, &model, &params_buf, &mut work, &mut on_device, (9, step as u32)).unwrap();
    let _ = rec.submit();
    let opacity = ctx.read_f32(on_device.opacity(), n).unwrap();
    let words = ctx.read_f32(on_device.layers(), device.packed_layers().len()).unwrap();
    let layers: Vec<u32> = words.iter().map(|w| w.to_bits()).collect();
    assert_eq!(work.n_rays(), RAYS, "{what}: the buffers' active rays are left as they were");

    let (mut worst, mut changed) = (0.0f32, 0);
    for (i, (&d, &h)) in opacity.iter().zip(&host.opacity).enumerate() {
        assert_eq!(d == CARVED, h == CARVED, "{what}: cell {i} carved on one side only ({d} against {h})");
        worst = worst.max((d - h).abs());
        changed += usize::from(d != device.opacity[i]);
    }
    assert!(worst <= TOL_OPACITY_ABS, "{what}: opacities differ by up to {worst:e}");
    assert!(changed > n / 10, "{what}: the update changed only {changed} of {n} cells");
    device.update_with_opacity(opacity, step).unwrap();
    assert!(device.warmed_up, "{what}: the warm-up ends as on the CPU");
    assert!(on_device.warmed_up(), "{what}: the warm-up ends on the device too");
    // The occupied cells and their dilations found on the device (`occupancy_refresh.wgsl`) are
    // the CPU's from the same opacities, bit for bit (the mean of the candidates, f32 on the
    // device and f64 on the host, decides no cell here).
    let want = device.packed_layers();
    let wrong = layers.iter().zip(&want).filter(|(a, b)| a != b).count();
    assert_eq!(wrong, 0, "{what}: {wrong} of {} words of the layers differ from the CPU's", want.len());
    let candidates: Vec<f32> = host.opacity.iter().copied().filter(|&v| v != CARVED).collect();
    let mean = candidates.iter().map(|&v| f64::from(v)).sum::<f64>() / candidates.len() as f64;
    let threshold = grid.threshold.min(mean as f32);
    let r = grid.resolution;
    let (mut differ, mut occupied) = (0, 0);
    for i in 0..n {
        let (x, y, z) = (i % r, (i / r) % r, i / (r * r));
        let (a, b) = (device.is_occupied(x, y, z), host.is_occupied(x, y, z));
        occupied += usize::from(b);
        if a != b {
            differ += 1;
            let off = (host.opacity[i] - threshold).abs();
            assert!(off <= 2.0 * TOL_OPACITY_ABS, "{what}: cell {i} occupied on one side, {off:e} from the threshold");
        }
    }
    let k = candidates.len();
    assert!(
        k / 5 < occupied && occupied < k - k / 5,
        "{what}: {occupied} of {k} candidates occupied: the threshold decides little"
    );
    eprintln!(
        "{what}: worst opacity difference {worst:e}; {differ} of {n} cells differ in occupancy ({occupied} occupied)"
    );
}

/// The Tri-Mip field with the recipe's MLP (run fused: the update in one dispatch), or with one
/// too wide for the fused kernels (`wide`: the update through the product kernels, in chunks).
fn tri_mip(unbounded: bool, wide: bool) -> ModelConfig {
    let half_side = if unbounded { CONTRACTED_BOUND } else { 1.5 };
    let field = Field::TriMip { planes: TriMipRecipe::planes(32), half_side, pre_filtered: true };
    let mlp = if wide { [2, 96, 1, 64] } else { TriMipRecipe::RECIPE.mlp };
    let cfg = TriMipRecipe::with_mlp(ModelConfig { field, unbounded, ..Preset::Fast.config() }, mlp);
    let runs_fused = mipnerf_gpu::mlp::MlpBuffers::runs_fused(&Model::new(cfg.clone()).unwrap().mlps()[0]);
    assert_eq!(runs_fused, !wide, "the MLP [{mlp:?}] runs fused: {runs_fused}");
    cfg
}

fn grid(resolution: usize, contracted: bool) -> OccupancyConfig {
    let bound = if contracted { CONTRACTED_BOUND } else { 1.5 };
    // A threshold above every opacity: the mean of the candidates' decides, about half occupied.
    OccupancyConfig { resolution, bound, contracted, threshold: 1.0, ..OccupancyConfig::default() }
}

#[test]
fn the_tri_mip_fields_grid_update_on_the_device_is_the_cpus() {
    update_agrees("tri-mip", tri_mip(false, false), grid(12, false));
    update_agrees("tri-mip, product kernels", tri_mip(false, true), grid(12, false));
}

#[test]
fn the_tri_mip_fields_contracted_grid_update_on_the_device_is_the_cpus() {
    update_agrees("tri-mip, contracted", tri_mip(true, false), grid(12, true));
}

#[test]
fn the_mip_nerf_fields_grid_update_on_the_device_is_the_cpus() {
    update_agrees("mip-nerf", Preset::Tiny.config(), grid(12, false));
    update_agrees("mip-nerf, contracted", ModelConfig { unbounded: true, ..Preset::Tiny.config() }, grid(10, true));
}

#[test]
fn a_grid_over_another_space_than_the_models_is_refused() {
    let Some(ctx) = context_or_skip("a_grid_over_another_space_than_the_models_is_refused") else { return };
    let model = Model::new(Preset::Tiny.config()).unwrap();
    let params = TrainState::fresh(&model, 3).params;
    let kernels = GpuModel::new(&ctx).unwrap();
    let mut work = ModelBuffers::new(&ctx, &model, RAYS).unwrap();
    let host = OccupancyGrid::new(grid(8, true)).unwrap();
    let mut on_device = DeviceGrid::new(&ctx, &host).unwrap();
    let params_buf = ctx.storage_buffer("params", &params, true);
    let mut rec = Recorder::new(&ctx, "occupancy update");
    let err = kernels.update_grid(&mut rec, &model, &params_buf, &mut work, &mut on_device, (9, 0)).unwrap_err();
    assert!(err.to_string().contains("contracted space"), "{err}");
}
