//! The Tri-Mip field inside the model (`ModelConfig::field`): the whole loss's gradient through
//! the MLP and the planes against finite differences (over world space, and over the contracted
//! space of an unbounded scene), the planes' own Adam settings, a short training run that cuts
//! the loss, the same bits whatever the thread count, and a checkpoint that holds the planes.
#![allow(clippy::unwrap_used, missing_docs)]

mod common;
use common::scene::ball_scene;
use mipnerf_core::checkpoint;
use mipnerf_core::model::{Field, Mode, Model, ModelConfig, Preset};
use mipnerf_core::model::{GradWith, TrainBatch};
use mipnerf_core::train::{AdamConfig, AdamState, FieldAdam, OptimConfig, Trainer};
use mipnerf_core::tri_mip::TriMipConfig;
use rand::{Rng, SeedableRng, rngs::SmallRng};

/// A small model of the Tri-Mip field: 16² planes of 4 features, 3 levels, a 2 x 32 MLP.
fn small(pre_filtered: bool) -> ModelConfig {
    let mut cfg = Preset::Tiny.config();
    cfg.net_depth = 2;
    cfg.net_width = 32;
    cfg.net_width_condition = 16;
    cfg.num_samples = 16;
    cfg.field =
        Field::TriMip { planes: TriMipConfig { resolution: 16, features: 4, levels: 3 }, half_side: 1.5, pre_filtered };
    cfg
}

#[test]
fn the_whole_losss_gradient_through_the_planes_and_the_mlp_matches_finite_differences() {
    the_whole_loss_matches_finite_differences(false, 0);
}

#[test]
fn coarse_to_fine_reads_the_planes_coarser_at_first_and_matches_finite_differences() {
    the_whole_loss_matches_finite_differences(false, 100);
}

#[test]
fn in_an_unbounded_scene_the_planes_read_the_contracted_space_and_match_finite_differences() {
    the_whole_loss_matches_finite_differences(true, 0);
}

/// The whole loss's gradient against central differences, the planes over world space or (in an
/// unbounded scene) over the contracted space, cube of half side 2; with `coarse_to_fine` steps
/// at its first, the footprints widened by their floor (then the loss is not the plain one's).
fn the_whole_loss_matches_finite_differences(unbounded: bool, coarse_to_fine: u64) {
    let (rays, colours) = ball_scene(2, 6);
    let mut cfg = small(true);
    // One level: the fine level's intervals carry no gradient by design (see training.rs).
    cfg.num_levels = 1;
    // The planes' total variation in the loss too (its own check: tests/tri_mip.rs).
    cfg.planes_tv_mult = 0.5;
    if unbounded {
        cfg.unbounded = true;
        let Field::TriMip { planes, pre_filtered, .. } = cfg.field else { unreachable!() };
        cfg.field = Field::TriMip { planes, half_side: 2.0, pre_filtered };
    }
    let plain = Model::new(cfg.clone()).unwrap();
    let model = Model::new(ModelConfig { coarse_to_fine_steps: coarse_to_fine, ..cfg }).unwrap();
    assert!(model.field_params() > 0 && model.field_params() < model.num_params());
    let mut params = model.init_params(3);
    // Planes of a visible size, so that the loss moves with them.
    let mut rng = SmallRng::seed_from_u64(4);
    for p in &mut params[..model.field_params()] {
        *p = rng.random_range(-0.5..0.5);
    }
    let mode = Mode::Train { seed: 1, step: 0 };
    let batch = TrainBatch { rays: &rays[..40], targets: &colours[..40] };
    let (widened, own) =
        (common::batch_loss(&model, batch, mode)(&params), common::batch_loss(&plain, batch, mode)(&params));
    assert_eq!(widened == own, coarse_to_fine == 0, "loss {widened} against the plain field's {own}");
    let mut grads = vec![0.0; model.num_params()];
    model.loss_and_grad(
        &params,
        TrainBatch { rays: &rays[..40], targets: &colours[..40] },
        mode,
        &mut grads,
        GradWith::default(),
    );
    let loss = common::batch_loss(&model, TrainBatch { rays: &rays[..40], targets: &colours[..40] }, mode);
    // Plane parameters the batch reaches (a non-zero gradient), and some of every MLP layer.
    let reached: Vec<usize> = (0..model.field_params()).filter(|&i| grads[i] != 0.0).collect();
    assert!(reached.len() > 100, "the batch reaches {} plane parameters", reached.len());
    let mut picks: Vec<(String, usize)> =
        (0..24).map(|_| ("planes".to_owned(), reached[rng.random_range(0..reached.len())])).collect();
    for l in &model.mlps()[0].layers {
        picks.extend((0..4).map(|_| (l.name.clone(), l.kernel + rng.random_range(0..l.fan_in * l.fan_out))));
    }
    common::assert_gradients_match_finite_differences(picks, &grads, &mut params, loss);
}

#[test]
fn the_planes_take_their_own_learning_rate_and_epsilon_in_one_adam_step() {
    let cfg = AdamConfig::default();
    let field = FieldAdam { lr_mult: 10.0, eps: 1e-15, skip_untouched: false };
    let params: Vec<f32> = (0..10).map(|i| i as f32 * 0.1).collect();
    // Gradients far below the MLP's epsilon (1e-8), as a texel few rays reach gets.
    let grads: Vec<f32> = (0..10).map(|i| (i as f32 - 4.5) * 1e-10).collect();
    let mut state = AdamState::new(10);
    let mut both = params.clone();
    state.update_split(&cfg, 1e-3, Some((4, field)), &mut both, &grads);
    let apart = |range: std::ops::Range<usize>, adam: AdamConfig, lr: f32| {
        let mut p = params[range.clone()].to_vec();
        AdamState::new(p.len()).update(&adam, lr, &mut p, &grads[range]);
        p
    };
    assert_eq!(both[..4], apart(0..4, AdamConfig { eps: 1e-15, ..cfg }, 1e-2)[..]);
    assert_eq!(both[4..], apart(4..10, cfg, 1e-3)[..]);
    assert_eq!(state.t, 1);
    // The planes move by the full rate, 1e-2, however small their gradient; the MLP's
    // parameters, under its epsilon, by a small part of its own.
    for i in 0..4 {
        assert!(((both[i] - params[i]).abs() - 1e-2).abs() < 1e-4, "plane {i}: {} -> {}", params[i], both[i]);
    }
    for i in 4..10 {
        assert!((both[i] - params[i]).abs() < 1e-4, "MLP {i}: {} -> {}", params[i], both[i]);
    }
}

#[test]
fn the_mlps_l2_adds_to_its_gradient_alone_and_pulls_its_weights_towards_zero() {
    let cfg = AdamConfig { l2: 0.5, ..AdamConfig::default() };
    let field = FieldAdam { lr_mult: 10.0, eps: 1e-15, skip_untouched: false };
    let params: Vec<f32> = (0..10).map(|i| i as f32 * 0.1 - 0.45).collect();
    let grads: Vec<f32> = (0..10).map(|i| (i as f32 - 4.5) * 1e-3).collect();
    let mut state = AdamState::new(10);
    let mut with_l2 = params.clone();
    state.update_split(&cfg, 1e-3, Some((4, field)), &mut with_l2, &grads);
    // The same as no L2 with the MLP's gradients plus 0.5 times its parameters; the field's
    // entries (the first 4) as without it.
    let plain = AdamConfig { l2: 0.0, ..cfg };
    let mut added = grads.clone();
    added[4..].iter_mut().zip(&params[4..]).for_each(|(g, p)| *g += 0.5 * p);
    let mut by_hand = params.clone();
    AdamState::new(10).update_split(&plain, 1e-3, Some((4, field)), &mut by_hand, &added);
    assert_eq!(with_l2, by_hand);
    let mut without = params.clone();
    AdamState::new(10).update_split(&plain, 1e-3, Some((4, field)), &mut without, &grads);
    assert_eq!(with_l2[..4], without[..4]);
    // Where the gradient is small beside the pull, every weight moves towards zero.
    for i in 4..10 {
        assert!(with_l2[i].abs() < params[i].abs(), "MLP {i}: {} -> {}", params[i], with_l2[i]);
    }
}

#[test]
fn a_skipped_untouched_entry_keeps_its_value_and_moments() {
    let cfg = AdamConfig::default();
    let field = |skip_untouched| FieldAdam { lr_mult: 10.0, eps: 1e-15, skip_untouched };
    let params: Vec<f32> = (0..8).map(|i| i as f32 * 0.1).collect();
    let first: Vec<f32> = (0..8).map(|i| (i as f32 - 3.5) * 1e-3).collect();
    // The second step reaches neither entry 1 (the field's) nor entry 5 (the MLP's).
    let second: Vec<f32> = first.iter().enumerate().map(|(i, &g)| if i == 1 || i == 5 { 0.0 } else { g }).collect();
    let run = |skip| {
        let (mut state, mut p) = (AdamState::new(8), params.clone());
        state.update_split(&cfg, 1e-3, Some((4, field(skip))), &mut p, &first);
        let after_first = (p.clone(), state.m.clone(), state.v.clone());
        state.update_split(&cfg, 1e-3, Some((4, field(skip))), &mut p, &second);
        (after_first, (p, state.m, state.v))
    };
    let ((p1, m1, v1), (p2, m2, v2)) = run(true);
    // Skipped: the field's untouched entry as it was, its moments included.
    assert_eq!((p2[1], m2[1], v2[1]), (p1[1], m1[1], v1[1]));
    // The MLP's untouched entry moves on its momentum and its moments decay, as without the rule.
    assert!(p2[5] != p1[5] && m2[5] == cfg.beta1 * m1[5] && v2[5] == cfg.beta2 * v1[5]);
    // The touched entries take the same update either way; without the rule entry 1 moves too.
    let (_, (dense, _, _)) = run(false);
    for i in [0, 2, 3, 4, 5, 6, 7] {
        assert_eq!(p2[i], dense[i], "entry {i}");
    }
    assert!(dense[1] != p1[1], "dense Adam moves an untouched entry on its momentum");
}

fn optim(steps: u64) -> OptimConfig {
    common::optim_decaying(1e-2, 1e-3, steps)
}

#[test]
fn a_few_hundred_steps_cut_the_loss_on_a_tiny_scene_with_either_reading_of_the_planes() {
    for pre_filtered in [true, false] {
        let (rays, colours) = ball_scene(8, 16);
        let steps = 200;
        let mut trainer = Trainer::new(Model::new(small(pre_filtered)).unwrap(), optim(steps), 1);
        let losses = common::train_on_random_batches(&mut trainer, &rays, &colours, steps as usize, 5);
        let first: f32 = losses[..10].iter().sum::<f32>() / 10.0;
        let last: f32 = losses[steps as usize - 10..].iter().sum::<f32>() / 10.0;
        eprintln!("tiny scene, pre-filtered {pre_filtered}: loss {first:.5} -> {last:.5} ({:.1}x)", first / last);
        assert!(last * 5.0 <= first, "pre-filtered {pre_filtered}: the loss fell only from {first} to {last}");
    }
}

#[test]
fn training_the_planes_is_bit_for_bit_reproducible_whatever_the_thread_count() {
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| {
            let (rays, colours) = ball_scene(2, 12);
            let mut trainer = Trainer::new(Model::new(small(true)).unwrap(), optim(100), 9);
            let losses: Vec<f32> =
                (0..3).map(|_| trainer.train_step(&rays[..200], &colours[..200]).stats.loss).collect();
            (losses, trainer.params)
        })
    };
    let (one, two, three) = (run(1), run(2), run(3));
    assert!(one == two && one == three, "losses or parameters differ between thread counts");
}

#[test]
fn a_checkpoint_holds_the_planes_and_loads_back_exactly() {
    let model = Model::new(small(true)).unwrap();
    let (_dir, path) = common::checkpoint_round_trip(&model);
    // The planes are a tensor of their own, [3, R, R, C].
    let bytes = std::fs::read(&path).unwrap();
    let tensors = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    assert_eq!(tensors.tensor("tri_mip/planes").unwrap().shape(), [3, 16, 16, 4]);
    // A Mip-NeRF model of the same MLP does not take it.
    let mut other = small(true);
    other.field = Field::MipNerf;
    assert!(checkpoint::load(&path, &Model::new(other).unwrap()).is_err());
}

/// The occupancy grid's density probes read the Tri-Mip planes (at the probe's footprint), not
/// the IPE.
#[test]
fn the_occupancy_probes_of_a_tri_mip_model_read_the_planes() {
    common::assert_probes_read_the_field(&Model::new(small(true)).unwrap());
}
