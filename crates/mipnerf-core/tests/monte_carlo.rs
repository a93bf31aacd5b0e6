//! Monte Carlo checks of the Gaussian approximation (the paper's Eqs. 7-8 and 14):
//! points drawn uniformly inside conical frustums have the mean and per-axis variance that
//! `conical_frustum_to_gaussian` claims, and the IPE equals the average positional encoding of
//! points drawn from that Gaussian. Both within the Monte Carlo standard error.
#![allow(clippy::unwrap_used, missing_docs)]

use glam::{DVec3, Vec3};
use mipnerf_core::mip::{self, Gaussian};
use rand::{Rng, SeedableRng, rngs::SmallRng};
use rand_distr::{Distribution, StandardNormal};

/// How many standard errors an estimate may be from the claim. With ~60 compared statistics per
/// test, 5 SE makes a false failure (p ~ 6e-7 each) practically impossible at a fixed seed, while a
/// wrong formula (off by a few percent) is far outside it.
const MC_SIGMAS: f64 = 5.0;
/// Samples per case.
const MC_SAMPLES: usize = 400_000;
/// Headroom for the f32 rounding of the claimed value itself.
const F32_SLACK: f64 = 1e-6;

struct Case {
    name: &'static str,
    d: Vec3,
    t0: f32,
    t1: f32,
    radius: f32,
}

fn cases() -> Vec<Case> {
    vec![
        Case { name: "thin, near", d: Vec3::new(0.1, -0.2, -1.0), t0: 2.0, t1: 2.05, radius: 0.002 },
        Case { name: "thick, near", d: Vec3::new(0.3, 0.4, -1.2), t0: 0.5, t1: 3.0, radius: 0.01 },
        Case { name: "thin, far", d: Vec3::new(-0.2, 0.1, -1.0), t0: 50.0, t1: 50.5, radius: 0.001 },
        Case { name: "thick, far", d: Vec3::new(0.0, 0.6, -0.8), t0: 20.0, t1: 60.0, radius: 0.003 },
        Case { name: "narrow cone", d: Vec3::new(0.5, 0.5, -0.7), t0: 2.0, t1: 4.0, radius: 1e-4 },
        Case { name: "wide cone", d: Vec3::new(0.2, -0.9, 0.3), t0: 1.0, t1: 2.5, radius: 0.4 },
        Case { name: "starts at apex", d: Vec3::new(1.0, 0.0, 0.0), t0: 0.0, t1: 1.5, radius: 0.2 },
    ]
}

/// Two unit vectors perpendicular to `d` and to each other.
fn basis(d: DVec3) -> (DVec3, DVec3) {
    let n = d.normalize();
    let a = if n.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
    let u = n.cross(a).normalize();
    (u, n.cross(u))
}

/// A point uniform in the frustum: `t` with density ∝ t² on [t0, t1] (cone cross-section grows
/// as t²), uniform on the disc of radius `radius * t` perpendicular to `d`.
fn sample_frustum(c: &Case, rng: &mut SmallRng) -> DVec3 {
    let d = c.d.as_dvec3();
    let (u, v) = basis(d);
    let (t0, t1) = (f64::from(c.t0), f64::from(c.t1));
    let t = (t0.powi(3) + rng.random::<f64>() * (t1.powi(3) - t0.powi(3))).cbrt();
    let rho = f64::from(c.radius) * t * rng.random::<f64>().sqrt();
    let theta = std::f64::consts::TAU * rng.random::<f64>();
    d * t + u * (rho * theta.cos()) + v * (rho * theta.sin())
}

/// Mean, variance, and standard errors of both, of a stream of samples.
struct Moments {
    n: f64,
    s1: f64,
    s2: f64,
    s3: f64,
    s4: f64,
    shift: f64,
}

impl Moments {
    fn new(shift: f64) -> Self {
        Self { n: 0.0, s1: 0.0, s2: 0.0, s3: 0.0, s4: 0.0, shift }
    }
    fn push(&mut self, x: f64) {
        let y = x - self.shift;
        self.n += 1.0;
        self.s1 += y;
        self.s2 += y * y;
        self.s3 += y * y * y;
        self.s4 += y * y * y * y;
    }
    fn mean(&self) -> f64 {
        self.shift + self.s1 / self.n
    }
    fn var(&self) -> f64 {
        let m = self.s1 / self.n;
        self.s2 / self.n - m * m
    }
    fn mean_se(&self) -> f64 {
        (self.var() / self.n).sqrt()
    }
    fn var_se(&self) -> f64 {
        let m = self.s1 / self.n;
        let m4 = self.s4 / self.n - 4.0 * m * self.s3 / self.n + 6.0 * m * m * self.s2 / self.n - 3.0 * m.powi(4);
        ((m4 - self.var().powi(2)).max(0.0) / self.n).sqrt()
    }
}

fn within(what: &str, est: f64, se: f64, claim: f64, bad: &mut Vec<String>) {
    let tol = MC_SIGMAS * se + F32_SLACK * claim.abs().max(1e-12);
    if (est - claim).abs() > tol {
        bad.push(format!(
            "{what}: Monte Carlo {est:e} ± {se:e}, formula {claim:e} ({:.1} SE off)",
            (est - claim).abs() / se
        ));
    }
}

#[test]
fn frustum_gaussian_moments_match_monte_carlo() {
    let mut bad = Vec::new();
    for (ci, c) in cases().iter().enumerate() {
        let g = mip::conical_frustum_to_gaussian(c.d, c.t0, c.t1, c.radius);
        let mut rng = SmallRng::seed_from_u64(1000 + ci as u64);
        let mean = g.mean.as_dvec3();
        let mut m: Vec<Moments> = (0..3).map(|k| Moments::new(mean[k])).collect();
        for _ in 0..MC_SAMPLES {
            let p = sample_frustum(c, &mut rng);
            for k in 0..3 {
                m[k].push(p[k]);
            }
        }
        for k in 0..3 {
            within(&format!("{} mean[{k}]", c.name), m[k].mean(), m[k].mean_se(), mean[k], &mut bad);
            within(&format!("{} var[{k}]", c.name), m[k].var(), m[k].var_se(), f64::from(g.cov_diag[k]), &mut bad);
        }
    }
    assert!(bad.is_empty(), "{} statistics disagree:\n{}", bad.len(), bad.join("\n"));
}

#[test]
fn the_monte_carlo_check_catches_a_wrong_formula() {
    // The same statistics against the cylinder's moments, which are wrong for a thick cone.
    let c = &cases()[1];
    let g = mip::cylinder_to_gaussian(c.d, c.t0, c.t1, c.radius);
    let mut rng = SmallRng::seed_from_u64(7);
    let mut m = Moments::new(0.0);
    for _ in 0..MC_SAMPLES / 4 {
        m.push(sample_frustum(c, &mut rng).z);
    }
    let mut bad = Vec::new();
    within("cylinder mean z", m.mean(), m.mean_se(), f64::from(g.mean.z), &mut bad);
    assert!(!bad.is_empty(), "a cylinder's mean passed for a thick cone");
}

#[test]
fn ipe_equals_the_expected_positional_encoding_under_the_gaussian() {
    let mut bad = Vec::new();
    let (min_deg, max_deg) = (0, 16);
    let len = mip::ipe_len(min_deg, max_deg);
    let half = len / 2;
    let mut ipe = vec![0.0f32; len];
    for (ci, c) in cases().iter().enumerate() {
        // Place the frustum in the world so the encoding sees a realistic position.
        let mut g = mip::conical_frustum_to_gaussian(c.d, c.t0, c.t1, c.radius);
        g.mean += Vec3::new(0.3, -0.7, 1.1);
        mip::integrated_pos_enc(&g, min_deg, max_deg, &mut ipe);
        let mut rng = SmallRng::seed_from_u64(2000 + ci as u64);
        let sd = g.cov_diag.as_dvec3().map(f64::sqrt);
        let mean = g.mean.as_dvec3();
        let mut sums: Vec<Moments> = (0..len).map(|_| Moments::new(0.0)).collect();
        let n_draws = MC_SAMPLES / 4;
        for _ in 0..n_draws {
            let z: [f64; 3] = std::array::from_fn(|_| StandardNormal.sample(&mut rng));
            let x = mean + sd * DVec3::from_array(z);
            for (i, deg) in (min_deg..max_deg).enumerate() {
                let s = f64::from(1u32 << deg);
                for k in 0..3 {
                    sums[i * 3 + k].push((x[k] * s).sin());
                    sums[half + i * 3 + k].push((x[k] * s).cos());
                }
            }
        }
        for (j, m) in sums.iter().enumerate() {
            // The standard error of an average of sines is at most 1/sqrt(n); use the sample's own.
            let se = m.mean_se().max(1e-9);
            within(&format!("{} feature {j}", g_name(c, ci)), m.mean(), se, f64::from(ipe[j]), &mut bad);
        }
    }
    assert!(bad.is_empty(), "{} IPE features disagree with Monte Carlo:\n{}", bad.len(), bad.join("\n"));
}

fn g_name(c: &Case, i: usize) -> String {
    format!("case {i} ({})", c.name)
}

#[test]
fn ipe_of_a_point_is_the_positional_encoding() {
    // Zero covariance: IPE = PE of the mean (the "w/o IPE" ablation's encoding).
    let g = Gaussian { mean: Vec3::new(0.4, -1.3, 2.2), cov_diag: Vec3::ZERO };
    let mut ipe = vec![0.0; mip::ipe_len(0, 6)];
    let mut pe = vec![0.0; mip::pos_enc_len(0, 6, false)];
    mip::integrated_pos_enc(&g, 0, 6, &mut ipe);
    mip::pos_enc(g.mean, 0, 6, false, &mut pe);
    for (i, (a, b)) in ipe.iter().zip(&pe).enumerate() {
        assert!((a - b).abs() <= 1e-6, "feature {i}: ipe {a} pe {b}");
    }
}

#[test]
fn a_wider_cone_damps_high_frequencies_more() {
    let d = Vec3::new(0.2, -0.3, -1.0);
    let mut narrow = vec![0.0; mip::ipe_len(0, 16)];
    let mut wide = narrow.clone();
    mip::integrated_pos_enc(&mip::conical_frustum_to_gaussian(d, 3.0, 3.1, 0.0005), 0, 16, &mut narrow);
    mip::integrated_pos_enc(&mip::conical_frustum_to_gaussian(d, 3.0, 3.1, 0.02), 0, 16, &mut wide);
    let energy = |f: &[f32], lo: usize| f[lo * 3..48].iter().chain(&f[48 + lo * 3..]).map(|x| x * x).sum::<f32>();
    assert!(energy(&wide, 6) < 0.5 * energy(&narrow, 6), "wide {} narrow {}", energy(&wide, 6), energy(&narrow, 6));
}
