//! Unbounded scenes: the scene contraction of mip-NeRF 360 (Barron et al. 2022, section 2) and
//! the spacing of samples out to infinity.
//!
//! A real capture's room reaches far past the object: Mip-NeRF's box cannot hold it. The
//! successor maps all of space into a ball of radius 2 (its Eq. 10),
//!
//! `contract(x) = x` for `|x| <= 1`, `(2 - 1/|x|) x/|x|` otherwise,
//!
//! so the unit ball (where the cameras are, once the scene is scaled, the `mipnerf-data` loaders) keeps its
//! geometry and everything beyond it, out to infinity, fills the shell between radius 1 and 2,
//! with distant space squeezed as disparity is. A conical frustum's Gaussian is carried through the
//! contraction by its linearisation at the mean (the successor's Eq. 9, its `track_linearize`):
//! mean `contract(μ)`, covariance `J Σ Jᵀ` with `J` the contraction's Jacobian at `μ`. Mip-NeRF's
//! IPE encodes along the axes, so it needs only the diagonal of `J Σ Jᵀ`, which is computed exactly
//! from the full (not the diagonal) frustum covariance ([`contract_frustum`]).
//!
//! With `r = |x| > 1` the Jacobian scales by `(2 - 1/r)/r` across the direction of `x` and by
//! `1/r²` along it ([`contract_jacobian`]); [`contract_frustum`] forms the diagonal of `J Σ Jᵀ`
//! in a closed form that loses nothing to cancellation where the two scales differ most.
//!
//! Samples along a ray are spaced in a normalised distance `s` (the successor's section 2.1):
//! linearly in `t` while `t < 1` and linearly in disparity beyond, `s = t/2` for `t < 1`, `s = 1 -
//! 1/(2t)` after ([`ray_distance_to_s`]), the one-dimensional picture of the contraction, so `s = 1`
//! is infinity. The coarse level is stratified in `s`, and the fine level resamples the coarse
//! histogram in `s` ([`crate::stages::resample_intervals`]), as the successor's sampler does.

use glam::{Mat3, Vec3};

use crate::mip::{FrustumMoments, Gaussian, lift_gaussian};

/// The far bound of every ray of an unbounded scene (world units along the ray's direction): far
/// enough to stand for infinity (`contract` maps it within `1e-6` of the sphere of radius 2, and
/// `s` within `5e-7` of 1), as the successor's `far = 1e6`.
pub const UNBOUNDED_FAR: f32 = 1e6;

/// `contract(x)`: the identity inside the unit ball, `(2 - 1/|x|) x/|x|` outside it. Points as
/// far as `1e18` from the origin (whose squared length is a finite `f32`).
#[must_use]
#[inline]
pub fn contract(x: Vec3) -> Vec3 {
    let r2 = x.length_squared();
    if r2 <= 1.0 {
        return x;
    }
    let r = r2.sqrt();
    x * ((2.0 - 1.0 / r) / r)
}

/// The contraction's Jacobian at `x` (symmetric): the identity inside the unit ball; outside it,
/// with `r = |x|`, the scale `a = (2 - 1/r)/r` across the direction of `x` and `c = 1/r²` along
/// it, `J = a I + (c - a) x xᵀ/r²`. Its diagonal is formed as `(a (r² - xᵢ²) + c xᵢ²)/r²`, with
/// `r² - xᵢ²` the sum of the other two squares, so that the small radial scale `c` is not lost to
/// cancellation far out (where `c - a ≈ -a`).
#[must_use]
#[inline]
pub fn contract_jacobian(x: Vec3) -> Mat3 {
    let x2 = x * x;
    let r2 = x2.element_sum();
    if r2 <= 1.0 {
        return Mat3::IDENTITY;
    }
    let r = r2.sqrt();
    let a = (2.0 - 1.0 / r) / r;
    let c = 1.0 / r2;
    let others = Vec3::new(x2.y + x2.z, x2.x + x2.z, x2.x + x2.y);
    let diag = (others * a + x2 * c) / r2;
    let off = -2.0 * (r - 1.0) / (r2 * r2);
    let (xy, xz, yz) = (off * x.x * x.y, off * x.x * x.z, off * x.y * x.z);
    Mat3::from_cols(Vec3::new(diag.x, xy, xz), Vec3::new(xy, diag.y, yz), Vec3::new(xz, yz, diag.z))
}

/// How much the contraction scales lengths across the direction of `x` (at `x`): 1 inside the
/// unit ball, `(2 - 1/r)/r` outside it (`r = |x|`). A cone from a camera inside the ball crosses
/// the contracted shells nearly radially, so its cross-section shrinks by this factor.
#[must_use]
#[inline]
pub fn contraction_across(x: Vec3) -> f32 {
    let r2 = x.length_squared();
    if r2 <= 1.0 {
        return 1.0;
    }
    let r = r2.sqrt();
    (2.0 - 1.0 / r) / r
}

/// A Gaussian with a diagonal covariance (an isotropic probe, [`crate::occupancy`]'s cells, or
/// any point query) carried through the contraction: unchanged inside the unit ball, else mean
/// `contract(μ)` and the diagonal of `J diag(Σ) Jᵀ`, `Σₖ Jᵢₖ² Σₖₖ`.
#[must_use]
pub fn contract_gaussian(g: &Gaussian) -> Gaussian {
    let x = g.mean;
    if x.length_squared() <= 1.0 {
        return *g;
    }
    let j = contract_jacobian(x);
    let row = |i: usize| j.row(i);
    let diag = Vec3::new(
        (row(0) * row(0) * g.cov_diag).element_sum(),
        (row(1) * row(1) * g.cov_diag).element_sum(),
        (row(2) * row(2) * g.cov_diag).element_sum(),
    );
    Gaussian { mean: contract(x), cov_diag: diag }
}

/// The Gaussian of one conical frustum (or cylinder) of a ray with origin `origin` and direction
/// `d`, with moments `m` ([`crate::mip::conical_frustum_moments`]), carried through the contraction:
/// inside the unit ball exactly [`lift_gaussian`]'s (plus the origin), outside it the mean
/// contracted and the diagonal of `J Σ Jᵀ` for the frustum's full covariance
/// `Σ = t_var d dᵀ + r_var (I - d dᵀ/|d|²)`, in closed form: with `u = J d` and `Jᵢ` the rows of
/// `J`, `(J Σ Jᵀ)ᵢᵢ = t_var uᵢ² + r_var |Jᵢ × d|²/|d|²` (the part across the ray as a cross
/// product, which cannot go negative).
#[must_use]
#[inline]
pub fn contract_frustum(origin: Vec3, d: Vec3, m: FrustumMoments) -> Gaussian {
    let mut g = lift_gaussian(d, m);
    g.mean += origin;
    let x = g.mean;
    if x.length_squared() <= 1.0 {
        return g;
    }
    let j = contract_jacobian(x);
    let u = j * d;
    let inv_d_mag_sq = 1.0 / d.length_squared().max(1e-10);
    let across = |i: usize| j.row(i).cross(d).length_squared() * inv_d_mag_sq;
    let cov_diag = u * u * m.t_var + Vec3::new(across(0), across(1), across(2)) * m.r_var;
    Gaussian { mean: contract(x), cov_diag }
}

/// The normalised distance `s` in `[0, 1)` of distance `t` (`>= 0`, units of the ray's
/// direction): `t/2` for `t < 1`, `1 - 1/(2t)` beyond (linear near, linear in disparity far,
/// continuous with its slope at `t = 1`).
#[must_use]
#[inline]
pub fn ray_distance_to_s(t: f32) -> f32 {
    if t < 1.0 { 0.5 * t } else { 1.0 - 0.5 / t }
}

/// The inverse of [`ray_distance_to_s`]: `2s` for `s < 1/2`, `1/(2 - 2s)` beyond.
#[must_use]
#[inline]
pub fn s_to_ray_distance(s: f32) -> f32 {
    if s < 0.5 { 2.0 * s } else { 1.0 / (2.0 - 2.0 * s) }
}

#[cfg(test)]
mod tests {
    use glam::DVec3;

    use super::*;
    use crate::mip::{conical_frustum_moments, lift_gaussian_full_cov};

    /// The successor's Eq. 10 in `f64`, for finite differences.
    fn contract_f64(x: DVec3) -> DVec3 {
        let r = x.length();
        if r <= 1.0 { x } else { x * ((2.0 - 1.0 / r) / r) }
    }

    /// The Jacobian of [`contract_f64`] by central differences (step `1e-6 max(|x|, 1)`, so that
    /// far out, where the entries are as small as `1/|x|²`, rounding does not swamp them), column
    /// `j` the derivative along axis `j`.
    fn jacobian_by_differences(x: DVec3) -> [[f64; 3]; 3] {
        let h = 1e-6 * x.length().max(1.0);
        let mut j = [[0.0; 3]; 3];
        for (c, e) in [DVec3::X, DVec3::Y, DVec3::Z].into_iter().enumerate() {
            let dv = (contract_f64(x + e * h) - contract_f64(x - e * h)) / (2.0 * h);
            for (r, row) in j.iter_mut().enumerate() {
                row[c] = dv[r];
            }
        }
        j
    }

    /// Relative error allowed between the `f32` contraction and its `f64` finite-difference
    /// reference (the differences themselves are good to about 1e-9).
    const CONTRACTION_TOL: f64 = 2e-5;

    #[test]
    fn contraction_is_the_successors_eq_10() {
        // The unit ball is untouched; outside, the radius becomes 2 - 1/r along the same direction.
        for x in [Vec3::ZERO, Vec3::new(0.3, -0.2, 0.5), Vec3::new(0.0, 0.0, 1.0)] {
            assert_eq!(contract(x), x);
        }
        assert!((contract(Vec3::new(2.0, 0.0, 0.0)) - Vec3::new(1.5, 0.0, 0.0)).length() < 1e-7);
        assert!((contract(Vec3::new(0.0, -4.0, 0.0)) - Vec3::new(0.0, -1.75, 0.0)).length() < 1e-7);
        let x = Vec3::new(3.0, 4.0, 12.0); // |x| = 13
        let want = x / 13.0 * (2.0 - 1.0 / 13.0);
        assert!((contract(x) - want).length() < 1e-6, "{:?} vs {want:?}", contract(x));
        // Continuous at the sphere, inside the ball of radius 2 everywhere (to rounding), 2 at
        // infinity.
        let e = 1e-4;
        assert!((contract(Vec3::new(1.0 + e, 0.0, 0.0)).x - 1.0).abs() < 2.0 * e);
        for &r in &[1.5f32, 10.0, 1e3, 1e6, 1e15] {
            let c = contract(Vec3::new(r, r, -r) / 3f32.sqrt()).length();
            assert!(c <= 2.0 + 4.0 * f32::EPSILON && c > 1.0, "|contract| {c} at radius {r}");
        }
        assert!((contract(Vec3::new(0.0, UNBOUNDED_FAR, 0.0)).y - 2.0).abs() <= 1e-6);
    }

    #[test]
    fn jacobian_matches_finite_differences() {
        let points = [
            DVec3::new(0.2, 0.1, -0.3),
            DVec3::new(1.2, 0.0, 0.0),
            DVec3::new(-0.9, 1.3, 0.4),
            DVec3::new(3.0, -2.0, 5.0),
            DVec3::new(40.0, 7.0, -11.0),
        ];
        for x in points {
            let j = contract_jacobian(x.as_vec3());
            let fd = jacobian_by_differences(x);
            let scale = fd.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
            for (r, fd_row) in fd.iter().enumerate() {
                for (c, &want) in fd_row.iter().enumerate() {
                    let ours = f64::from(j.row(r)[c]);
                    let err = (ours - want).abs() / scale;
                    assert!(err < CONTRACTION_TOL, "J[{r}][{c}] at {x:?}: {ours} vs {want}");
                }
            }
        }
    }

    #[test]
    fn contracted_frustum_is_the_linearisation_of_its_full_covariance() {
        // J Σ Jᵀ with J from finite differences and Σ the full frustum covariance, in f64: the
        // closed form must give its diagonal.
        let cases = [
            (Vec3::new(0.1, -0.2, 0.9), Vec3::new(0.3, 0.5, -1.0), 0.5f32, 0.7f32, 0.004f32),
            (Vec3::new(0.0, 0.8, 0.0), Vec3::new(-1.0, 0.2, 0.3), 2.0, 2.6, 0.002),
            (Vec3::new(0.5, 0.0, -0.5), Vec3::new(0.7, 0.7, 0.2), 8.0, 30.0, 0.01),
            (Vec3::new(0.9, 0.1, 0.0), Vec3::new(1.0, 0.1, -0.05), 100.0, 3000.0, 0.003),
        ];
        for (o, d, t0, t1, radius) in cases {
            let m = conical_frustum_moments(t0, t1, radius);
            let g = contract_frustum(o, d, m);
            let mean = (o + d * m.t_mean).as_dvec3();
            let sigma = lift_gaussian_full_cov(d, m);
            let sigma = |r: usize, c: usize| f64::from(sigma.col(c)[r]);
            let j = jacobian_by_differences(mean);
            assert!((g.mean.as_dvec3() - contract_f64(mean)).length() < 1e-6 * contract_f64(mean).length());
            for i in 0..3 {
                let mut want = 0.0;
                for p in 0..3 {
                    for q in 0..3 {
                        want += j[i][p] * sigma(p, q) * j[i][q];
                    }
                }
                let got = f64::from(g.cov_diag[i]);
                assert!(
                    (got - want).abs() <= CONTRACTION_TOL * want.abs().max(1e-12),
                    "cov[{i}] of [{t0}, {t1}] along {d:?}: {got} vs {want}"
                );
            }
        }
    }

    #[test]
    fn inside_the_ball_the_frustum_is_mipnerfs() {
        let (o, d) = (Vec3::new(0.1, 0.2, -0.3), Vec3::new(0.2, -0.1, 1.0));
        let m = conical_frustum_moments(0.2, 0.3, 0.01);
        let mut want = lift_gaussian(d, m);
        want.mean += o;
        assert_eq!(contract_frustum(o, d, m), want);
        let g = Gaussian { mean: Vec3::new(0.5, 0.5, 0.5), cov_diag: Vec3::splat(0.01) };
        assert_eq!(contract_gaussian(&g), g);
    }

    #[test]
    fn isotropic_gaussians_shrink_along_the_radius_as_one_over_r_squared() {
        // At x = (r, 0, 0), J = diag(1/r², (2 - 1/r)/r, (2 - 1/r)/r).
        let r = 5.0f32;
        let v = 0.04f32;
        let g = contract_gaussian(&Gaussian { mean: Vec3::new(r, 0.0, 0.0), cov_diag: Vec3::splat(v) });
        let radial = v / (r * r * r * r);
        let across = v * ((2.0 - 1.0 / r) / r).powi(2);
        assert!((g.cov_diag.x - radial).abs() < 1e-6 * radial, "{} vs {radial}", g.cov_diag.x);
        assert!((g.cov_diag.y - across).abs() < 1e-6 * across);
        assert_eq!(g.cov_diag.y, g.cov_diag.z);
    }

    #[test]
    fn spacing_is_linear_near_and_disparity_far() {
        assert_eq!(ray_distance_to_s(0.0), 0.0);
        assert_eq!(ray_distance_to_s(0.5), 0.25);
        assert_eq!(ray_distance_to_s(1.0), 0.5);
        assert_eq!(ray_distance_to_s(2.0), 0.75);
        assert!(ray_distance_to_s(UNBOUNDED_FAR) < 1.0);
        // Linear in disparity beyond 1: equal steps in s are equal steps in 1/t.
        let (a, b, c) = (s_to_ray_distance(0.6), s_to_ray_distance(0.7), s_to_ray_distance(0.8));
        assert!(((1.0 / a - 1.0 / b) - (1.0 / b - 1.0 / c)).abs() < 1e-6);
        for &t in &[0.0f32, 0.01, 0.3, 0.999, 1.0, 1.5, 7.0, 123.0, 1e4] {
            let back = s_to_ray_distance(ray_distance_to_s(t));
            assert!((back - t).abs() <= 1e-5 * t.max(1.0) * t.max(1.0), "t {t}: {back}");
        }
    }
}
