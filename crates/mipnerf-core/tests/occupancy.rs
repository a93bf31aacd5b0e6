//! Occupancy-guided sampling on the CPU: a full grid is the paper's sampler bit for bit, the voxel
//! traversal finds exactly the occupied cells along a ray, coarse samples stay in the occupied
//! spans, empty rays render the background and add no gradient, the grid learns where the density is, and it survives a
//! checkpoint.
#![allow(clippy::unwrap_used, missing_docs)]

mod common;
use common::scene::{BALL_RADIUS, ball_scene};
use glam::Vec3;
use mipnerf_core::bf16::Precision;
use mipnerf_core::checkpoint::{self, Checkpoint};
use mipnerf_core::compare::{Tolerance, assert_close};
use mipnerf_core::contract::UNBOUNDED_FAR;
use mipnerf_core::mip::Gaussian;
use mipnerf_core::mlp::MlpCache;
use mipnerf_core::model::{GradScratch, LevelOutput, Levels, LossStats, Mode, Model, ModelConfig, Preset};
use mipnerf_core::model::{GradWith, TrainBatch};
use mipnerf_core::occupancy::{CARVED, CONTRACTED_BOUND, DensityField, OccupancyConfig, OccupancyGrid};
use mipnerf_core::rng::{RayRng, Stream};
use mipnerf_core::sampling::{sample_along_rays, sample_along_segments};
use mipnerf_core::train::{AdamState, OptimConfig, Trainer};
use rand::{Rng, SeedableRng, rngs::SmallRng};

/// Rays rendered in chunks of different composition agree to the matrix product's rounding (the
/// same bound as chunked rendering elsewhere: about 1e-5 relative).
const TOL_CHUNKING: Tolerance = Tolerance::new(1e-6, 1e-5);

/// How far (world units) a test point must be from a cell face before its cell is trusted: the
/// traversal computes face crossings in `f32`.
const FACE_MARGIN: f32 = 1e-4;

fn model() -> Model {
    Model::new(ModelConfig { num_samples: 16, ..Preset::Tiny.config() }).unwrap()
}

/// A warmed-up grid over `[-1.5, 1.5]³` whose cell `i` is occupied when `occupied(centre)`.
fn grid_where(resolution: usize, mut occupied: impl FnMut(Vec3) -> bool) -> OccupancyGrid {
    let config = OccupancyConfig { resolution, ..OccupancyConfig::default() };
    let probe = OccupancyGrid::new(config).unwrap();
    let opacity = (0..resolution.pow(3)).map(|i| if occupied(probe.cell_center(i)) { 1.0 } else { 0.0 }).collect();
    OccupancyGrid::from_state(config, opacity, true).unwrap()
}

fn outputs_flat(o: &[LevelOutput]) -> Vec<f32> {
    o.iter().flat_map(|l| [l.rgb[0], l.rgb[1], l.rgb[2], l.distance, l.acc]).collect()
}

/// One training step's loss and gradient of `m` at `params` on a batch, with the paper's sampler
/// and guided by `grid` (seed 7, step 11).
fn paper_and_guided(
    m: &Model,
    params: &[f32],
    batch: TrainBatch<'_>,
    grid: &OccupancyGrid,
) -> ((LossStats, Vec<f32>), (LossStats, Vec<f32>)) {
    let mode = Mode::Train { seed: 7, step: 11 };
    let run = |with: GradWith<'_>| {
        let mut g = vec![0.0; m.num_params()];
        let stats = m.loss_and_grad(params, batch, mode, &mut g, with);
        (stats, g)
    };
    (run(GradWith::default()), run(GradWith { grid: Some(grid), ..GradWith::default() }))
}

#[test]
fn a_full_grid_samples_renders_and_trains_exactly_as_the_paper() {
    let m = model();
    let (rays, colours) = ball_scene(4, 8);
    let params = m.init_params(3);
    let full = OccupancyGrid::new(OccupancyConfig::default()).unwrap();
    assert!(full.is_full());
    let ((paper, g_paper), (guided, g_full)) =
        paper_and_guided(&m, &params, TrainBatch { rays: &rays, targets: &colours }, &full);
    assert_eq!(paper, guided);
    assert_eq!(
        g_paper.iter().map(|g| g.to_bits()).collect::<Vec<_>>(),
        g_full.iter().map(|g| g.to_bits()).collect::<Vec<_>>()
    );
    assert_eq!(m.render(&params, &rays), m.render_guided(&params, &rays, Some(&full)));
    // Training with a grid still in its warm-up (every cell occupied) is training without one.
    let optim = OptimConfig::default();
    let mut plain = Trainer::new(m.clone(), optim.clone(), 1);
    let mut with_grid = Trainer::new(m.clone(), optim, 1);
    with_grid.occupancy =
        Some(OccupancyGrid::new(OccupancyConfig { warmup_steps: 100, ..OccupancyConfig::default() }).unwrap());
    for _ in 0..3 {
        assert_eq!(plain.train_step(&rays, &colours), with_grid.train_step(&rays, &colours));
    }
    assert_eq!(plain.params, with_grid.params);
}

#[test]
fn the_traversal_finds_exactly_the_occupied_cells_along_each_ray() {
    let mut rng = SmallRng::seed_from_u64(11);
    let grid = grid_where(16, |_| rng.random_bool(0.3));
    let (rays, _) = ball_scene(6, 6);
    let h = grid.cell_size();
    let b = grid.config.bound;
    let mut bad = Vec::new();
    let mut checked = 0;
    for (k, r) in rays.iter().enumerate() {
        let mut spans = Vec::new();
        // The axis alone (a ray of zero radius): exactly the cells it crosses.
        grid.ray_segments(&mipnerf_core::Ray { radius: 0.0, ..*r }, &mut spans);
        for w in spans.windows(2) {
            assert!(w[0][1] < w[1][0], "ray {k}: spans overlap or touch: {spans:?}");
        }
        let n = 4000;
        for i in 0..n {
            let t = r.near + (r.far - r.near) * (i as f32 + 0.5) / n as f32;
            let p = r.origin + r.direction * t;
            let q = (p + Vec3::splat(b)) / h;
            let frac = q - q.floor();
            let dir_len = r.direction.length();
            if (0..3).any(|a| frac[a].min(1.0 - frac[a]) * h < FACE_MARGIN * dir_len.max(1.0)) {
                continue;
            }
            let inside = p.abs().max_element() < b;
            let want = inside && grid.is_occupied(q.x as usize, q.y as usize, q.z as usize);
            let got = spans.iter().any(|s| s[0] <= t && t <= s[1]);
            checked += 1;
            if got != want {
                bad.push(format!("ray {k} t {t}: in spans {got}, occupied {want} ({spans:?})"));
            }
        }
    }
    assert!(checked > 10_000, "only {checked} points checked");
    assert!(bad.is_empty(), "{} of {checked} points disagree:\n{}", bad.len(), bad[..bad.len().min(20)].join("\n"));
}

#[test]
fn a_cone_wider_than_a_cell_samples_the_cells_its_footprint_covers() {
    // A 2x2x2 block of occupied cells at the centre of a 16³ grid over [-1.5, 1.5]³ (cells h =
    // 0.1875 wide, the block's y cells are 7 and 8).
    let grid = grid_where(16, |c| c.abs().max_element() < 0.1);
    let h = grid.cell_size();
    // Rays along x at height y, in the cube for t in [1.5, 4.5].
    let spans = |y: f32, radius: f32| {
        let ray = mipnerf_core::Ray {
            origin: Vec3::new(-3.0, y, 0.05),
            direction: Vec3::X,
            viewdir: Vec3::X,
            radius,
            lossmult: 1.0,
            near: 0.5,
            far: 5.5,
        };
        let mut s = Vec::new();
        grid.ray_segments(&ray, &mut s);
        s
    };
    let (beside, two_away) = (1.5 * h, 2.5 * h); // y cells 9 and 10
    assert!(spans(beside, 0.0).is_empty(), "the axis alone meets no occupied cell");
    // A thin cone (a full-scale pixel's) is dilated by one cell: beside the block, it sees it.
    assert_eq!(spans(beside, 1e-4).len(), 1, "{:?}", spans(beside, 1e-4));
    assert!(spans(two_away, 1e-4).is_empty(), "{:?}", spans(two_away, 1e-4));
    // A footprint of two cells where it leaves the cube (2 r / h = 2 at t = 4.5): two cells of
    // reach, so the x cells 5 to 10 around the block.
    let wide = spans(two_away, h / 4.5);
    assert_eq!(wide.len(), 1, "{wide:?}");
    let [t0, t1] = wide[0];
    assert!((t1 - t0 - 6.0 * h).abs() < 1e-4 && (t0 + t1) / 2.0 > 2.9 && (t0 + t1) / 2.0 < 3.1, "{wide:?}");
}

#[test]
fn coarse_samples_are_stratified_inside_the_occupied_spans() {
    let jitter = Some(RayRng::new(1, 2, Stream::SampleJitter, 3));
    for j in [None, jitter] {
        let (mut a, mut b) = (vec![0.0; 17], vec![0.0; 17]);
        sample_along_rays(2.0, 6.0, false, j, &mut a);
        sample_along_segments(&[[2.0, 6.0]], false, j, &mut b);
        assert_eq!(a, b, "one span is the paper's sampler");
    }
    let spans = [[2.0f32, 2.5], [3.0, 3.25], [4.0, 5.25]];
    let n = 32;
    for j in [None, jitter] {
        let mut t = vec![0.0; n + 1];
        sample_along_segments(&spans, false, j, &mut t);
        assert!(t.windows(2).all(|w| w[0] <= w[1]), "sorted: {t:?}");
        for (i, x) in t.iter().enumerate() {
            assert!(spans.iter().any(|s| s[0] <= *x && *x <= s[1]), "edge {i} = {x} outside {spans:?}");
        }
        // An edge at each end of every span: no interval straddles a gap, and each gap is
        // exactly one interval.
        for s in spans {
            assert!(t.contains(&s[0]) && t.contains(&s[1]), "span {s:?} has no edge at an end: {t:?}");
        }
        let gaps: Vec<[f32; 2]> = t
            .windows(2)
            .filter(|w| !spans.iter().any(|s| s[0] <= w[0] && w[1] <= s[1]))
            .map(|w| [w[0], w[1]])
            .collect();
        assert_eq!(gaps, vec![[2.5, 3.0], [3.25, 4.0]], "{t:?}");
        // The 30 intervals inside spans shared by length (0.5 : 0.25 : 1.25 of 2.0), one each
        // first: 1 + 27 · cumulative share rounded.
        let per_span: Vec<usize> =
            spans.iter().map(|s| t.windows(2).filter(|w| s[0] <= w[0] && w[1] <= s[1]).count()).collect();
        assert_eq!(per_span, vec![8, 4, 18], "{t:?}");
        if j.is_none() {
            // Evenly spaced inside each span.
            for (s, &m) in spans.iter().zip(&per_span) {
                for w in t.windows(2).filter(|w| s[0] <= w[0] && w[1] <= s[1]) {
                    assert!((w[1] - w[0] - (s[1] - s[0]) / m as f32).abs() < 1e-6, "step {w:?} in {s:?}");
                }
            }
        }
    }
}

#[test]
fn too_many_spans_for_the_samples_join_across_the_narrowest_gaps() {
    // Five spans need 9 intervals; with 6 the two narrowest gaps (0.1 and 0.2) are joined,
    // leaving three spans and two gaps: one interval each, and one to spare.
    let spans = [[1.0f32, 1.5], [1.6, 2.0], [3.0, 3.5], [3.7, 4.0], [5.0, 5.5]];
    let mut t = vec![0.0; 7];
    sample_along_segments(&spans, false, None, &mut t);
    let joined = [[1.0f32, 2.0], [3.0, 4.0], [5.0, 5.5]];
    for s in joined {
        assert!(t.contains(&s[0]) && t.contains(&s[1]), "joined span {s:?} has no edge at an end: {t:?}");
    }
    assert!(t.windows(2).all(|w| w[0] <= w[1]) && t[0] == 1.0 && t[6] == 5.5, "{t:?}");
    // So few samples that only one span fits: the paper's sampler over their hull.
    let mut two = vec![0.0; 3];
    let mut hull = vec![0.0; 3];
    sample_along_segments(&spans, false, None, &mut two);
    sample_along_rays(1.0, 5.5, false, None, &mut hull);
    assert_eq!(two, hull);
}

#[test]
fn the_last_level_alone_is_the_last_level_of_every_levels_render_bit_for_bit() {
    // Rendering the last level alone runs the earlier levels' densities without their colour
    // layers; the resampling reads only their weights, so nothing of the last level may change:
    // one MLP and two, one ray per pixel and 2x2, with and without a partial grid, and bf16
    // where this CPU has a kernel for it.
    let (rays, _) = ball_scene(4, 12);
    let tiny = ModelConfig { num_samples: 16, ..Preset::Tiny.config() };
    let grid = grid_where(32, |c| c.length() < BALL_RADIUS);
    let configs = [
        ("mipnerf", tiny.clone()),
        ("nerf, two MLPs", tiny.clone().nerf()),
        ("nerf, 2x2 rays per pixel", ModelConfig { supersample: 2, ..tiny.clone().nerf() }),
    ];
    let mut bf16 = Model::new(tiny).unwrap();
    let with_bf16 = bf16.set_precision(Precision::Bf16).is_ok().then_some(("mipnerf, bf16", bf16));
    let models = configs.into_iter().map(|(name, c)| (name, Model::new(c).unwrap())).chain(with_bf16);
    let mut checked = 0;
    for (name, m) in models {
        let params = m.init_params(9);
        let levels = m.config().num_levels;
        for grid in [None, Some(&grid)] {
            let all = m.render_levels(&params, &rays, grid, Levels::All);
            let last = m.render_levels(&params, &rays, grid, Levels::Last);
            let pixels = rays.len() / m.rays_per_pixel();
            assert_eq!((all.len(), last.len()), (pixels * levels, pixels), "{name}");
            let want: Vec<LevelOutput> = all.chunks(levels).map(|l| l[levels - 1]).collect();
            let (last, want) = (outputs_flat(&last), outputs_flat(&want));
            let differ = last.iter().zip(&want).filter(|(a, b)| a.to_bits() != b.to_bits()).count();
            assert_eq!(differ, 0, "{name}, grid {}: {differ} of {} values differ", grid.is_some(), want.len());
            // The coarse level's colour is not the fine level's: the test would see a mix-up.
            assert!(all.chunks(levels).any(|l| l[0].rgb != l[levels - 1].rgb), "{name}");
            checked += 1;
        }
    }
    assert!(checked >= 6, "{checked} cases");
}

#[test]
fn rays_that_meet_no_occupied_cell_render_the_background_and_add_no_gradient() {
    let m = model();
    let params = m.init_params(5);
    // Occupied: the middle of the ball. The 24-pixel views' cones reach two cells beyond it.
    let grid = grid_where(32, |c| c.length() < 0.5 * BALL_RADIUS);
    let (rays, colours) = ball_scene(4, 24);
    let mut spans = Vec::new();
    let (hit, miss): (Vec<usize>, Vec<usize>) = (0..rays.len()).partition(|&i| {
        spans.clear();
        grid.ray_segments(&rays[i], &mut spans);
        !spans.is_empty()
    });
    assert!(hit.len() > 50 && miss.len() > 50, "{} rays hit, {} miss", hit.len(), miss.len());
    let out = m.render_guided(&params, &rays, Some(&grid));
    for &i in &miss {
        for level in &out[2 * i..2 * i + 2] {
            assert_eq!(*level, LevelOutput { rgb: [1.0; 3], distance: rays[i].near, acc: 0.0 }, "ray {i}");
        }
    }
    // The rays that hit render the same alone as among the empty ones.
    let hit_rays: Vec<_> = hit.iter().map(|&i| rays[i]).collect();
    let alone = m.render_guided(&params, &hit_rays, Some(&grid));
    let among: Vec<LevelOutput> = hit.iter().flat_map(|&i| out[2 * i..2 * i + 2].to_vec()).collect();
    assert_close("hit rays", &outputs_flat(&among), &outputs_flat(&alone), TOL_CHUNKING);
    // A batch of empty rays: the background's error, and no gradient at all; on white, and on
    // random backgrounds, where each empty ray's error is against its own pixel's colour (its
    // index in the batch).
    let miss_rays: Vec<_> = miss.iter().map(|&i| rays[i]).collect();
    let miss_targets: Vec<_> = miss.iter().map(|&i| colours[i]).collect();
    let mode = Mode::Train { seed: 0, step: 0 };
    let random = Model::new(ModelConfig { random_bkgd: true, ..m.config().clone() }).unwrap();
    for m in [&m, &random] {
        let mut g = vec![0.0; m.num_params()];
        let mut scratch = GradScratch::default();
        let stats = m.loss_and_grad(
            &params,
            TrainBatch { rays: &miss_rays, targets: &miss_targets },
            mode,
            &mut g,
            GradWith { scratch: Some(&mut scratch), grid: Some(&grid) },
        );
        assert!(g.iter().all(|&x| x == 0.0), "empty rays moved the parameters");
        let background = |i: usize| {
            if m.config().random_bkgd { mipnerf_core::rng::random_background(0, 0, i as u32) } else { [1.0; 3] }
        };
        let want: f64 = miss_targets
            .iter()
            .enumerate()
            .flat_map(|(i, c)| {
                let bg = background(i);
                (0..3).map(move |k| f64::from(bg[k] - c[k]).powi(2))
            })
            .sum::<f64>()
            / (3.0 * miss_targets.len() as f64);
        for (l, mse) in stats.mse.iter().enumerate() {
            let random = m.config().random_bkgd;
            assert!(
                (f64::from(*mse) - want).abs() <= 1e-6 * want.max(1e-6),
                "random {random} level {l}: mse {mse}, want {want}"
            );
        }
    }
    // ... and in evaluation it renders on white, as before.
    for level in &random.render_guided(&params, &miss_rays[..3], Some(&grid)) {
        assert_eq!(level.rgb, [1.0; 3]);
    }
}

#[test]
fn the_grid_learns_where_the_density_is() {
    let (rays, colours) = ball_scene(8, 16);
    let steps = 300;
    let optim = common::optim_decaying(5e-3, 5e-4, steps);
    let mut trainer = Trainer::new(Model::new(Preset::Tiny.config()).unwrap(), optim, 1);
    // A threshold of 0.1 over a cell (σ > 0.56 here): the default, 0.01, keeps cells whose
    // density the model has only begun to lower, and on this scene without masks keeps most.
    let config = OccupancyConfig {
        resolution: 16,
        warmup_steps: 100,
        update_every: 10,
        threshold: 0.1,
        ..OccupancyConfig::default()
    };
    trainer.occupancy = Some(OccupancyGrid::new(config).unwrap());
    let mut rng = SmallRng::seed_from_u64(5);
    for _ in 0..steps {
        let idx: Vec<usize> = (0..256).map(|_| rng.random_range(0..rays.len())).collect();
        let r: Vec<_> = idx.iter().map(|&i| rays[i]).collect();
        let c: Vec<_> = idx.iter().map(|&i| colours[i]).collect();
        trainer.train_step(&r, &c);
    }
    let grid = trainer.occupancy.as_ref().unwrap();
    assert!(grid.warmed_up && !grid.is_full());
    let (mut core, mut core_occ, mut far, mut far_empty) = (0, 0, 0, 0);
    for i in 0..16usize.pow(3) {
        let c = grid.cell_center(i);
        let (x, y, z) = (i % 16, (i / 16) % 16, i / 256);
        if c.length() < 0.5 * BALL_RADIUS {
            core += 1;
            core_occ += usize::from(grid.is_occupied(x, y, z));
        } else if c.length() > BALL_RADIUS + 0.4 && c.z.abs() < 1.0 {
            far += 1;
            far_empty += usize::from(!grid.is_occupied(x, y, z));
        }
    }
    eprintln!("ball core: {core_occ}/{core} occupied; far from the ball: {far_empty}/{far} empty");
    assert_eq!(core_occ, core, "cells inside the ball were dropped");
    assert!(far_empty * 2 > far, "only {far_empty} of {far} cells far from the ball were found empty");
}

#[test]
fn the_grid_round_trips_through_a_checkpoint() {
    let m = model();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("ck.safetensors");
    let mut rng = SmallRng::seed_from_u64(2);
    let config = OccupancyConfig { resolution: 8, bound: 1.25, ..OccupancyConfig::default() };
    let opacity: Vec<f32> =
        (0..512).map(|_| if rng.random_bool(0.3) { CARVED } else { rng.random_range(0.0..1.0) }).collect();
    let grid = OccupancyGrid::from_state(config, opacity, true).unwrap();
    let n = m.num_params();
    let ck = Checkpoint { step: 9, params: m.init_params(1), adam: AdamState::new(n), occupancy: Some(grid) };
    checkpoint::save(&path, &m, &ck).unwrap();
    assert_eq!(checkpoint::load(&path, &m).unwrap(), ck);
    let plain = Checkpoint { occupancy: None, ..ck };
    checkpoint::save(&path, &m, &plain).unwrap();
    assert_eq!(checkpoint::load(&path, &m).unwrap().occupancy, None);
    // Bad saved state is refused with what is wrong.
    let e = OccupancyGrid::from_state(config, vec![f32::NAN; 512], true).unwrap_err().to_string();
    assert!(e.contains("NaN"), "{e}");
    let e = OccupancyGrid::from_state(config, vec![0.0; 500], true).unwrap_err().to_string();
    assert!(e.contains("500 cells") && e.contains("512"), "{e}");
    let e = OccupancyGrid::new(OccupancyConfig { bound: -1.0, ..config }).unwrap_err().to_string();
    assert!(e.contains("bound"), "{e}");
}

/// The ball scene as an unbounded scene: the world scaled by 1/3.2 so that its cameras (3.2 out)
/// stand just inside the unit ball, every ray reaching `UNBOUNDED_FAR` (the white beyond the
/// ball is then the far, contracted, part of the scene, learnt as any other).
fn unbounded_ball_scene(views: usize, size: u32) -> (Vec<mipnerf_core::Ray>, Vec<[f32; 3]>) {
    let (rays, colours) = ball_scene(views, size);
    let k = 1.0 / 3.2;
    let rays = rays
        .into_iter()
        .map(|r| mipnerf_core::Ray { origin: r.origin * k, near: r.near * k, far: UNBOUNDED_FAR, ..r })
        .collect();
    (rays, colours)
}

fn unbounded_model() -> Model {
    Model::new(ModelConfig { num_samples: 16, unbounded: true, ..Preset::Tiny.config() }).unwrap()
}

fn contracted_config(resolution: usize) -> OccupancyConfig {
    OccupancyConfig { resolution, bound: CONTRACTED_BOUND, contracted: true, ..OccupancyConfig::default() }
}

#[test]
fn a_fresh_contracted_grid_samples_and_trains_exactly_as_the_unbounded_sampler() {
    // Every cell the contracted space reaches is a candidate: each ray is one span from near to
    // far, so the sampler is the unbounded one (in s) bit for bit.
    let m = unbounded_model();
    let (rays, colours) = unbounded_ball_scene(4, 8);
    let params = m.init_params(3);
    let grid = OccupancyGrid::new(contracted_config(16)).unwrap();
    let left = grid.occupied_fraction();
    // The cells of the cube outside the ball of radius 2 are never candidates (a ball fills
    // pi/6 of its cube; the cells it touches a little more).
    assert!(left > 0.5 && left < 0.7, "{left}");
    let ((paper, g_paper), (guided, g_grid)) =
        paper_and_guided(&m, &params, TrainBatch { rays: &rays, targets: &colours }, &grid);
    assert_eq!(paper, guided);
    assert_eq!(g_paper, g_grid);
    assert_eq!(m.render(&params, &rays), m.render_guided(&params, &rays, Some(&grid)));
}

#[test]
fn a_contracted_grid_walks_each_ray_through_the_cells_its_contraction_meets() {
    use mipnerf_core::contract::{contract, ray_distance_to_s, s_to_ray_distance};
    use mipnerf_core::occupancy::CONTRACTED_STEPS_PER_CELL;
    let mut rng = SmallRng::seed_from_u64(12);
    let resolution = 16;
    let probe = OccupancyGrid::new(contracted_config(resolution)).unwrap();
    let opacity = (0..resolution.pow(3))
        .map(|i| {
            if probe.opacity[i] == CARVED {
                CARVED
            } else if rng.random_bool(0.3) {
                1.0
            } else {
                0.0
            }
        })
        .collect();
    let grid = OccupancyGrid::from_state(contracted_config(resolution), opacity, true).unwrap();
    let (rays, _) = unbounded_ball_scene(6, 6);
    let n = CONTRACTED_STEPS_PER_CELL * resolution;
    let (mut checked, mut dense, mut dense_bad) = (0, 0, 0);
    for (k, r) in rays.iter().enumerate() {
        let axis = mipnerf_core::Ray { radius: 0.0, ..*r };
        let mut spans = Vec::new();
        grid.ray_segments(&axis, &mut spans);
        for w in spans.windows(2) {
            assert!(w[0][1] < w[1][0], "ray {k}: spans overlap or touch: {spans:?}");
        }
        let inside = |t: f32| spans.iter().any(|s| s[0] <= t && t <= s[1]);
        // At the middle of every step of the walk: in a span exactly when its contraction's
        // cell is occupied.
        let (s0, s1) = (ray_distance_to_s(r.near), ray_distance_to_s(r.far));
        for i in 0..n {
            let t = s_to_ray_distance(s0 + (i as f32 + 0.5) * (s1 - s0) / n as f32);
            assert_eq!(
                inside(t),
                grid.is_occupied_at(r.origin + r.direction * t),
                "ray {k} step {i} (t {t}): {spans:?}"
            );
            checked += 1;
        }
        // Between them, a point whose contraction lies in its step's middle's cell is in a span
        // exactly when that cell is occupied (a step is judged by its middle).
        let cell = |t: f32| ((contract(r.origin + r.direction * t) + CONTRACTED_BOUND) / grid.cell_size()).floor();
        for i in 0..1000 {
            let s = s0 + (i as f32 + 0.37) * (s1 - s0) / 1000.0;
            let t = s_to_ray_distance(s);
            let step = (((s - s0) / (s1 - s0) * n as f32) as usize).min(n - 1);
            let middle = s_to_ray_distance(s0 + (step as f32 + 0.5) * (s1 - s0) / n as f32);
            if cell(t) != cell(middle) {
                continue;
            }
            dense += 1;
            dense_bad += usize::from(inside(t) != grid.is_occupied_at(r.origin + r.direction * t));
        }
    }
    assert!(checked > 1000 && dense > 100_000, "{checked} {dense}");
    assert_eq!(dense_bad, 0, "{dense_bad} of {dense} points between the steps disagree with their step");
}

/// Training an unbounded scene with a contracted grid: the loss falls, the grid leaves its
/// warm-up and skips space, and no cell the model has made dense is dropped (probed afresh at
/// another point of each cell, a cell whose opacity over its length is well above the threshold
/// is occupied). Where the model puts the ball is the model's affair: from 8 views around it, it
/// may paint the ball on the far, contracted, shell as well as place it at the centre.
#[test]
fn an_unbounded_scene_trains_with_a_contracted_grid_that_keeps_its_dense_cells() {
    let (rays, colours) = unbounded_ball_scene(8, 16);
    let steps = 300;
    let optim = common::optim_decaying(5e-3, 5e-4, steps);
    let mut trainer = Trainer::new(unbounded_model(), optim, 1);
    let r = 16;
    let config = OccupancyConfig { warmup_steps: 100, update_every: 10, threshold: 0.1, ..contracted_config(r) };
    trainer.occupancy = Some(OccupancyGrid::new(config).unwrap());
    let losses = common::train_on_random_batches(&mut trainer, &rays, &colours, steps as usize, 5);
    let (first, last) = (losses[..10].iter().sum::<f32>(), losses[steps as usize - 10..].iter().sum::<f32>());
    assert!(last < first / 4.0, "the loss went from {first} to {last} (sums of 10 steps)");
    let grid = trainer.occupancy.as_ref().unwrap();
    assert!(grid.warmed_up && !grid.is_full());
    let mut fresh = OccupancyGrid::new(OccupancyConfig { decay: 0.0, warmup_steps: 0, ..grid.config }).unwrap();
    fresh.update(&trainer.model.density_field(&trainer.params), 99, 12_345);
    let (mut dense, mut dropped) = (0, Vec::new());
    for i in 0..r.pow(3) {
        if fresh.opacity[i] > 0.5 {
            dense += 1;
            if !grid.is_occupied(i % r, (i / r) % r, i / (r * r)) {
                dropped.push((grid.cell_center(i), fresh.opacity[i], grid.opacity[i]));
            }
        }
    }
    eprintln!("{dense} cells dense, {} of the grid's cells occupied", grid.occupied_fraction());
    assert!(dense > 0 && dropped.is_empty(), "{} of {dense} dense cells dropped: {dropped:?}", dropped.len());
}

/// The reference the grid's density probes are checked against (the way they ran before
/// fern's profile showed their cost): each probe encoded alone ([`Model::encode_point`], or as it is in a
/// contracted grid), then the batch through the first MLP's full forward pass in a fresh cache,
/// the raw densities activated.
fn densities_by_full_forward(model: &Model, params: &[f32], probes: &[Gaussian], contracted: bool) -> Vec<f32> {
    let c = model.config();
    let (x_dim, n) = (c.x_dim(), probes.len());
    let mut x = vec![0.0f32; n * x_dim];
    for (g, dst) in probes.iter().zip(x.chunks_exact_mut(x_dim)) {
        if contracted {
            let encoding = (c.point_encoding, Precision::F32);
            mipnerf_core::stages::encode_gaussian(g, encoding, c.min_deg_point, c.max_deg_point, dst);
        } else {
            model.encode_point(g, dst);
        }
    }
    let mut cache = MlpCache::default();
    model.mlps()[0].forward(params, &x, &vec![0.0; n * c.view_dim()], n, 1, &mut cache);
    cache.raw_density.iter().map(|&raw| c.density_activation.forward(raw, c.density_bias)).collect()
}

#[test]
fn the_density_probes_give_the_bits_of_the_full_forward_pass() {
    // The probes run as a batch through the trunk and density head alone, in buffers each thread
    // keeps between updates, encoded in 512-bit vectors where the CPU has them: none of it may
    // change a bit. Bounded and unbounded models (the latter probed in world space and in
    // contracted space), f32 and bf16 where the CPU has a kernel, twice through the kept
    // buffers with batches of other sizes between.
    let mut rng = SmallRng::seed_from_u64(17);
    let mut probes = |n: usize| -> Vec<Gaussian> {
        (0..n)
            .map(|_| Gaussian {
                mean: Vec3::new(rng.random_range(-2.0..2.0), rng.random_range(-2.0..2.0), rng.random_range(-2.0..2.0)),
                cov_diag: Vec3::splat(rng.random_range(1e-4..1e-2)),
            })
            .collect()
    };
    let batches = [probes(37), probes(300), probes(5)];
    let bf16 = !matches!(mipnerf_core::bf16::Bf16Support::detect(), mipnerf_core::bf16::Bf16Support::Unavailable(_));
    if !bf16 {
        mipnerf_core::test_support::skipped_for_cpu_feature(
            "the_density_probes_give_the_bits_of_the_full_forward_pass (its bf16 half)",
            "avx512_bf16",
            "no bf16 kernel on this CPU",
        );
    }
    for precision in [Precision::F32, Precision::Bf16] {
        if precision == Precision::Bf16 && !bf16 {
            continue;
        }
        for (mut m, contracted) in [(model(), false), (unbounded_model(), false), (unbounded_model(), true)] {
            m.set_precision(precision).unwrap();
            let params = m.init_params(4);
            for _ in 0..2 {
                for probes in &batches {
                    let got = m.density_field(&params).densities(probes, contracted);
                    let want = densities_by_full_forward(&m, &params, probes, contracted);
                    let bits = |v: &[f32]| v.iter().map(|d| d.to_bits()).collect::<Vec<u32>>();
                    assert_eq!(
                        bits(&got),
                        bits(&want),
                        "{precision:?}, unbounded {}, contracted {contracted}, {} probes",
                        m.config().unbounded,
                        probes.len()
                    );
                }
            }
        }
    }
}

#[test]
#[should_panic(expected = "the last forward pass was density-only")]
fn no_backward_pass_follows_a_density_only_pass() {
    let m = model();
    let params = m.init_params(4);
    let shape = &m.mlps()[0];
    let c = m.config();
    let (n, x) = (4, vec![0.1f32; 4 * c.x_dim()]);
    let mut cache = MlpCache::default();
    shape.forward(&params, &x, &vec![0.0; n * c.view_dim()], n, 1, &mut cache);
    shape.density(&params, &x, n, &mut cache);
    let mut grads = vec![0.0; params.len()];
    shape.backward(
        &params,
        mipnerf_core::mlp::MlpInputs { x: &x, view: &vec![0.0; n * c.view_dim()], samples_per_ray: 1 },
        &mut cache,
        mipnerf_core::mlp::OutputGradients { rgb: &[0.0; 12], density: &[0.0; 4] },
        &mut grads,
    );
}
