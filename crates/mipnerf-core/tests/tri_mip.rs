//! The Tri-Mip encoding (`core/tri_mip.rs`): the pyramid, the trilinear taps and their adjoint,
//! the level from a conical frustum, and finite differences of a loss through the encoding alone
//! and through the whole field (the encoding, then a small MLP) on small planes.
#![allow(clippy::unwrap_used, missing_docs)]

use glam::Vec3;
use mipnerf_core::mip::{FrustumMoments, conical_frustum_moments, conical_frustum_to_gaussian};
use mipnerf_core::tri_mip::{Pyramid, TriMipConfig, encode, encode_backward, footprint_radius, level_of, taps};
use rand::{Rng, SeedableRng, rngs::SmallRng};

/// f32 sums of a few products: the pyramid's means and the taps' blends.
const SUM_TOLERANCE: f32 = 1e-6;
/// The dot-product test of the adjoint, relative to the terms' magnitude (f32 sums of ~10^4 terms).
const ADJOINT_TOLERANCE: f64 = 1e-5;
/// Central differences of a loss that is linear in the planes: exact but for f32 rounding at the
/// step (relative).
const FINITE_DIFFERENCE_TOLERANCE: f64 = 2e-3;

fn small() -> TriMipConfig {
    TriMipConfig { resolution: 16, features: 3, levels: 4 }
}

fn random_planes(config: &TriMipConfig, seed: u64) -> Vec<f32> {
    let mut rng = SmallRng::seed_from_u64(seed);
    (0..config.num_params()).map(|_| rng.random_range(-1.0..1.0)).collect()
}

fn random_point(rng: &mut SmallRng) -> Vec3 {
    // A little outside the box too: the edges clamp.
    Vec3::new(rng.random_range(-0.05..1.05), rng.random_range(-0.05..1.05), rng.random_range(-0.05..1.05))
}

#[test]
fn shapes_that_do_not_halve_evenly_are_refused() {
    assert!(TriMipConfig::default().validate().is_ok());
    assert_eq!(TriMipConfig::default().num_params(), 3 * 512 * 512 * 16);
    for bad in [
        TriMipConfig { resolution: 24, features: 4, levels: 5 },
        TriMipConfig { resolution: 0, features: 4, levels: 1 },
        TriMipConfig { resolution: 16, features: 0, levels: 1 },
        TriMipConfig { resolution: 16, features: 4, levels: 0 },
    ] {
        assert!(bad.validate().is_err(), "{bad:?}");
    }
}

#[test]
fn each_level_of_the_pyramid_is_the_mean_of_the_level_0_block_it_covers() {
    let c = small();
    let level0 = random_planes(&c, 1);
    let mut pyramid = Pyramid::zeros(c);
    pyramid.build(&level0);
    for l in 1..c.levels {
        let (size, block) = (c.size(l), 1 << l);
        for p in 0..3 {
            for v in 0..size {
                for u in 0..size {
                    for f in 0..c.features {
                        let mut mean = 0.0f32;
                        for dv in 0..block {
                            for du in 0..block {
                                let (fu, fv) = (u * block + du, v * block + dv);
                                mean += level0[((p * c.resolution + fv) * c.resolution + fu) * c.features + f];
                            }
                        }
                        mean /= (block * block) as f32;
                        let got = pyramid.level(l)[((p * size + v) * size + u) * c.features + f];
                        assert!(
                            (got - mean).abs() < SUM_TOLERANCE,
                            "level {l} plane {p} ({u}, {v}) {f}: {got} vs {mean}"
                        );
                    }
                }
            }
        }
    }
    // Constant planes stay constant at every level.
    let mut pyramid = Pyramid::zeros(c);
    pyramid.build(&vec![0.25; c.num_params()]);
    assert!((1..c.levels).all(|l| pyramid.level(l).iter().all(|&x| (x - 0.25).abs() < SUM_TOLERANCE)));
}

#[test]
fn taps_read_texel_centres_exactly_reproduce_linear_planes_and_blend_levels_linearly() {
    let c = small();
    // Each feature of each plane a linear function of its texel's centre: bilinear reads give
    // the function itself inside the plane, at every level (the box filter keeps it linear).
    let f = |p: usize, f: usize, u: f32, v: f32| (p as f32 + 1.0) * u - (f as f32 + 0.5) * v + 0.125 * f as f32;
    let mut level0 = vec![0.0; c.num_params()];
    for p in 0..3 {
        for v in 0..c.resolution {
            for u in 0..c.resolution {
                for k in 0..c.features {
                    let (cu, cv) = ((u as f32 + 0.5) / c.resolution as f32, (v as f32 + 0.5) / c.resolution as f32);
                    level0[((p * c.resolution + v) * c.resolution + u) * c.features + k] = f(p, k, cu, cv);
                }
            }
        }
    }
    let mut pyramid = Pyramid::zeros(c);
    pyramid.build(&level0);
    let mut rng = SmallRng::seed_from_u64(2);
    let mut out = vec![0.0; c.encoding_dim()];
    for _ in 0..200 {
        // Inside the texel centres of the coarsest level read, so that no edge clamps.
        let level = rng.random_range(0.0..(c.levels - 1) as f32);
        let margin = 0.5 / c.size(c.levels - 1) as f32;
        let x = Vec3::new(
            rng.random_range(margin..1.0 - margin),
            rng.random_range(margin..1.0 - margin),
            rng.random_range(margin..1.0 - margin),
        );
        encode(&c, &level0, &pyramid, &taps(&c, x, level), &mut out);
        let coords = [x.x, x.y, x.z];
        for (p, &(a, b)) in mipnerf_core::tri_mip::PLANES.iter().enumerate() {
            for k in 0..c.features {
                let want = f(p, k, coords[a], coords[b]);
                let got = out[p * c.features + k];
                assert!((got - want).abs() < 1e-4, "plane {p} feature {k} at {x} level {level}: {got} vs {want}");
            }
        }
    }
    // At a level-0 texel centre, level 0 reads that texel alone; half way between two levels,
    // the mean of the two levels' reads.
    let level0 = random_planes(&c, 3);
    pyramid.build(&level0);
    let (u, v, w) = (5usize, 9usize, 2usize);
    let centre = |i: usize| (i as f32 + 0.5) / c.resolution as f32;
    let x = Vec3::new(centre(u), centre(v), centre(w));
    encode(&c, &level0, &pyramid, &taps(&c, x, 0.0), &mut out);
    for k in 0..c.features {
        let texel = level0[(v * c.resolution + u) * c.features + k];
        assert!((out[k] - texel).abs() < SUM_TOLERANCE, "xy plane reads its texel");
    }
    let (mut at1, mut at2, mut half) = (out.clone(), out.clone(), out.clone());
    encode(&c, &level0, &pyramid, &taps(&c, x, 1.0), &mut at1);
    encode(&c, &level0, &pyramid, &taps(&c, x, 2.0), &mut at2);
    encode(&c, &level0, &pyramid, &taps(&c, x, 1.5), &mut half);
    for k in 0..c.encoding_dim() {
        assert!((half[k] - 0.5 * (at1[k] + at2[k])).abs() < SUM_TOLERANCE);
    }
}

/// `<encode(P), y> = <P, encodeᵀ(y)>` over many samples: the taps' scatter and the pyramid's
/// push-down are the exact adjoints of the reads and the box filters.
#[test]
fn the_backward_pass_is_the_adjoint_of_the_encoding_through_the_pyramid() {
    let c = small();
    let level0 = random_planes(&c, 4);
    let mut pyramid = Pyramid::zeros(c);
    pyramid.build(&level0);
    let mut rng = SmallRng::seed_from_u64(5);
    let mut grad0 = vec![0.0f32; c.num_params()];
    let mut grad_pyramid = Pyramid::zeros(c);
    let (mut forward, mut scale) = (0.0f64, 0.0f64);
    let mut out = vec![0.0; c.encoding_dim()];
    for _ in 0..500 {
        let t = taps(&c, random_point(&mut rng), rng.random_range(-0.5..c.levels as f32));
        encode(&c, &level0, &pyramid, &t, &mut out);
        let y: Vec<f32> = (0..c.encoding_dim()).map(|_| rng.random_range(-1.0..1.0)).collect();
        forward += out.iter().zip(&y).map(|(a, b)| f64::from(a * b)).sum::<f64>();
        scale += out.iter().zip(&y).map(|(a, b)| f64::from((a * b).abs())).sum::<f64>();
        encode_backward(&c, &t, &y, &mut grad0, &mut grad_pyramid);
    }
    grad_pyramid.push_down(&mut grad0);
    let backward: f64 = level0.iter().zip(&grad0).map(|(a, b)| f64::from(*a) * f64::from(*b)).sum();
    assert!((forward - backward).abs() <= ADJOINT_TOLERANCE * scale, "{forward} vs {backward} (scale {scale})");
}

/// Central differences of `L = Σ w · encode(x)` in a sample of level-0 parameters, on small
/// planes, against the backward pass (taps' scatter, then the pyramid's push-down).
#[test]
fn finite_differences_of_a_loss_through_the_encoding_match_the_backward_pass() {
    let c = TriMipConfig { resolution: 8, features: 2, levels: 3 };
    let mut level0 = random_planes(&c, 6);
    let mut rng = SmallRng::seed_from_u64(7);
    let samples: Vec<(Vec3, f32, Vec<f32>)> = (0..40)
        .map(|_| {
            let w = (0..c.encoding_dim()).map(|_| rng.random_range(-1.0..1.0)).collect();
            (random_point(&mut rng), rng.random_range(0.0..2.0), w)
        })
        .collect();
    let loss = |level0: &[f32]| -> f64 {
        let mut pyramid = Pyramid::zeros(c);
        pyramid.build(level0);
        let mut out = vec![0.0; c.encoding_dim()];
        samples
            .iter()
            .map(|(x, l, w)| {
                encode(&c, level0, &pyramid, &taps(&c, *x, *l), &mut out);
                out.iter().zip(w).map(|(a, b)| f64::from(a * b)).sum::<f64>()
            })
            .sum()
    };
    let mut grad0 = vec![0.0f32; c.num_params()];
    let mut grad_pyramid = Pyramid::zeros(c);
    for (x, l, w) in &samples {
        encode_backward(&c, &taps(&c, *x, *l), w, &mut grad0, &mut grad_pyramid);
    }
    grad_pyramid.push_down(&mut grad0);
    let h = 1e-2f32;
    let mut checked = 0;
    for i in (0..c.num_params()).step_by(7) {
        let kept = level0[i];
        level0[i] = kept + h;
        let up = loss(&level0);
        level0[i] = kept - h;
        let down = loss(&level0);
        level0[i] = kept;
        let numeric = (up - down) / (2.0 * f64::from(h));
        let analytic = f64::from(grad0[i]);
        assert!(
            (numeric - analytic).abs() <= FINITE_DIFFERENCE_TOLERANCE * analytic.abs().max(1.0),
            "parameter {i}: numeric {numeric}, analytic {analytic}"
        );
        checked += usize::from(analytic != 0.0);
    }
    assert!(checked > 20, "the samples reach the parameters checked ({checked})");
}

#[test]
fn a_point_reads_level_0_and_a_wider_cone_reads_a_coarser_level() {
    let c = TriMipConfig::default();
    assert_eq!(level_of(0.0, &c), 0.0);
    assert_eq!(level_of(f32::NAN, &c), 0.0);
    let point = FrustumMoments { t_mean: 1.0, t_var: 0.0, r_var: 0.0 };
    assert_eq!(level_of(footprint_radius(&point), &c), 0.0);
    // Along one cone, farther samples are wider and read coarser levels; twice the distance is
    // one level up; a cone twice as wide is one level up at the same distance.
    let radius = 2e-3;
    let level = |t: f32, r: f32| level_of(footprint_radius(&conical_frustum_moments(t, t * 1.01, r)), &c);
    let levels: Vec<f32> = [1.0, 2.0, 4.0, 8.0].iter().map(|&t| level(t, radius)).collect();
    assert!(levels.windows(2).all(|w| w[1] > w[0]), "{levels:?}");
    for w in levels.windows(2) {
        assert!((w[1] - w[0] - 1.0).abs() < 0.01, "doubling the distance adds a level: {levels:?}");
    }
    let wider = level(2.0, 2.0 * radius);
    assert!((wider - levels[1] - 1.0).abs() < 0.01, "{wider} vs {}", levels[1]);
    // The level clamps at the top of the pyramid.
    assert_eq!(level(1e4, 0.1), (c.levels - 1) as f32);
}

/// For a pixel's cone the footprint is the sphere Tri-MipRF's code inscribes in the cone,
/// `r = d · radii · cos / sqrt((sqrt(1/cos² - 1) - radii)² + 1)` (on the optical axis, `cos = 1`:
/// `d · radii / sqrt(radii² + 1)`, `radii` Mip-NeRF's base radius), within a hundredth of a level,
/// at the frusta of the paper's sampling; the Gaussian's isotropic spread is not (its trace is
/// the frustum's length).
#[test]
fn the_footprint_is_tri_mip_rfs_inscribed_sphere_for_a_pixels_cone() {
    let pixel = 1.0 / 400.0;
    let radii = pixel * 2.0 / 12f32.sqrt();
    // 128 samples over [2, 6]: frusta 1/32 long.
    for d in [2.0f32, 3.0, 4.5, 6.0] {
        let (t0, t1) = (d - 1.0 / 64.0, d + 1.0 / 64.0);
        let m = conical_frustum_moments(t0, t1, radii);
        let ours = footprint_radius(&m);
        let theirs = m.t_mean * radii / (radii * radii + 1.0).sqrt();
        let apart = (ours / theirs).log2().abs();
        assert!(apart < 0.01, "at {d}: {ours} vs Tri-MipRF's {theirs} ({apart} levels apart)");
        let g = conical_frustum_to_gaussian(Vec3::Z, t0, t1, radii);
        let isotropic = (5.0 / 3.0 * g.cov_diag.element_sum()).sqrt();
        let coarser = (isotropic / theirs).log2();
        assert!(coarser > 0.5, "the trace measures the frustum's length: {isotropic} vs {theirs} ({coarser} levels)");
    }
}

/// Central differences of a loss through the whole field (the encoding, then a small MLP of the
/// field's shape: no skip, the view encoding beside the bottleneck) in level-0 parameters,
/// against the backward pass: the MLP's backward and [`MlpShape::input_gradient`], the taps'
/// scatter and the pyramid's push-down. In f64 differences of f32 passes: ReLU's kinks and f32
/// rounding bound the agreement.
#[test]
fn finite_differences_of_the_whole_fields_loss_match_its_backward_pass() {
    use mipnerf_core::mlp::{MlpCache, MlpConfig, MlpShape};
    let c = TriMipConfig { resolution: 8, features: 4, levels: 3 };
    let config = MlpConfig {
        net_depth: 2,
        net_width: 16,
        skip_layer: 99,
        net_depth_condition: 1,
        net_width_condition: 8,
        x_dim: c.encoding_dim(),
        view_dim: 5,
    };
    let shape = MlpShape::new(config, 0).unwrap();
    let mut weights = vec![0.0; shape.num_params];
    shape.init_glorot(&mut weights, 11);
    let mut rng = SmallRng::seed_from_u64(12);
    let mut level0: Vec<f32> = (0..c.num_params()).map(|_| rng.random_range(-0.5..0.5)).collect();
    let (n_rays, per_ray) = (6, 5);
    let n = n_rays * per_ray;
    let samples: Vec<(Vec3, f32)> = (0..n).map(|_| (random_point(&mut rng), rng.random_range(0.0..2.0))).collect();
    let view: Vec<f32> = (0..n_rays * config.view_dim).map(|_| rng.random_range(-1.0..1.0)).collect();
    let w_rgb: Vec<f32> = (0..n * 3).map(|_| rng.random_range(-1.0..1.0)).collect();
    let w_density: Vec<f32> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
    let mut cache = MlpCache::default();
    cache.set_training(true);
    let encode_all = |level0: &[f32]| -> Vec<f32> {
        let mut pyramid = Pyramid::zeros(c);
        pyramid.build(level0);
        let mut x = vec![0.0; n * c.encoding_dim()];
        for (k, (p, l)) in samples.iter().enumerate() {
            let out = &mut x[k * c.encoding_dim()..(k + 1) * c.encoding_dim()];
            encode(&c, level0, &pyramid, &taps(&c, *p, *l), out);
        }
        x
    };
    let loss = |level0: &[f32], cache: &mut MlpCache| -> f64 {
        let x = encode_all(level0);
        shape.forward(&weights, &x, &view, n_rays, per_ray, cache);
        let rgb: f64 = cache.raw_rgb.iter().zip(&w_rgb).map(|(a, b)| f64::from(*a) * f64::from(*b)).sum();
        let density: f64 = cache.raw_density.iter().zip(&w_density).map(|(a, b)| f64::from(*a) * f64::from(*b)).sum();
        rgb + density
    };
    let _ = loss(&level0, &mut cache);
    let x = encode_all(&level0);
    let mut weight_grads = vec![0.0; shape.num_params];
    shape.backward(
        &weights,
        mipnerf_core::mlp::MlpInputs { x: &x, view: &view, samples_per_ray: per_ray },
        &mut cache,
        mipnerf_core::mlp::OutputGradients { rgb: &w_rgb, density: &w_density },
        &mut weight_grads,
    );
    let mut d_x = vec![0.0; n * c.encoding_dim()];
    shape.input_gradient(&weights, &cache, &mut d_x);
    let mut grad0 = vec![0.0f32; c.num_params()];
    let mut grad_pyramid = Pyramid::zeros(c);
    for (k, (p, l)) in samples.iter().enumerate() {
        let d = &d_x[k * c.encoding_dim()..(k + 1) * c.encoding_dim()];
        encode_backward(&c, &taps(&c, *p, *l), d, &mut grad0, &mut grad_pyramid);
    }
    grad_pyramid.push_down(&mut grad0);
    let h = 1e-3f32;
    let (mut checked, mut worst) = (0, 0.0f64);
    for i in (0..c.num_params()).step_by(5) {
        if grad0[i] == 0.0 {
            continue;
        }
        let kept = level0[i];
        level0[i] = kept + h;
        let up = loss(&level0, &mut cache);
        level0[i] = kept - h;
        let down = loss(&level0, &mut cache);
        level0[i] = kept;
        let numeric = (up - down) / (2.0 * f64::from(h));
        let analytic = f64::from(grad0[i]);
        let error = (numeric - analytic).abs() / analytic.abs().max(0.05);
        worst = worst.max(error);
        checked += 1;
    }
    assert!(checked > 30, "parameters with a gradient checked: {checked}");
    assert!(worst < WHOLE_FIELD_TOLERANCE, "worst relative error {worst} over {checked} parameters");
}

/// The whole field's central differences (f32 passes, ReLU): relative to the gradient (or to
/// 0.05 where it is smaller).
const WHOLE_FIELD_TOLERANCE: f64 = 2e-2;

/// The batched passes are the per-sample ones, bit for bit, on one thread or several: the
/// encodings (made in parallel) and the backward scatter (the planes in parallel, each in batch
/// and sample order).
#[test]
fn the_batched_passes_equal_the_per_sample_ones_bit_for_bit_at_any_thread_count() {
    use mipnerf_core::tri_mip::{Taps, encode_backward_batch, encode_batch};
    let c = TriMipConfig { resolution: 32, features: 4, levels: 4 };
    let level0 = random_planes(&c, 8);
    let mut pyramid = Pyramid::zeros(c);
    pyramid.build(&level0);
    let mut rng = SmallRng::seed_from_u64(9);
    let n = 3000;
    let points: Vec<Vec3> = (0..n).map(|_| random_point(&mut rng)).collect();
    let levels: Vec<f32> = (0..n).map(|_| rng.random_range(-0.5..4.0)).collect();
    let dim = c.encoding_dim();
    let d_x: Vec<f32> = (0..n * dim).map(|_| rng.random_range(-1.0..1.0)).collect();
    // The sequential reference.
    let mut want_x = vec![0.0; n * dim];
    let (mut want0, mut want_pyramid) = (vec![0.0; c.num_params()], Pyramid::zeros(c));
    for k in 0..n {
        let t = taps(&c, points[k], levels[k]);
        encode(&c, &level0, &pyramid, &t, &mut want_x[k * dim..(k + 1) * dim]);
        encode_backward(&c, &t, &d_x[k * dim..(k + 1) * dim], &mut want0, &mut want_pyramid);
    }
    for threads in [1, 2, 5] {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| {
            let mut x = vec![0.0; n * dim];
            let mut t = vec![taps(&c, Vec3::ZERO, 0.0); n];
            encode_batch(&c, &level0, &pyramid, &points, &levels, &mut t, &mut x);
            assert_eq!(x, want_x, "{threads} threads: encodings");
            let (mut got0, mut got_pyramid) = (vec![0.0; c.num_params()], Pyramid::zeros(c));
            // In two batches, as a training step's chunks come.
            let (t1, t2) = t.split_at(1000);
            let (d1, d2) = d_x.split_at(1000 * dim);
            encode_backward_batch(&c, &[(t1, d1), (t2, d2)], &mut got0, &mut got_pyramid);
            assert!(got0.iter().zip(&want0).all(|(a, b)| a.to_bits() == b.to_bits()), "{threads} threads: level 0");
            assert_eq!(got_pyramid, want_pyramid, "{threads} threads: the levels above");
            let _: &[Taps] = &t;
        });
    }
}

/// The view encoding's 16 spherical harmonics are orthonormal over the sphere (integrated over a
/// Fibonacci lattice of 40,000 directions) and take their closed-form values on the axes.
#[test]
fn the_view_encodings_spherical_harmonics_are_orthonormal() {
    use mipnerf_core::tri_mip::{SH_VALUES, spherical_harmonics};
    let n = 40_000;
    let mut gram = [[0.0f64; SH_VALUES]; SH_VALUES];
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    for k in 0..n {
        let z = 1.0 - (2.0 * k as f64 + 1.0) / n as f64;
        let r = (1.0 - z * z).sqrt();
        let phi = golden * k as f64;
        let y = spherical_harmonics(Vec3::new((r * phi.cos()) as f32, (r * phi.sin()) as f32, z as f32));
        for i in 0..SH_VALUES {
            for j in 0..SH_VALUES {
                gram[i][j] += f64::from(y[i]) * f64::from(y[j]) * 4.0 * std::f64::consts::PI / n as f64;
            }
        }
    }
    for i in 0..SH_VALUES {
        for j in 0..SH_VALUES {
            let want = if i == j { 1.0 } else { 0.0 };
            assert!((gram[i][j] - want).abs() < 2e-3, "<Y{i}, Y{j}> = {}", gram[i][j]);
        }
    }
    // On +z: Y00 = 1/(2 sqrt(pi)), Y10 = sqrt(3/(4 pi)), Y20 = sqrt(5/(4 pi)), Y30 = sqrt(7/(4 pi)),
    // the others 0; a direction's length does not matter.
    let y = spherical_harmonics(Vec3::new(0.0, 0.0, 2.5));
    let pi = std::f32::consts::PI;
    let expect = [
        (0, 0.5 / pi.sqrt()),
        (2, (3.0 / (4.0 * pi)).sqrt()),
        (6, (5.0 / (4.0 * pi)).sqrt()),
        (12, (7.0 / (4.0 * pi)).sqrt()),
    ];
    for (i, v) in y.iter().enumerate() {
        let want = expect.iter().find(|e| e.0 == i).map_or(0.0, |e| e.1);
        assert!((v - want).abs() < 1e-5, "Y{i} on +z: {v} vs {want}");
    }
}

/// The planes' total variation: its value by a direct sum over the neighbouring pairs, its
/// gradient against central differences (f64 of the f32 function), and the same bits on any
/// number of threads.
#[test]
fn the_planes_total_variation_and_its_gradient_match_a_direct_sum_and_finite_differences() {
    use mipnerf_core::tri_mip::total_variation;
    let c = TriMipConfig { resolution: 8, features: 3, levels: 2 };
    let level0 = random_planes(&c, 21);
    let weight = 0.7f32;
    let (size, f) = (c.resolution, c.features);
    let at =
        |p: &[f32], plane: usize, v: usize, u: usize, k: usize| f64::from(p[((plane * size + v) * size + u) * f + k]);
    let direct = |p: &[f32]| {
        let mut sum = 0.0;
        for plane in 0..3 {
            for v in 0..size {
                for u in 0..size {
                    for k in 0..f {
                        if u + 1 < size {
                            sum += (at(p, plane, v, u, k) - at(p, plane, v, u + 1, k)).powi(2);
                        }
                        if v + 1 < size {
                            sum += (at(p, plane, v, u, k) - at(p, plane, v + 1, u, k)).powi(2);
                        }
                    }
                }
            }
        }
        f64::from(weight) * sum / (3 * 2 * size * (size - 1) * f) as f64
    };
    let mut grad = vec![0.0; c.num_params()];
    let value = total_variation(&c, &level0, weight, &mut grad);
    assert!((value - direct(&level0)).abs() <= TV_TOLERANCE * direct(&level0), "{value} against {}", direct(&level0));
    let h = 1e-3f32;
    for i in (0..c.num_params()).step_by(7) {
        let (mut up, mut down) = (level0.clone(), level0.clone());
        up[i] += h;
        down[i] -= h;
        let fd = (direct(&up) - direct(&down)) / f64::from(2.0 * h);
        let g = f64::from(grad[i]);
        assert!(
            (g - fd).abs() <= TV_TOLERANCE * fd.abs().max(1e-4),
            "texel value {i}: analytic {g:e}, finite difference {fd:e}"
        );
    }
    for threads in [1, 3] {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        let (v, g) = pool.install(|| {
            let mut g = vec![0.0; c.num_params()];
            (total_variation(&c, &level0, weight, &mut g), g)
        });
        assert!(v.to_bits() == value.to_bits() && g == grad, "{threads} threads");
    }
}

/// The total variation's relative agreement with its direct f64 sum and its finite differences
/// (its f32 sums of a few hundred terms).
const TV_TOLERANCE: f64 = 1e-3;
