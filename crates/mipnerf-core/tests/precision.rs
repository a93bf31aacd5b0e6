//! Where f32 loses precision: the textbook conical-frustum moments against the stable form.
#![allow(clippy::unwrap_used, missing_docs)]

use mipnerf_core::mip::{FrustumMoments, conical_frustum_moments};

/// The stable form in f64: the truth the f32 results are measured against.
fn stable_f64(t0: f64, t1: f64) -> (f64, f64) {
    let mu = (t0 + t1) / 2.0;
    let hw = (t1 - t0) / 2.0;
    let denom = 3.0 * mu * mu + hw * hw;
    let t_mean = mu + 2.0 * mu * hw * hw / denom;
    let t_var = hw * hw / 3.0 - 4.0 / 15.0 * (hw.powi(4) * (12.0 * mu * mu - hw * hw)) / (denom * denom);
    (t_mean, t_var)
}

/// The stable f32 form keeps t_var to this relative error even for thin, distant frustums.
const TOL_STABLE_REL: f64 = 1e-4;

#[test]
fn naive_formula_loses_the_variance_of_a_thin_distant_frustum_and_stable_one_keeps_it() {
    for (t0, t1) in [(100.0f32, 100.5f32), (1000.0, 1001.0), (1e4, 1e4 + 8.0)] {
        let (want_mean, want_var) = stable_f64(f64::from(t0), f64::from(t1));
        let stable = conical_frustum_moments(t0, t1, 0.001);
        let naive = conical_frustum_moments_naive(t0, t1, 0.001);
        let rel = |got: f32, want: f64| (f64::from(got) - want).abs() / want.abs();
        assert!(
            rel(stable.t_var, want_var) < TOL_STABLE_REL,
            "stable t_var {} vs {want_var} at [{t0}, {t1}]",
            stable.t_var
        );
        assert!(rel(stable.t_mean, want_mean) < 1e-6, "stable t_mean {} vs {want_mean}", stable.t_mean);
        assert!(
            rel(naive.t_var, want_var) > 0.5 || !naive.t_var.is_finite(),
            "expected the naive f32 t_var to be badly wrong at [{t0}, {t1}], got {} vs {want_var}",
            naive.t_var
        );
    }
}

#[test]
fn both_forms_agree_where_f32_is_comfortable() {
    let s = conical_frustum_moments(2.0, 3.0, 0.01);
    let n = conical_frustum_moments_naive(2.0, 3.0, 0.01);
    assert!((s.t_mean - n.t_mean).abs() < 1e-5);
    assert!((s.t_var - n.t_var).abs() < 1e-4 * s.t_var.abs().max(1e-3));
    assert!((s.r_var - n.r_var).abs() < 1e-5 * s.r_var);
}

/// The textbook (unstable) moments of a conical frustum, as the paper's Eq. 7 writes them.
///
/// Kept here only to show where `f32` loses precision: `t1⁵ - t0⁵` of two close, large `t`
/// cancels catastrophically. Use [`conical_frustum_moments`] instead.
fn conical_frustum_moments_naive(t0: f32, t1: f32, base_radius: f32) -> FrustumMoments {
    let d3 = t1.powi(3) - t0.powi(3);
    let d4 = t1.powi(4) - t0.powi(4);
    let d5 = t1.powi(5) - t0.powi(5);
    let t_mean = (3.0 * d4) / (4.0 * d3);
    let r_var = base_radius * base_radius * (3.0 / 20.0 * d5 / d3);
    let t_mosq = 3.0 / 5.0 * d5 / d3;
    FrustumMoments { t_mean, t_var: t_mosq - t_mean * t_mean, r_var }
}
