//! End to end through the public API: a camera's rays, sampled, cast into Gaussians, encoded,
//! shaded by a known density field (a slab) in place of the MLP, volume rendered, resampled and
//! rendered again: the depth comes out where the slab is, and the fine level concentrates its
//! samples there, as Mip-NeRF's hierarchical sampling should.
#![allow(clippy::unwrap_used, missing_docs)]

use mipnerf_core::RayShape;
use mipnerf_core::cone;
use mipnerf_core::mip::{self, Gaussian};
use mipnerf_core::sampling::{PdfSamples, RESAMPLE_PADDING};
use mipnerf_core::{Camera, PixelCenters, resample_along_rays, sample_along_rays, volumetric_rendering};

/// The slab occupies world z in [SLAB_Z - SLAB_HALF, SLAB_Z + SLAB_HALF].
const SLAB_Z: f32 = -1.0;
const SLAB_HALF: f32 = 0.15;

/// Density of the slab seen through a Gaussian: the fraction of its mass inside the slab.
fn density(g: &Gaussian) -> f32 {
    let sd = g.cov_diag.z.sqrt().max(1e-6);
    let cdf = |x: f32| 0.5 * (1.0 + erf((x - g.mean.z) / (sd * std::f32::consts::SQRT_2)));
    60.0 * (cdf(SLAB_Z + SLAB_HALF) - cdf(SLAB_Z - SLAB_HALF))
}

fn erf(x: f32) -> f32 {
    // Abramowitz-Stegun 7.1.26, |error| < 1.5e-7.
    let t = 1.0 / (1.0 + 0.327_591_1 * x.abs());
    let y = 1.0
        - (((((1.061_405_4 * t - 1.453_152_1) * t) + 1.421_413_7) * t - 0.284_496_74) * t + 0.254_829_6)
            * t
            * (-x * x).exp();
    y.copysign(x)
}

#[test]
fn a_slab_renders_at_its_depth_and_the_fine_level_samples_it() {
    // Camera at z = 2 looking down -z: the slab's front face is 2.85 away along the axis.
    let pose = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 2.0]];
    let cam = Camera::from_camera_angle_x(8, 8, 0.7, pose).unwrap();
    let rays = cam.generate_rays(PixelCenters::Centered, 0.5, 6.0, 1.0);
    let n = 64;
    let (mut t, mut t_fine) = (vec![0.0; n + 1], vec![0.0; n + 1]);
    let mut gs = vec![Gaussian::default(); n];
    let mut enc = vec![0.0; mip::ipe_len(0, 16)];
    let mut w = vec![0.0; n];
    let rgb = vec![[0.8, 0.2, 0.1]; n];
    for ray in &rays {
        sample_along_rays(ray.near, ray.far, false, None, &mut t);
        cone::cast_ray(&t, ray.origin, ray.direction, ray.radius, RayShape::Cone, &mut gs);
        for g in &gs {
            mip::integrated_pos_enc(g, 0, 16, &mut enc);
            assert!(enc.iter().all(|x| x.is_finite() && x.abs() <= 1.0));
        }
        let sigma: Vec<f32> = gs.iter().map(density).collect();
        let coarse =
            volumetric_rendering(&rgb, &sigma, &t, ray.direction, mipnerf_core::render::background(true), &mut w);
        // Front face at depth 2.85 along the camera axis (t is depth since direction.z = -1).
        assert!(coarse.acc > 0.99, "slab not opaque: acc {}", coarse.acc);
        assert!((coarse.distance - 2.9).abs() < 0.1, "coarse depth {}", coarse.distance);
        assert!((coarse.rgb[0] - 0.8).abs() < 0.02, "colour {:?}", coarse.rgb);

        resample_along_rays(&t, &w, RESAMPLE_PADDING, PdfSamples::Deterministic, &mut t_fine);
        let near_slab = t_fine.iter().filter(|&&x| (2.6..3.4).contains(&x)).count();
        assert!(near_slab > n / 2, "fine level put only {near_slab} of {} edges near the slab", n + 1);
        cone::cast_ray(&t_fine, ray.origin, ray.direction, ray.radius, RayShape::Cone, &mut gs);
        let sigma: Vec<f32> = gs.iter().map(density).collect();
        let fine =
            volumetric_rendering(&rgb, &sigma, &t_fine, ray.direction, mipnerf_core::render::background(true), &mut w);
        assert!((fine.distance - 2.87).abs() < 0.05, "fine depth {}", fine.distance);
    }
}
