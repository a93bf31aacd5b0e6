//! Cone casting (section 3.1 of the Mip-NeRF paper), in one place: a pixel becomes a cone
//! ([`Ray`]: apex at the camera centre, axis through the pixel, radius at the image plane from the
//! pixel's footprint, [`radius_from_spacing`]), and the cone's intervals between sample edges
//! become Gaussians ([`cast_ray`], with the frustum maths of [`crate::mip`]), then IPE features
//! ([`crate::stages::cast_and_encode`]).
//!
//! Where the rays come from: [`crate::camera::Camera::ray_at`] (pinhole cameras),
//! [`crate::dataset::ndc_ray`] (forward-facing scenes in NDC) and the sub-pixel cones of
//! supersampling ([`crate::dataset`]); all of them take their radius from [`radius_from_spacing`].

use glam::Vec3;

use crate::contract::contract_frustum;
use crate::mip::{Gaussian, conical_frustum_moments, cylinder_moments};

/// One ray (a cone) through one pixel, in the official code's terms.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Ray {
    /// Camera centre in world space.
    pub origin: Vec3,
    /// Unnormalised direction: `t = 1` lies on the image plane at unit depth.
    pub direction: Vec3,
    /// `direction` normalised.
    pub viewdir: Vec3,
    /// Cone radius at `t = 1`: the spacing to the neighbouring pixel's direction times
    /// `2/sqrt(12)`, so that the cone's cross-section has the pixel footprint's variance.
    pub radius: f32,
    /// Loss weight of this ray (`4^j` at scale `j` of a multiscale dataset: its footprint area).
    pub lossmult: f32,
    /// Near bound along the ray.
    pub near: f32,
    /// Far bound along the ray.
    pub far: f32,
}

/// The cone's radius at `t = 1` for a pixel whose neighbouring rays' directions are `spacing`
/// apart at `t = 1` (world units): `spacing * 2/sqrt(12)`, so that the cone's cross-section has the
/// variance of the pixel's square footprint (the official code's `dx * 2 / sqrt(12)`). Computed in
/// `f64` and rounded to `f32` once.
#[must_use]
#[inline]
pub fn radius_from_spacing(spacing: f64) -> f32 {
    debug_assert!(spacing.is_finite(), "radius_from_spacing: non-finite spacing {spacing}");
    (spacing * 2.0 / 12f64.sqrt()) as f32
}

/// The shape cast through each pixel: a cone (Mip-NeRF) or a cylinder (used with NDC rays).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
#[repr(u32)]
pub enum RayShape {
    /// A cone whose radius grows linearly with `t`: radius `t * base_radius`.
    #[default]
    Cone = 0,
    /// A cylinder of constant radius (the official choice for forward-facing NDC scenes).
    Cylinder = 1,
}

/// Casts one ray: the Gaussian of every interval between consecutive `t_vals` (`n + 1` edges give
/// `n` Gaussians, written to `out`), in world space (origin added).
///
/// # Panics
/// If `out.len() + 1 != t_vals.len()`.
pub fn cast_ray(t_vals: &[f32], origin: Vec3, direction: Vec3, radius: f32, shape: RayShape, out: &mut [Gaussian]) {
    assert_eq!(out.len() + 1, t_vals.len(), "cast_ray: need one more t value than Gaussians");
    for (g, t) in out.iter_mut().zip(t_vals.windows(2)) {
        let mut lifted = crate::mip::lift_gaussian(direction, moments(shape, t[0], t[1], radius));
        lifted.mean += origin;
        *g = lifted;
    }
}

/// [`cast_ray`] in an unbounded scene: each interval's Gaussian carried through the scene
/// contraction ([`contract_frustum`]: unchanged inside the unit ball, linearised outside it).
///
/// # Panics
/// If `out.len() + 1 != t_vals.len()`.
pub fn cast_ray_contracted(
    t_vals: &[f32],
    origin: Vec3,
    direction: Vec3,
    radius: f32,
    shape: RayShape,
    out: &mut [Gaussian],
) {
    assert_eq!(out.len() + 1, t_vals.len(), "cast_ray_contracted: need one more t value than Gaussians");
    for (g, t) in out.iter_mut().zip(t_vals.windows(2)) {
        *g = contract_frustum(origin, direction, moments(shape, t[0], t[1], radius));
    }
}

/// The moments of the interval `[t0, t1]` of a ray of this shape.
#[inline]
fn moments(shape: RayShape, t0: f32, t1: f32, radius: f32) -> crate::mip::FrustumMoments {
    match shape {
        RayShape::Cone => conical_frustum_moments(t0, t1, radius),
        RayShape::Cylinder => cylinder_moments(t0, t1, radius),
    }
}
