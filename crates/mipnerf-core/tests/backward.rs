//! Finite-difference checks of every analytic backward pass in the core crate, on inputs away from
//! kinks, reporting all mismatches in one message.
#![allow(clippy::unwrap_used, missing_docs)]

use glam::Vec3;
use mipnerf_core::render::{
    DensityActivation, RayComposite, Upstream, background, rgb_activation, rgb_activation_derivative,
    volumetric_rendering, volumetric_rendering_backward,
};
use rand::{Rng, SeedableRng, rngs::SmallRng};

/// Central differences in f64 of an f32 function: step relative to the input's scale.
const FD_STEP: f64 = 1e-2;
/// |analytic - numeric| <= FD_ABS + FD_REL * |numeric|. Central differences are O(h²) accurate; the
/// rest is the f32 rounding of the function values divided by the step.
const FD_ABS: f64 = 2e-4;
const FD_REL: f64 = 1e-2;

fn check(what: &str, analytic: f64, numeric: f64, bad: &mut Vec<String>) {
    if (analytic - numeric).abs() > FD_ABS + FD_REL * numeric.abs() {
        bad.push(format!("{what}: analytic {analytic:e}, finite difference {numeric:e}"));
    }
}

struct RayCase {
    rgb: Vec<[f32; 3]>,
    density: Vec<f32>,
    t: Vec<f32>,
    dir: Vec3,
}

fn random_ray(rng: &mut SmallRng, n: usize) -> RayCase {
    let mut t: Vec<f32> = (0..=n).map(|_| rng.random_range(2.0..6.0)).collect();
    t.sort_by(f32::total_cmp);
    // Keep intervals apart so deltas are not tiny.
    for i in 1..=n {
        t[i] = t[i].max(t[i - 1] + 0.05);
    }
    RayCase {
        rgb: (0..n)
            .map(|_| [rng.random_range(0.05..0.95), rng.random_range(0.05..0.95), rng.random_range(0.05..0.95)])
            .collect(),
        density: (0..n).map(|_| rng.random_range(0.05..3.0)).collect(),
        t,
        dir: Vec3::new(rng.random_range(-0.5..0.5), rng.random_range(-0.5..0.5), -1.0),
    }
}

/// The scalar the checks differentiate: L = c · rgb_out + a acc.
fn loss(r: &RayCase, bg: [f32; 3], c: [f32; 3], a: f32) -> f64 {
    let mut w = vec![0.0; r.density.len()];
    let out = volumetric_rendering(&r.rgb, &r.density, &r.t, r.dir, bg, &mut w);
    (0..3).map(|k| f64::from(c[k]) * f64::from(out.rgb[k])).sum::<f64>() + f64::from(a) * f64::from(out.acc)
}

#[test]
fn volumetric_rendering_backward_matches_finite_differences() {
    let mut rng = SmallRng::seed_from_u64(42);
    let mut bad = Vec::new();
    let mut checked = 0;
    for case in 0..12 {
        let n = [1, 2, 5, 16][case % 4];
        // White, black, and a colour (random backgrounds), each with every sample count.
        let bg = match case % 3 {
            0 => background(true),
            1 => background(false),
            _ => [rng.random_range(0.0..1.0), rng.random_range(0.0..1.0), rng.random_range(0.0..1.0)],
        };
        let mut r = random_ray(&mut rng, n);
        let c = [rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)];
        let a = rng.random_range(-1.0..1.0);
        let mut w = vec![0.0; n];
        volumetric_rendering(&r.rgb, &r.density, &r.t, r.dir, bg, &mut w);
        let mut g_rgb = vec![[0.0; 3]; n];
        let mut g_den = vec![0.0; n];
        let composite = RayComposite { rgb: &r.rgb, density: &r.density, t_vals: &r.t, dir: r.dir, bg };
        volumetric_rendering_backward(composite, &w, Upstream { d_rgb: c, d_acc: a }, &mut g_rgb, &mut g_den);
        for i in 0..n {
            let x0 = r.density[i];
            let h = (FD_STEP * f64::from(x0).abs().max(0.3)) as f32;
            r.density[i] = x0 + h;
            let up = loss(&r, bg, c, a);
            r.density[i] = x0 - h;
            let down = loss(&r, bg, c, a);
            r.density[i] = x0;
            let h_eff = (f64::from(x0 + h) - f64::from(x0 - h)) / 2.0;
            check(&format!("case {case} d/d density[{i}]"), f64::from(g_den[i]), (up - down) / (2.0 * h_eff), &mut bad);
            for k in 0..3 {
                let x0 = r.rgb[i][k];
                let h = 1e-2f32;
                r.rgb[i][k] = x0 + h;
                let up = loss(&r, bg, c, a);
                r.rgb[i][k] = x0 - h;
                let down = loss(&r, bg, c, a);
                r.rgb[i][k] = x0;
                let h_eff = (f64::from(x0 + h) - f64::from(x0 - h)) / 2.0;
                check(
                    &format!("case {case} d/d rgb[{i}][{k}]"),
                    f64::from(g_rgb[i][k]),
                    (up - down) / (2.0 * h_eff),
                    &mut bad,
                );
                checked += 1;
            }
            checked += 1;
        }
    }
    assert!(checked > 100);
    assert!(bad.is_empty(), "{} of {checked} gradients disagree:\n{}", bad.len(), bad.join("\n"));
}

#[test]
fn a_wrong_gradient_is_caught() {
    // The checker itself: perturb the analytic density gradient by 5% and expect a report.
    let mut rng = SmallRng::seed_from_u64(3);
    let mut r = random_ray(&mut rng, 4);
    let mut w = vec![0.0; 4];
    volumetric_rendering(&r.rgb, &r.density, &r.t, r.dir, background(true), &mut w);
    let mut g_rgb = vec![[0.0; 3]; 4];
    let mut g_den = vec![0.0; 4];
    let composite = RayComposite { rgb: &r.rgb, density: &r.density, t_vals: &r.t, dir: r.dir, bg: background(true) };
    let upstream = Upstream { d_rgb: [1.0, 0.5, -0.3], d_acc: 0.0 };
    volumetric_rendering_backward(composite, &w, upstream, &mut g_rgb, &mut g_den);
    let x0 = r.density[1];
    let h = 1e-3f32;
    r.density[1] = x0 + h;
    let up = loss(&r, background(true), [1.0, 0.5, -0.3], 0.0);
    r.density[1] = x0 - h;
    let down = loss(&r, background(true), [1.0, 0.5, -0.3], 0.0);
    let numeric = (up - down) / (2.0 * f64::from(h));
    let mut bad = Vec::new();
    check("perturbed", f64::from(g_den[1]) * 1.05 + 0.01, numeric, &mut bad);
    assert_eq!(bad.len(), 1, "a 5% error went unnoticed (numeric {numeric})");
}

#[test]
fn activation_derivatives_match_finite_differences() {
    let mut bad = Vec::new();
    let xs = [-6.0f32, -2.5, -0.7, -0.2, 0.3, 0.9, 2.2, 7.0];
    for &x in &xs {
        let h = 1e-3f32;
        let fd = |f: &dyn Fn(f32) -> f32| {
            (f64::from(f(x + h)) - f64::from(f(x - h))) / (f64::from(x + h) - f64::from(x - h))
        };
        for bias in [-1.0f32, 0.0] {
            for act in [DensityActivation::Softplus, DensityActivation::Relu] {
                // Away from ReLU's kink at raw = -bias.
                if act == DensityActivation::Relu && (x + bias).abs() < 0.05 {
                    continue;
                }
                check(
                    &format!("{act:?} bias {bias} at {x}"),
                    f64::from(act.derivative(x, bias)),
                    fd(&|v| act.forward(v, bias)),
                    &mut bad,
                );
            }
        }
        for pad in [0.001f32, 0.0] {
            check(
                &format!("rgb padding {pad} at {x}"),
                f64::from(rgb_activation_derivative(x, pad)),
                fd(&|v| rgb_activation(v, pad)),
                &mut bad,
            );
        }
    }
    assert!(bad.is_empty(), "{} derivatives disagree:\n{}", bad.len(), bad.join("\n"));
}

/// mip-NeRF 360's distortion loss (its Eq. 15) in f64, as written: the double sum.
fn distortion_by_definition(s: &[f32], w: &[f32]) -> f64 {
    let n = w.len();
    let mid = |i: usize| 0.5 * (f64::from(s[i]) + f64::from(s[i + 1]));
    let mut loss = 0.0;
    for i in 0..n {
        for j in 0..n {
            loss += f64::from(w[i]) * f64::from(w[j]) * (mid(i) - mid(j)).abs();
        }
        loss += f64::from(w[i]) * f64::from(w[i]) * (f64::from(s[i + 1]) - f64::from(s[i])) / 3.0;
    }
    loss
}

/// Relative difference allowed between the O(n) distortion loss (f32 prefix sums) and the double
/// sum in f64: a few f32 roundings of sums of up to 64 terms.
const TOL_DISTORTION_REL: f64 = 1e-5;

/// The distortion loss: its O(n) form against the definition's double sum, its gradient with
/// respect to the weights and, through [`weights_backward`], the densities, against finite
/// differences, and its meaning: one short stretch of weight costs less than the same weight
/// spread along the ray.
#[test]
fn distortion_loss_matches_its_definition_and_finite_differences() {
    use mipnerf_core::render::weights_backward;
    use mipnerf_core::stages::distortion_loss;
    let mut rng = SmallRng::seed_from_u64(7);
    let mut bad = Vec::new();
    let mut checked = 0;
    for case in 0..12 {
        let n = [1, 3, 16, 64][case % 4];
        let mut s: Vec<f32> = (0..=n).map(|_| rng.random_range(0.0..1.0)).collect();
        s.sort_by(f32::total_cmp);
        let w: Vec<f32> = (0..n).map(|_| rng.random_range(0.0..1.0) / n as f32).collect();
        let scale = rng.random_range(0.1..2.0);
        let mut d_w = vec![0.0; n];
        let loss = distortion_loss(&s, &w, scale, &mut d_w);
        let exact = distortion_by_definition(&s, &w);
        if (f64::from(loss) - exact).abs() > TOL_DISTORTION_REL * exact.abs().max(1e-6) {
            bad.push(format!("case {case}: O(n) {loss:e}, definition {exact:e}"));
        }
        // d/dw by central differences of the definition (a quadratic: exact up to rounding).
        for i in 0..n {
            let h = 1e-3f32;
            let (mut up, mut down) = (w.clone(), w.clone());
            up[i] += h;
            down[i] -= h;
            let h_eff = (f64::from(up[i]) - f64::from(down[i])) / 2.0;
            let numeric = f64::from(scale) * (distortion_by_definition(&s, &up) - distortion_by_definition(&s, &down))
                / (2.0 * h_eff);
            check(&format!("case {case} d/dw[{i}]"), f64::from(d_w[i]), numeric, &mut bad);
            checked += 1;
        }
        // Through the weights of volume rendering: d/d density.
        if n <= 16 {
            let mut r = random_ray(&mut rng, n);
            let edges: Vec<f32> = r.t.iter().map(|t| (t - r.t[0]) / (r.t[n] - r.t[0])).collect();
            let through = |r: &RayCase| -> f64 {
                let mut w = vec![0.0; n];
                volumetric_rendering(&r.rgb, &r.density, &r.t, r.dir, [0.0; 3], &mut w);
                distortion_by_definition(&edges, &w)
            };
            let mut w = vec![0.0; n];
            volumetric_rendering(&r.rgb, &r.density, &r.t, r.dir, [0.0; 3], &mut w);
            let mut d_w = vec![0.0; n];
            distortion_loss(&edges, &w, 1.0, &mut d_w);
            let mut g_den = vec![0.0; n];
            weights_backward(&r.density, &r.t, r.dir, &w, &d_w, &mut g_den);
            for i in 0..n {
                let x0 = r.density[i];
                let h = (FD_STEP * f64::from(x0).abs().max(0.3)) as f32;
                r.density[i] = x0 + h;
                let up = through(&r);
                r.density[i] = x0 - h;
                let down = through(&r);
                r.density[i] = x0;
                let h_eff = (f64::from(x0 + h) - f64::from(x0 - h)) / 2.0;
                check(
                    &format!("case {case} d/d density[{i}]"),
                    f64::from(g_den[i]),
                    (up - down) / (2.0 * h_eff),
                    &mut bad,
                );
                checked += 1;
            }
        }
    }
    assert!(checked > 200);
    assert!(bad.is_empty(), "{} of {checked} checks disagree:\n{}", bad.len(), bad.join("\n"));
    // A surface (all the weight in one interval of width 0.01) against the same weight in a fog
    // over the whole ray.
    let s: Vec<f32> = (0..=100).map(|i| i as f32 / 100.0).collect();
    let mut surface = vec![0.0; 100];
    surface[40] = 1.0;
    let fog = vec![0.01; 100];
    let mut d_w = vec![0.0; 100];
    let (at_surface, in_fog) = (distortion_loss(&s, &surface, 1.0, &mut d_w), distortion_loss(&s, &fog, 1.0, &mut d_w));
    assert!((f64::from(at_surface) - 0.01 / 3.0).abs() < 1e-7, "{at_surface}");
    // A uniform unit weight over [0, 1]: 1/3 (the mean distance of two uniform points), less the
    // double sum's discretisation.
    assert!((f64::from(in_fog) - 1.0 / 3.0).abs() < 1e-4, "{in_fog}");
}
