//! The settings a run resolves to: every unset field filled with its default for the data and
//! the field's recipe, so that the saved configuration says exactly what ran.

use mipnerf_core::config::{DataFit, GridFit};
use mipnerf_core::model::{FastRecipe, TriMipRecipe};
use mipnerf_core::train::AdamConfig;

use super::{
    Backend, FAST_BATCH_RAYS, FAST_LR, FAST_LR_DELAY_STEPS, FieldArg, MAX_STEPS, ModelKind, PrecisionArg, PresetArg,
    TrainSettings,
};

/// What a grid field's recipe sets of a run's settings where they do not say
/// ([`TrainSettings::grid_recipe_for`]).
struct GridRecipeSettings {
    tri_mip_tv: Option<f32>,
    hash_grid_decay: Option<f32>,
    lr_decay_steps: Option<u64>,
    density_noise_steps: Option<u64>,
}

impl TrainSettings {
    /// Fills every unset field with its default (given whether the data is LLFF), so the saved
    /// configuration says exactly what ran.
    #[must_use]
    pub fn resolved(&self, llff: bool) -> Self {
        let kind = self.model.unwrap_or(ModelKind::Mipnerf);
        let mip = kind == ModelKind::Mipnerf;
        // Forward-facing photos train in NDC space.
        // Unbounded scenes are spherified photos (or refused by the loader).
        let unbounded = self.unbounded.unwrap_or(false);
        let spherify = self.spherify.unwrap_or(unbounded);
        let forward_facing = llff && !spherify;
        // What the data implies where no flag says otherwise, as the library fits it: masked
        // photos are an object alone, composited as Blender's objects are.
        let masked = self.masks.is_some();
        let fit = DataFit { forward_facing, white_bkgd: DataFit::white_by_default(llff, masked), masked };
        let preset = self.preset.unwrap_or(PresetArg::Tiny);
        let fast = preset == PresetArg::Fast;
        let (tri_mip, grid) = (self.uses_tri_mip(), self.uses_grid_field());
        let recipe = GridFit::of(fit, unbounded);
        let noise = self.density_noise.unwrap_or(fit.density_noise());
        let grid_recipe = self.grid_recipe_for(recipe, noise);
        // A time budget ends the run, so the step count only caps it when given.
        let steps = self.steps.unwrap_or(if self.time_budget.is_some() { MAX_STEPS } else { 2000 });
        let occupancy = self.uses_occupancy();
        // On photos (LLFF, COLMAP) the tiny preset learns at the fast preset's rate: 21.86 dB
        // against 19.10 dB at the official 5e-4 after 5 minutes on 40 lego photos
        // (docs/results/own-photos/lr); small and paper keep the paper's rate everywhere.
        let lr = if fast || (llff && preset == PresetArg::Tiny) { FAST_LR } else { (5e-4, 5e-6) };
        Self {
            data: self.data.clone(),
            preset: Some(preset),
            model: Some(kind),
            steps: Some(steps),
            batch_rays: Some(self.batch_rays.unwrap_or(if fast { FAST_BATCH_RAYS } else { 1024 })),
            seed: Some(self.seed.unwrap_or(0)),
            backend: Some(self.backend.unwrap_or(if fast { Backend::Cpu } else { Backend::Auto })),
            checkpoint_every: Some(self.checkpoint_every.unwrap_or(500)),
            log_every: Some(self.log_every.unwrap_or(10)),
            lr_init: Some(self.lr_init.unwrap_or(lr.0)),
            lr_final: Some(self.lr_final.unwrap_or(lr.1)),
            lr_delay_steps: Some(self.lr_delay_steps.unwrap_or(if fast || self.time_budget.is_some() {
                FAST_LR_DELAY_STEPS
            } else {
                2500.min(steps / 10)
            })),
            lr_delay_mult: Some(self.lr_delay_mult.unwrap_or(0.01)),
            grad_max_norm: Some(self.grad_max_norm.unwrap_or(0.0)),
            grad_max_val: Some(self.grad_max_val.unwrap_or(0.0)),
            num_samples: self.num_samples,
            num_levels: self.num_levels,
            ipe: Some(self.ipe.unwrap_or(mip)),
            area_loss: Some(self.area_loss.unwrap_or(mip)),
            two_mlps: Some(self.two_mlps.unwrap_or(!mip)),
            misc: Some(self.misc.unwrap_or(mip)),
            centered_pixels: Some(self.centered_pixels.unwrap_or(mip)),
            supersample: Some(self.supersample.unwrap_or(1)),
            ray_shape: Some(self.ray_shape.unwrap_or(fit.ray_shape())),
            // Recorded only when it is not 0, so that the configurations of other runs read as
            // they always did, or where the data's default is not (so that a resumed run keeps 0).
            density_noise: Some(noise).filter(|&d| d != 0.0 || fit.density_noise() != 0.0),
            density_noise_steps: grid_recipe.density_noise_steps,
            white_bkgd: Some(self.white_bkgd.unwrap_or(fit.white_bkgd)),
            random_bkgd: Some(self.random_bkgd.unwrap_or(fit.random_bkgd())),
            masks: self.masks.clone(),
            half_res: Some(self.half_res.unwrap_or(false)),
            llff_factor: Some(self.llff_factor.unwrap_or(4)),
            spherify: Some(spherify),
            // An unbounded scene's cameras lie in the unit ball instead (a radius given with it is
            // kept, for `validate` to refuse).
            spherify_radius: if unbounded {
                self.spherify_radius
            } else {
                spherify.then(|| self.spherify_radius.unwrap_or(mipnerf_data::llff::SPHERIFY_RADIUS as f32))
            },
            unbounded: self.unbounded.filter(|&u| u),
            distortion_loss: self.distortion_loss.filter(|&d| d != 0.0),
            field: self.field.filter(|&f| f != FieldArg::MipNerf),
            tri_mip_bound: self.tri_mip_bound,
            // The field's recipe where the field is Tri-Mip; kept as given otherwise, for `validate`
            // to refuse.
            tri_mip_resolution: self.tri_mip_resolution.or(tri_mip.then_some(recipe.planes_resolution)),
            tri_mip_mlp: self.tri_mip_mlp.or(grid.then_some(TriMipRecipe::RECIPE.mlp)),
            tri_mip_lr_mult: self.tri_mip_lr_mult.or(grid.then(|| self.grid_adam().lr_mult)),
            grid_adam_eps: self.grid_adam_eps,
            grid_adam_skip_untouched: self.grid_adam_skip_untouched,
            tri_mip_tv: grid_recipe.tri_mip_tv,
            hash_grid_decay: grid_recipe.hash_grid_decay,
            adam_beta2: self.adam_beta2.filter(|&b| b != AdamConfig::default().beta2),
            mlp_l2: self.mlp_l2.filter(|&w| w != 0.0),
            coarse_to_fine_steps: self.coarse_to_fine_steps.filter(|&n| n != 0),
            lr_decay_steps: grid_recipe.lr_decay_steps,
            occupancy: Some(occupancy),
            occupancy_resolution: occupancy
                .then(|| self.occupancy_resolution.unwrap_or(FastRecipe::RECIPE.occupancy_resolution)),
            occupancy_bound: self.occupancy_bound,
            occupancy_masks: occupancy.then(|| self.occupancy_masks.unwrap_or(true)),
            time_budget: self.time_budget.clone(),
            snapshots: self.snapshots.clone(),
            val_every: Some(self.val_every.unwrap_or(0)),
            val_images: Some(self.val_images.unwrap_or(2)),
            // The fast preset computes in bf16 where the CPU has AMX (2.3 times the training
            // rate, +1.8 dB at 2 minutes) or an AVX-512 BF16 that outruns f32, as on AMD Zen 4
            // (docs/results/precision/); every other preset in f32, the paper's precision.
            // The Tri-Mip field's small MLP is measured in f32 only (docs/results/tri-mip/).
            precision: Some(self.precision.unwrap_or(if fast && FastRecipe::RECIPE.bf16_where_available && !grid {
                PrecisionArg::Auto
            } else {
                PrecisionArg::F32
            })),
            flush_subnormals: Some(self.flush_subnormals.unwrap_or(preset.preset().flushes_subnormals())),
        }
    }

    /// The grid fields' recipe for the data (`recipe`) where the settings do not say: the planes'
    /// total variation, the hash grid's weight decay, its rate's decay steps and the steps its
    /// density noise (`noise`, resolved) fades over (none where the field is another, where the
    /// data has no noise, or where a weight is 0 as the recipe's is: a 0 against the recipe is
    /// recorded, so that a resumed run keeps it).
    fn grid_recipe_for(&self, recipe: GridFit, noise: f32) -> GridRecipeSettings {
        let (tri_mip, hash_grid) = (self.uses_tri_mip(), self.field == Some(FieldArg::HashGrid));
        let keep = |w: f32, ours: bool, of_recipe: f32| w != 0.0 || (ours && of_recipe != 0.0);
        GridRecipeSettings {
            tri_mip_tv: self
                .tri_mip_tv
                .or(tri_mip.then_some(recipe.planes_tv))
                .filter(|&w| keep(w, tri_mip, recipe.planes_tv)),
            hash_grid_decay: self
                .hash_grid_decay
                .or(hash_grid.then_some(recipe.hash_grid_decay))
                .filter(|&w| keep(w, hash_grid, recipe.hash_grid_decay)),
            lr_decay_steps: self.lr_decay_steps.or(recipe.hash_grid_lr_decay_steps.filter(|_| hash_grid)),
            density_noise_steps: {
                let of_recipe = recipe.hash_grid_density_noise_steps.filter(|_| hash_grid && noise != 0.0);
                self.density_noise_steps.or(of_recipe).filter(|&n| n != 0 || of_recipe.is_some())
            },
        }
    }
}
