//! Property tests of the invariants the rest of the system relies on.
#![allow(clippy::unwrap_used, missing_docs)]

use glam::Vec3;
use mipnerf_core::mip::{self, Gaussian};
use mipnerf_core::render::volumetric_rendering;
use mipnerf_core::rng::{RayRng, Stream};
use mipnerf_core::sampling::{PdfSamples, RESAMPLE_PADDING, resample_along_rays, sample_along_rays};
use proptest::prelude::*;

/// Tolerance of `sum(weights) == acc`: both are the same f32 sum in the same order.
const TOL_WEIGHT_SUM: f32 = 1e-6;

fn edges(n: usize) -> impl Strategy<Value = (f32, f32, Vec<f32>)> {
    (0.1f32..5.0, 0.5f32..20.0, prop::collection::vec(0.0f32..1.0, n)).prop_map(|(near, span, mut u)| {
        u.sort_by(f32::total_cmp);
        let far = near + span;
        let mut t: Vec<f32> = u.iter().map(|s| near + s * span).collect();
        t[0] = near;
        *t.last_mut().unwrap() = far;
        (near, far, t)
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    #[test]
    fn weights_sum_to_acc_and_acc_is_an_opacity(
        (_, _, t) in edges(17),
        density in prop::collection::vec(0.0f32..50.0, 16),
        rgb in prop::collection::vec(0.0f32..1.0, 48),
        white in any::<bool>(),
    ) {
        let rgb: Vec<[f32; 3]> = rgb.chunks(3).map(|c| [c[0], c[1], c[2]]).collect();
        let mut w = vec![0.0; 16];
        let out = volumetric_rendering(&rgb, &density, &t, Vec3::new(0.1, 0.2, -1.0), mipnerf_core::render::background(white), &mut w);
        let sum: f32 = w.iter().sum();
        prop_assert!((sum - out.acc).abs() <= TOL_WEIGHT_SUM, "sum {} acc {}", sum, out.acc);
        prop_assert!((0.0..=1.0).contains(&out.acc), "acc {}", out.acc);
        prop_assert!(w.iter().all(|&x| x >= 0.0));
        prop_assert!(out.distance >= t[0] && out.distance <= t[16]);
        prop_assert!(out.rgb.iter().all(|&c| (-1e-6..=1.0 + 1e-6).contains(&c)), "rgb {:?}", out.rgb);
    }

    #[test]
    fn resampled_edges_are_sorted_and_inside_near_far(
        (near, far, t) in edges(33),
        weights in prop::collection::vec(prop_oneof![Just(0.0f32), 0.0f32..1.0], 32),
        seed in any::<u32>(),
        randomized in any::<bool>(),
    ) {
        let samples = if randomized { PdfSamples::Stratified(RayRng::new(seed, 0, Stream::ResampleOffsets, 0)) } else { PdfSamples::Deterministic };
        let mut out = vec![0.0; 33];
        resample_along_rays(&t, &weights, RESAMPLE_PADDING, samples, &mut out);
        prop_assert!(out.windows(2).all(|p| p[0] <= p[1]), "not sorted: {:?}", out);
        prop_assert!(out.iter().all(|&x| x >= near && x <= far), "outside [{}, {}]: {:?}", near, far, out);
    }

    #[test]
    fn jittered_coarse_edges_are_sorted_and_inside_near_far(
        near in 0.1f32..5.0, span in 0.1f32..20.0, seed in any::<u32>(), ray in any::<u32>(), lindisp in any::<bool>(),
    ) {
        let far = near + span;
        let mut t = vec![0.0; 65];
        sample_along_rays(near, far, lindisp, Some(RayRng::new(seed, 3, Stream::SampleJitter, ray)), &mut t);
        prop_assert!(t.windows(2).all(|p| p[0] <= p[1]), "not sorted: {:?}", t);
        prop_assert!(t.iter().all(|&x| x >= near * (1.0 - 1e-6) && x <= far * (1.0 + 1e-6)));
    }

    #[test]
    fn ipe_features_are_bounded_and_shrink_as_variance_grows(
        mean in prop::array::uniform3(-8.0f32..8.0),
        var in prop::array::uniform3(0.0f32..0.5),
        grow in prop::array::uniform3(1.0f32..20.0),
    ) {
        let g1 = Gaussian { mean: Vec3::from_array(mean), cov_diag: Vec3::from_array(var) };
        let g2 = Gaussian { cov_diag: g1.cov_diag * Vec3::from_array(grow), ..g1 };
        let mut f1 = vec![0.0; mip::ipe_len(0, 16)];
        let mut f2 = f1.clone();
        mip::integrated_pos_enc(&g1, 0, 16, &mut f1);
        mip::integrated_pos_enc(&g2, 0, 16, &mut f2);
        prop_assert!(f1.iter().all(|x| x.abs() <= 1.0));
        for (i, (a, b)) in f1.iter().zip(&f2).enumerate() {
            prop_assert!(b.abs() <= a.abs(), "feature {}: |{}| grew to |{}|", i, a, b);
        }
    }
}
