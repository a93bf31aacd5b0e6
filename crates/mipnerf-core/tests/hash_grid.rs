//! The hash-grid field (`hash_grid.rs`, `Field::HashGrid`): the levels' layout, the error
//! function and Zip-NeRF's down-weighting (a point reads every level, a wider cone fades the fine
//! ones first), trilinear reads that reproduce a linear field, the backward pass as the exact
//! adjoint of the forward one, and inside the model the whole loss's gradient against finite
//! differences (world and contracted space), a short training run that cuts the loss, the same
//! bits whatever the thread count, a checkpoint that holds the tables and probes that read them.
#![allow(clippy::unwrap_used, missing_docs)]

mod common;
use common::scene::ball_scene;
use glam::Vec3;
use mipnerf_core::checkpoint;
use mipnerf_core::hash_grid::{GridSample, HashGridConfig, Levels, downweight, erf};
use mipnerf_core::model::{Field, GradWith, Mode, Model, ModelConfig, Preset, TrainBatch};
use mipnerf_core::train::{FieldAdam, OptimConfig, Trainer};
use rand::{Rng, SeedableRng, rngs::SmallRng};

/// The error function's bound (Abramowitz and Stegun 7.1.26: 1.5e-7, plus f32 rounding).
const TOL_ERF: f32 = 3e-7;
/// Sums of 8 corners times weights in f32, against the same in f64.
const TOL_TRILINEAR: f32 = 2e-6;
/// A dot product of a few thousand f32 terms, two summation orders.
const TOL_ADJOINT: f64 = 1e-5;

/// A small grid: 4 levels of 2 features from 4 to 32 cells, tables of 2^9 (levels 0 and 1 dense,
/// 2 and 3 hashed).
fn small_grid() -> HashGridConfig {
    HashGridConfig { levels: 4, features: 2, log2_table: 9, coarsest: 4, finest: 32 }
}

fn random_params(config: &HashGridConfig, seed: u64) -> Vec<f32> {
    let mut rng = SmallRng::seed_from_u64(seed);
    (0..config.num_params()).map(|_| rng.random_range(-1.0..1.0)).collect()
}

fn random_samples(n: usize, max_scale: f32, seed: u64) -> Vec<GridSample> {
    let mut rng = SmallRng::seed_from_u64(seed);
    (0..n)
        .map(|_| GridSample {
            at: Vec3::new(rng.random_range(0.0..1.0), rng.random_range(0.0..1.0), rng.random_range(0.0..1.0)),
            scale: if max_scale > 0.0 { rng.random_range(0.0..max_scale) } else { 0.0 },
        })
        .collect()
}

#[test]
fn the_levels_grow_from_the_coarsest_to_the_finest_and_hash_where_the_vertices_overflow_the_table() {
    let g = small_grid();
    g.validate().unwrap();
    let cells: Vec<usize> = (0..g.levels).map(|l| g.resolution(l)).collect();
    assert_eq!(cells, [4, 8, 16, 32]);
    // 5³ = 125 and 9³ = 729 vertices against 512 entries.
    assert_eq!((0..4).map(|l| g.is_dense(l)).collect::<Vec<_>>(), [true, false, false, false]);
    assert_eq!((0..4).map(|l| g.entries(l)).collect::<Vec<_>>(), [125, 512, 512, 512]);
    assert_eq!(g.num_params(), (125 + 3 * 512) * 2);
    assert_eq!(g.offset(2), (125 + 512) * 2);
    assert_eq!(g.encoding_dim(), 8);
    // The recipe's: 16 to 512 cells, Instant-NGP's growth.
    let r = mipnerf_core::model::HashGridRecipe::RECIPE.grid;
    assert_eq!((r.resolution(0), r.resolution(r.levels - 1)), (16, 512));
    for bad in [
        HashGridConfig { levels: 0, ..g },
        HashGridConfig { features: 0, ..g },
        HashGridConfig { log2_table: 30, ..g },
        HashGridConfig { coarsest: 64, finest: 32, ..g },
    ] {
        assert!(bad.validate().is_err(), "{bad:?} was accepted");
    }
}

#[test]
fn the_error_function_matches_its_table() {
    // erf to 7 places (Abramowitz and Stegun, table 7.1).
    for (x, want) in [(0.0, 0.0), (0.1, 0.112_462_9), (0.5, 0.520_499_9), (1.0, 0.842_700_8), (2.0, 0.995_322_3)] {
        assert!((erf(x) - want).abs() <= TOL_ERF, "erf({x}) = {}, want {want}", erf(x));
    }
    assert_eq!(erf(f32::INFINITY), 1.0);
}

#[test]
fn a_point_reads_every_level_and_a_wider_cone_fades_the_finer_levels_first() {
    assert_eq!(downweight(0.0, 512), 1.0);
    // One cell's width as the standard deviation: erf(1 / sqrt(8)).
    assert!((downweight(1.0 / 64.0, 64) - erf(1.0 / 8f32.sqrt())).abs() < TOL_ERF);
    let scales = [1e-4, 1e-3, 1e-2, 0.1];
    for cells in [16, 64, 512] {
        let w: Vec<f32> = scales.iter().map(|&s| downweight(s, cells)).collect();
        // Never up, and down by the widest (f32's erf is 1 exactly past about 3.9).
        assert!(w.windows(2).all(|p| p[1] <= p[0]) && w[3] < w[0], "{cells} cells: {w:?} does not fall with the scale");
    }
    for &s in &scales {
        let w: Vec<f32> = [16, 64, 512].iter().map(|&n| downweight(s, n)).collect();
        assert!(w.windows(2).all(|p| p[1] <= p[0]), "scale {s}: {w:?} does not fall with the level");
    }
    // A footprint of a tenth of the box leaves the coarsest level and silences the finest.
    assert!(downweight(0.1, 16) > 0.2 && downweight(0.1, 512) < 0.01);
    // In the encoding: the same point, wider, has smaller fine features.
    let g = small_grid();
    let levels = Levels::new(g);
    let params = random_params(&g, 1);
    let at = Vec3::new(0.31, 0.62, 0.47);
    let (mut point, mut wide) = (vec![0.0; 8], vec![0.0; 8]);
    levels.encode(&params, &GridSample { at, scale: 0.0 }, &mut point);
    levels.encode(&params, &GridSample { at, scale: 0.05 }, &mut wide);
    for l in 0..4 {
        let w = downweight(0.05, g.resolution(l));
        for f in 0..2 {
            assert!((wide[2 * l + f] - w * point[2 * l + f]).abs() <= TOL_TRILINEAR, "level {l}");
        }
    }
}

#[test]
fn a_dense_level_reads_a_linear_field_exactly_and_every_level_is_continuous_across_cells() {
    // One dense level of 8 cells whose vertices hold a linear function of their position.
    let g = HashGridConfig { levels: 1, features: 1, log2_table: 10, coarsest: 8, finest: 8 };
    assert!(g.is_dense(0));
    let linear = |p: Vec3| 0.3 + 0.5 * p.x - 1.25 * p.y + 2.0 * p.z;
    let mut params = vec![0.0; g.num_params()];
    for k in 0..9 {
        for j in 0..9 {
            for i in 0..9 {
                params[i + 9 * (j + 9 * k)] = linear(Vec3::new(i as f32, j as f32, k as f32) / 8.0);
            }
        }
    }
    let levels = Levels::new(g);
    for s in random_samples(200, 0.0, 2) {
        let mut out = [0.0];
        levels.encode(&params, &GridSample { scale: 0.0, ..s }, &mut out);
        assert!((out[0] - linear(s.at)).abs() <= TOL_TRILINEAR, "at {:?}: {} against {}", s.at, out[0], linear(s.at));
    }
    // Hashed levels too are continuous: a hair either side of a cell's face reads the same.
    let g = small_grid();
    let (levels, params) = (Levels::new(g), random_params(&g, 3));
    for l in 0..g.levels {
        let face = 2.0 / g.resolution(l) as f32;
        let (mut a, mut b) = (vec![0.0; 8], vec![0.0; 8]);
        levels.encode(&params, &GridSample { at: Vec3::new(face - 1e-6, 0.4, 0.7), scale: 0.0 }, &mut a);
        levels.encode(&params, &GridSample { at: Vec3::new(face + 1e-6, 0.4, 0.7), scale: 0.0 }, &mut b);
        let gap = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max);
        assert!(gap < 1e-3, "level {l}: features jump by {gap} across a face");
    }
}

#[test]
fn the_backward_pass_is_the_exact_adjoint_and_the_same_whatever_the_thread_count() {
    let g = small_grid();
    let levels = Levels::new(g);
    let samples = random_samples(300, 0.05, 4);
    let mut rng = SmallRng::seed_from_u64(5);
    let d_x: Vec<f32> = (0..samples.len() * g.encoding_dim()).map(|_| rng.random_range(-1.0..1.0)).collect();
    let params = random_params(&g, 6);
    // <encode(p), d> = <p, encode*(d)>, the encoding being linear in the tables.
    let mut x = vec![0.0; d_x.len()];
    levels.encode_many(&params, &samples, &mut x);
    // Level by level over the samples, the same bits as sample by sample.
    let mut one = vec![0.0; g.encoding_dim()];
    for (s, want) in samples.iter().zip(x.chunks_exact(g.encoding_dim())) {
        levels.encode(&params, s, &mut one);
        assert_eq!(one, want);
    }
    let lhs: f64 = x.iter().zip(&d_x).map(|(a, b)| f64::from(*a) * f64::from(*b)).sum();
    let backward = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        let mut grad = vec![0.0; g.num_params()];
        // Two batches, as a step's chunks come.
        let (s0, s1) = samples.split_at(120);
        let (d0, d1) = d_x.split_at(120 * g.encoding_dim());
        pool.install(|| levels.encode_backward_batch(&[(s0, d0), (s1, d1)], &mut grad));
        grad
    };
    let grad = backward(1);
    let rhs: f64 = params.iter().zip(&grad).map(|(a, b)| f64::from(*a) * f64::from(*b)).sum();
    assert!((lhs - rhs).abs() <= TOL_ADJOINT * lhs.abs().max(1.0), "<Ap, d> = {lhs}, <p, A*d> = {rhs}");
    assert!(grad.iter().filter(|&&v| v != 0.0).count() > 1000, "the samples reach too few entries");
    assert_eq!(grad, backward(2));
    assert_eq!(grad, backward(3));
}

/// A small model of the hash-grid field: the small grid, a 2 x 32 MLP.
fn small(half_side: f32) -> ModelConfig {
    let mut cfg = Preset::Tiny.config();
    cfg.net_depth = 2;
    cfg.net_width = 32;
    cfg.net_width_condition = 16;
    cfg.num_samples = 16;
    cfg.field = Field::HashGrid { grid: small_grid(), half_side };
    cfg
}

#[test]
fn the_whole_losss_gradient_through_the_grid_and_the_mlp_matches_finite_differences() {
    for unbounded in [false, true] {
        let (rays, colours) = ball_scene(2, 6);
        let mut cfg = small(if unbounded { 2.0 } else { 1.5 });
        // One level: the fine level's intervals carry no gradient by design (see training.rs).
        cfg.num_levels = 1;
        cfg.unbounded = unbounded;
        let model = Model::new(cfg).unwrap();
        assert!(model.field_params() == small_grid().num_params() && model.field_params() < model.num_params());
        let mut params = model.init_params(3);
        let mut rng = SmallRng::seed_from_u64(4);
        for p in &mut params[..model.field_params()] {
            *p = rng.random_range(-0.5..0.5);
        }
        let (mode, batch) =
            (Mode::Train { seed: 1, step: 0 }, TrainBatch { rays: &rays[..40], targets: &colours[..40] });
        let mut grads = vec![0.0; model.num_params()];
        model.loss_and_grad(&params, batch, mode, &mut grads, GradWith::default());
        let reached: Vec<usize> = (0..model.field_params()).filter(|&i| grads[i] != 0.0).collect();
        assert!(reached.len() > 100, "unbounded {unbounded}: the batch reaches {} grid parameters", reached.len());
        let mut picks: Vec<(String, usize)> =
            (0..24).map(|_| ("grid".to_owned(), reached[rng.random_range(0..reached.len())])).collect();
        for l in &model.mlps()[0].layers {
            picks.extend((0..4).map(|_| (l.name.clone(), l.kernel + rng.random_range(0..l.fan_in * l.fan_out))));
        }
        common::assert_gradients_match_finite_differences(
            picks,
            &grads,
            &mut params,
            common::batch_loss(&model, batch, mode),
        );
    }
}

fn optim(steps: u64) -> OptimConfig {
    OptimConfig {
        field: Some(FieldAdam { lr_mult: 2.0, eps: 1e-15, skip_untouched: false }),
        ..common::optim_decaying(1e-2, 1e-3, steps)
    }
}

#[test]
fn a_few_hundred_steps_cut_the_loss_on_a_tiny_scene_and_the_bits_do_not_depend_on_the_threads() {
    let (rays, colours) = ball_scene(8, 16);
    let steps = 200;
    let mut trainer = Trainer::new(Model::new(small(1.5)).unwrap(), optim(steps), 1);
    let losses = common::train_on_random_batches(&mut trainer, &rays, &colours, steps as usize, 5);
    let first: f32 = losses[..10].iter().sum::<f32>() / 10.0;
    let last: f32 = losses[steps as usize - 10..].iter().sum::<f32>() / 10.0;
    eprintln!("tiny scene, hash grid: loss {first:.5} -> {last:.5} ({:.1}x)", first / last);
    assert!(last * 5.0 <= first, "the loss fell only from {first} to {last}");
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| {
            // With the grid's weight decay, whose sums are blocked too.
            let model = Model::new(ModelConfig { grid_decay_mult: 0.01, ..small(1.5) }).unwrap();
            let mut trainer = Trainer::new(model, optim(100), 9);
            let losses: Vec<f32> =
                (0..3).map(|_| trainer.train_step(&rays[..200], &colours[..200]).stats.loss).collect();
            (losses, trainer.params)
        })
    };
    let (one, two) = (run(1), run(2));
    assert!(one == two, "losses or parameters differ between thread counts");
}

#[test]
fn a_checkpoint_holds_the_tables_and_loads_back_exactly() {
    let model = Model::new(small(1.5)).unwrap();
    let (_dir, path) = common::checkpoint_round_trip(&model);
    let bytes = std::fs::read(&path).unwrap();
    let tensors = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    assert_eq!(tensors.tensor("hash_grid/tables").unwrap().shape(), [small_grid().num_params() / 2, 2]);
    // A Mip-NeRF model of the same MLP does not take it.
    let mut other = small(1.5);
    other.field = Field::MipNerf;
    assert!(checkpoint::load(&path, &Model::new(other).unwrap()).is_err());
}

/// The occupancy grid's density probes read the grid at the probe's footprint.
#[test]
fn the_occupancy_probes_of_a_hash_grid_model_read_the_grid() {
    common::assert_probes_read_the_field(&Model::new(small(1.5)).unwrap());
}

#[test]
fn a_grid_that_cannot_be_built_is_an_error_naming_it() {
    let mut cfg = small(1.5);
    cfg.field = Field::HashGrid { grid: HashGridConfig { levels: 40, ..small_grid() }, half_side: 1.5 };
    let e = Model::new(cfg.clone()).unwrap_err().to_string();
    assert!(e.contains("levels 40"), "{e}");
    cfg.field = Field::HashGrid { grid: small_grid(), half_side: f32::NAN };
    let e = Model::new(cfg).unwrap_err().to_string();
    assert!(e.contains("half side"), "{e}");
    // The planes' total variation is the Tri-Mip field's alone.
    let mut cfg = small(1.5);
    cfg.planes_tv_mult = 0.5;
    assert!(Model::new(cfg).is_err());
    // And the grid's weight decay the hash grid's: a positive number, with that field.
    let mut cfg = small(1.5);
    for bad in [-0.1, f32::NAN] {
        cfg.grid_decay_mult = bad;
        let e = Model::new(cfg.clone()).unwrap_err().to_string();
        assert!(e.contains("grid_decay_mult"), "{e}");
    }
    cfg.grid_decay_mult = 0.1;
    assert!(Model::new(cfg).is_ok());
    let cfg = ModelConfig { grid_decay_mult: 0.1, ..Preset::Tiny.config() };
    assert!(Model::new(cfg).unwrap_err().to_string().contains("hash-grid field"));
}

/// Sums of squares of a few thousand f32 values in f64, against the same term by term.
const TOL_DECAY: f64 = 1e-12;

#[test]
fn the_weight_decay_is_each_levels_mean_square_and_its_gradient_matches_finite_differences() {
    let grid = small_grid();
    let tables = random_params(&grid, 11);
    // Above the recipe's 0.1, so that the decay's gradient on an entry stands well clear of the
    // finite differences' tolerance.
    let weight = 2.0;
    let mut grad = vec![0.5f32; grid.num_params()];
    let decay = grid.weight_decay(&tables, weight, &mut grad);
    // Level by level: the mean square over its values, so that the dense coarse levels weigh as
    // much as the hashed ones with more entries.
    let mut expected = 0.0f64;
    for level in 0..grid.levels {
        let values = &tables[grid.offset(level)..grid.offset(level + 1)];
        let mean_square = values.iter().map(|&v| f64::from(v) * f64::from(v)).sum::<f64>() / values.len() as f64;
        expected += f64::from(weight) * mean_square;
        // The gradient is added to what is there: 2 weight v / count.
        for (i, &v) in values.iter().enumerate() {
            let want = 0.5 + 2.0 * weight * v / values.len() as f32;
            assert!((grad[grid.offset(level) + i] - want).abs() <= 1e-6, "level {level} entry {i}");
        }
    }
    assert!((decay - expected).abs() <= TOL_DECAY * expected, "{decay} against {expected}");
    assert!(grid.entries(0) < grid.entries(3), "the levels differ in size");

    // Through the model: the loss carries the decay as its regulariser, and the loss's gradient
    // matches finite differences on grid entries no ray reaches (the decay's alone) and others.
    let (rays, colours) = ball_scene(2, 6);
    let mut cfg = small(1.5);
    cfg.num_levels = 1;
    let plain = Model::new(cfg.clone()).unwrap();
    cfg.grid_decay_mult = weight;
    let model = Model::new(cfg).unwrap();
    let mut params = model.init_params(3);
    params[..model.field_params()].copy_from_slice(&tables);
    let (mode, batch) = (Mode::Train { seed: 1, step: 0 }, TrainBatch { rays: &rays[..40], targets: &colours[..40] });
    let mut grads = vec![0.0; model.num_params()];
    let stats = model.loss_and_grad(&params, batch, mode, &mut grads, GradWith::default());
    let mut plain_grads = vec![0.0; model.num_params()];
    let plain_stats = plain.loss_and_grad(&params, batch, mode, &mut plain_grads, GradWith::default());
    assert!((f64::from(stats.regulariser) - expected).abs() <= 1e-6 * expected, "{}", stats.regulariser);
    assert!((stats.loss - plain_stats.loss - stats.regulariser).abs() <= 1e-6 * stats.loss);
    let unreached: Vec<usize> = (0..model.field_params()).filter(|&i| plain_grads[i] == 0.0).collect();
    let reached: Vec<usize> = (0..model.field_params()).filter(|&i| plain_grads[i] != 0.0).collect();
    assert!(!unreached.is_empty() && !reached.is_empty());
    let mut rng = SmallRng::seed_from_u64(5);
    let mut picks = Vec::new();
    for (what, from) in [("unreached", &unreached), ("reached", &reached)] {
        picks.extend((0..12).map(|_| (what.to_owned(), from[rng.random_range(0..from.len())])));
    }
    common::assert_gradients_match_finite_differences(
        picks,
        &grads,
        &mut params,
        common::batch_loss(&model, batch, mode),
    );
}

#[test]
fn coarse_to_fine_reads_the_fine_levels_faintly_first_differentiates_exactly_and_ends_as_the_plain_field() {
    let (rays, colours) = ball_scene(2, 6);
    let mut plain = small(1.5);
    plain.num_levels = 1;
    let c2f = ModelConfig { coarse_to_fine_steps: 100, ..plain.clone() };
    let (model, plain) = (Model::new(c2f).unwrap(), Model::new(plain).unwrap());
    let mut params = model.init_params(3);
    let mut rng = SmallRng::seed_from_u64(4);
    for p in &mut params[..model.field_params()] {
        *p = rng.random_range(-0.5..0.5);
    }
    let batch = TrainBatch { rays: &rays[..40], targets: &colours[..40] };
    let run = |model: &Model, step: u32| {
        let mut grads = vec![0.0; model.num_params()];
        let loss = model.loss_and_grad(&params, batch, Mode::Train { seed: 1, step }, &mut grads, GradWith::default());
        (loss.loss, grads)
    };
    // From its last step on (and in evaluation), the field read at the samples' own footprints.
    assert_eq!(run(&model, 100), run(&plain, 100));
    // At step 0 the floor (a sixteenth of the box: a standard deviation of 1/32, added to the
    // samples' own) weighs the finest level's 32 cells at most erf(1/sqrt(8)) = 0.38 and the
    // coarsest's 4 cells 1.00: each finer level learns less than it would (0.95, 0.89, 0.86,
    // 0.73 of its own gradient here; the MLP's response moves them all).
    let ((_, start), (_, own)) = (run(&model, 0), run(&plain, 0));
    let grid = small_grid();
    let norm = |g: &[f32], level: usize| {
        let end = if level + 1 < grid.levels { grid.offset(level + 1) } else { grid.num_params() };
        g[grid.offset(level)..end].iter().map(|v| f64::from(*v).powi(2)).sum::<f64>().sqrt()
    };
    let ratios: Vec<f64> = (0..grid.levels).map(|l| norm(&start, l) / norm(&own, l)).collect();
    assert!(ratios.windows(2).all(|w| w[1] < w[0]), "finer levels learn less: {ratios:.3?}");
    assert!(ratios[0] > 0.9 && ratios[grid.levels - 1] < 0.8, "the coarsest and the finest level: {ratios:.3?}");
    // The floor is a constant of the step: the gradient through it is the loss's.
    let reached: Vec<usize> = (0..model.field_params()).filter(|&i| start[i] != 0.0).collect();
    let mut picks: Vec<(String, usize)> =
        (0..24).map(|_| ("grid".to_owned(), reached[rng.random_range(0..reached.len())])).collect();
    picks.extend((0..8).map(|_| ("mlp".to_owned(), rng.random_range(model.field_params()..model.num_params()))));
    let mode = Mode::Train { seed: 1, step: 0 };
    common::assert_gradients_match_finite_differences(
        picks,
        &start,
        &mut params,
        common::batch_loss(&model, batch, mode),
    );
    // The Mip-NeRF MLP reads every frequency at the cone's own scale: no floor for it.
    let refused = Model::new(ModelConfig { coarse_to_fine_steps: 100, ..Preset::Tiny.config() });
    assert!(refused.is_err_and(|e| e.to_string().contains("coarse_to_fine_steps")));
}
