//! The settings' defaults per preset and data.

use super::{FAST_LR, PresetArg, TrainSettings};

/// The learning-rate defaults per kind of data and preset (docs/results/own-photos/lr).
#[test]
fn learning_rate_defaults_follow_the_data_and_the_preset() {
    let lr = |preset: Option<PresetArg>, llff: bool| {
        let r = TrainSettings { preset, ..TrainSettings::default() }.resolved(llff);
        (r.lr_init.unwrap(), r.lr_final.unwrap())
    };
    // Photos: the tiny preset (the default) learns at the fast rate.
    assert_eq!(lr(None, true), FAST_LR);
    assert_eq!(lr(Some(PresetArg::Tiny), true), FAST_LR);
    assert_eq!(lr(Some(PresetArg::Fast), true), FAST_LR);
    // The faithful presets keep the paper's rate on every kind of data.
    assert_eq!(lr(Some(PresetArg::Small), true), (5e-4, 5e-6));
    assert_eq!(lr(Some(PresetArg::Paper), true), (5e-4, 5e-6));
    // Blender and multiscale data: the paper's rate but for the fast preset.
    assert_eq!(lr(None, false), (5e-4, 5e-6));
    assert_eq!(lr(Some(PresetArg::Fast), false), FAST_LR);
    // A rate given is kept.
    let given = TrainSettings { lr_init: Some(1e-3), ..TrainSettings::default() }.resolved(true);
    assert_eq!(given.lr_init, Some(1e-3));
}

/// Subnormals are flushed by default where core's preset says so (tiny, fast), kept by the
/// faithful presets (small, paper), and a setting given wins either way.
#[test]
fn subnormals_follow_the_preset_unless_set() {
    let flush = |preset, set| {
        TrainSettings { preset: Some(preset), flush_subnormals: set, ..TrainSettings::default() }
            .resolved(false)
            .flush_subnormals
            .unwrap()
    };
    for (preset, by_default) in
        [(PresetArg::Tiny, true), (PresetArg::Fast, true), (PresetArg::Small, false), (PresetArg::Paper, false)]
    {
        assert_eq!(flush(preset, None), by_default, "{preset:?}");
        assert_eq!(by_default, preset.preset().flushes_subnormals());
        assert!(flush(preset, Some(true)) && !flush(preset, Some(false)));
    }
}

/// `--preset fast` is core's fast recipe, the one `Options::preset(Preset::Fast)` takes too
/// (tests/facade.rs checks that side).
#[test]
fn the_fast_preset_is_cores_fast_recipe() {
    use mipnerf_core::model::FastRecipe;
    let r = TrainSettings { preset: Some(PresetArg::Fast), ..TrainSettings::default() }.resolved(false);
    let recipe = FastRecipe::RECIPE;
    assert_eq!(r.batch_rays, Some(recipe.batch_rays));
    assert_eq!((r.lr_init.unwrap(), r.lr_final.unwrap()), recipe.lr);
    assert_eq!((r.lr_delay_steps, r.lr_delay_mult), (Some(recipe.lr_delay_steps), Some(0.01)));
    assert_eq!((r.occupancy, r.occupancy_resolution), (Some(true), Some(recipe.occupancy_resolution)));
    assert_eq!(
        r.precision,
        Some(if recipe.bf16_where_available { super::PrecisionArg::Auto } else { super::PrecisionArg::F32 })
    );
}

/// Adam's `beta2` is flax's unless set, recorded only when set to another, and reaches the
/// optimiser; the hash grid's weight decay and its rate's decay steps are its recipe's for the
/// data unless set, and reach the model and the schedule.
#[test]
fn adams_beta2_and_the_grids_decay_reach_the_optimiser_and_the_model() {
    use super::FieldArg;
    use mipnerf_core::model::HashGridRecipe;
    use mipnerf_core::train::FieldAdam;
    let plain = TrainSettings::default().resolved(false);
    assert_eq!((plain.adam_beta2, plain.optim_config().unwrap().adam.beta2), (None, 0.999));
    let set = TrainSettings { adam_beta2: Some(0.99), ..TrainSettings::default() }.resolved(false);
    assert_eq!((set.adam_beta2, set.optim_config().unwrap().adam.beta2), (Some(0.99), 0.99));
    // The MLP's L2: off unless set, recorded when set.
    assert_eq!((plain.mlp_l2, plain.optim_config().unwrap().adam.l2), (None, 0.0));
    let l2 = TrainSettings { mlp_l2: Some(1e-6), ..TrainSettings::default() }.resolved(false);
    assert_eq!((l2.mlp_l2, l2.resolved(false).optim_config().unwrap().adam.l2), (Some(1e-6), 1e-6));
    // Coarse to fine: off unless set, recorded when set, in the model's configuration.
    assert_eq!((plain.coarse_to_fine_steps, plain.model_config().unwrap().coarse_to_fine_steps), (None, 0));
    let c2f =
        TrainSettings { field: Some(FieldArg::HashGrid), coarse_to_fine_steps: Some(500), ..TrainSettings::default() };
    let c2f = c2f.resolved(true);
    assert_eq!(
        (c2f.coarse_to_fine_steps, c2f.resolved(true).model_config().unwrap().coarse_to_fine_steps),
        (Some(500), 500)
    );
    // The hash grid's recipe: its decay and its rate's decay steps on forward-facing photos.
    let grid = |decay: Option<f32>, forward_facing: bool| {
        let s = TrainSettings {
            field: Some(FieldArg::HashGrid),
            hash_grid_decay: decay,
            tri_mip_bound: Some(1.0),
            ..TrainSettings::default()
        }
        .resolved(forward_facing);
        (s.hash_grid_decay, s.model_config().unwrap().grid_decay_mult, s.optim_config().unwrap().lr.decay_steps)
    };
    let recipe = HashGridRecipe::RECIPE;
    let steps = Some(recipe.lr_decay_steps_forward_facing);
    assert_eq!(grid(None, true), (Some(recipe.decay_forward_facing), recipe.decay_forward_facing, steps));
    assert_eq!(recipe.decay, 0.0);
    assert_eq!(grid(None, false), (None, 0.0, None));
    assert_eq!(grid(Some(0.5), false), (Some(0.5), 0.5, None));
    // Turned off against the recipe: recorded, so that a resumed run (whose settings are the
    // recorded ones, resolved again) keeps it off.
    assert_eq!(grid(Some(0.0), true), (Some(0.0), 0.0, steps));
    let off = TrainSettings {
        field: Some(FieldArg::HashGrid),
        hash_grid_decay: Some(0.0),
        tri_mip_bound: Some(1.0),
        ..TrainSettings::default()
    }
    .resolved(true);
    assert_eq!(off.resolved(true).model_config().unwrap().grid_decay_mult, 0.0);
    let planes_off = TrainSettings {
        field: Some(FieldArg::TriMip),
        tri_mip_tv: Some(0.0),
        tri_mip_bound: Some(1.0),
        ..TrainSettings::default()
    }
    .resolved(true);
    assert_eq!(planes_off.tri_mip_tv, Some(0.0));
    assert_eq!(planes_off.resolved(true).model_config().unwrap().planes_tv_mult, 0.0);
    let noise_off = TrainSettings { density_noise: Some(0.0), ..TrainSettings::default() }.resolved(true);
    assert_eq!(noise_off.density_noise, Some(0.0));
    assert_eq!(noise_off.resolved(true).model_config().unwrap().density_noise, 0.0);
    // Where the data's default is 0 too, nothing is recorded (as before).
    assert_eq!(
        TrainSettings { density_noise: Some(0.0), ..TrainSettings::default() }.resolved(false).density_noise,
        None
    );
    assert_eq!(plain.model_config().unwrap().grid_decay_mult, 0.0);
    // The hash grid's density noise on forward-facing photos fades over the recipe's steps,
    // recorded; with the noise off, or another field, or on other data, it is held (none).
    let fade = |field, noise: Option<f32>, set: Option<u64>, forward_facing: bool| {
        let s = TrainSettings {
            field,
            density_noise: noise,
            density_noise_steps: set,
            tri_mip_bound: Some(1.0),
            ..TrainSettings::default()
        }
        .resolved(forward_facing);
        (s.density_noise_steps, s.resolved(forward_facing).model_config().unwrap().density_noise_steps)
    };
    let recipe_fade = recipe.density_noise_steps_forward_facing;
    assert_eq!(fade(Some(FieldArg::HashGrid), None, None, true), (Some(recipe_fade), recipe_fade));
    assert_eq!(fade(Some(FieldArg::HashGrid), None, Some(300), true), (Some(300), 300));
    assert_eq!(fade(Some(FieldArg::HashGrid), Some(0.0), None, true), (None, 0));
    assert_eq!(fade(Some(FieldArg::HashGrid), None, None, false), (None, 0));
    assert_eq!(fade(Some(FieldArg::TriMip), None, None, true), (None, 0));
    assert_eq!(fade(None, None, None, true), (None, 0));
    assert_eq!(fade(None, None, Some(300), true), (Some(300), 300));
    // Held against the recipe: recorded, so that a resumed run keeps it held; elsewhere 0 is
    // what it would be anyway.
    assert_eq!(fade(Some(FieldArg::HashGrid), None, Some(0), true), (Some(0), 0));
    assert_eq!(fade(None, None, Some(0), true), (None, 0));
    // Other runs decay over all their steps unless told.
    let decay_steps = |field, set| {
        let s = TrainSettings { field, lr_decay_steps: set, tri_mip_bound: Some(1.0), ..TrainSettings::default() }
            .resolved(true);
        s.optim_config().unwrap().lr.decay_steps
    };
    assert_eq!(decay_steps(Some(FieldArg::HashGrid), Some(500)), Some(500));
    assert_eq!(decay_steps(Some(FieldArg::TriMip), None), None);
    assert_eq!(decay_steps(None, Some(500)), Some(500));
    // A grid's Adam epsilon, and whether it skips untouched entries, are its recipe's unless set.
    let grid_adam = |set: TrainSettings| {
        let s = TrainSettings { field: Some(FieldArg::HashGrid), tri_mip_bound: Some(1.0), ..set }.resolved(true);
        (s.grid_adam_skip_untouched, s.optim_config().unwrap().field.unwrap())
    };
    let recipe = HashGridRecipe::RECIPE.adam;
    assert_eq!(grid_adam(TrainSettings::default()), (None, recipe));
    let eps = grid_adam(TrainSettings { grid_adam_eps: Some(1e-8), ..TrainSettings::default() }).1;
    assert_eq!(eps, FieldAdam { eps: 1e-8, ..recipe });
    let skip = grid_adam(TrainSettings { grid_adam_skip_untouched: Some(true), ..TrainSettings::default() });
    assert_eq!(skip, (Some(true), FieldAdam { skip_untouched: true, ..recipe }));
}
