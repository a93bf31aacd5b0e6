//! Property tests of the invariants the rest of the system relies on.
#![allow(clippy::unwrap_used, missing_docs)]

use glam::Vec3;
use mipnerf_core::cone::cast_ray_contracted;
use mipnerf_core::contract::UNBOUNDED_FAR;
use mipnerf_core::mip::{self, Gaussian};
use mipnerf_core::model::Mode;
use mipnerf_core::render::volumetric_rendering;
use mipnerf_core::rng::{RayRng, Stream};
use mipnerf_core::sampling::{
    PdfSamples, RESAMPLE_PADDING, Spacing, resample_along_rays, sample_along_rays, sample_spaced,
};
use mipnerf_core::{Ray, RayShape, stages};
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
    fn unbounded_edges_are_sorted_and_reach_from_near_to_infinity(
        near in 0.02f32..3.0, seed in any::<u32>(), ray in any::<u32>(), randomized in any::<bool>(),
        weights in prop::collection::vec(prop_oneof![Just(0.0f32), 0.0f32..1.0], 32),
    ) {
        // The coarse edges in s, then the fine ones resampled in s: sorted, inside [near, far]
        // (to the rounding of s near 1, where an ulp of s is a relative 1.2e-7 t of t), and the
        // contracted Gaussians of every interval inside the ball of radius 2.
        let far = UNBOUNDED_FAR;
        let jitter = randomized.then(|| RayRng::new(seed, 3, Stream::SampleJitter, ray));
        let mut t = vec![0.0; 33];
        sample_spaced(near, far, Spacing::Unbounded, jitter, &mut t);
        let inside = |x: f32| x >= near * (1.0 - 1e-6) && x <= far * (1.0 + 0.2);
        prop_assert!(t.windows(2).all(|p| p[0] <= p[1]), "not sorted: {:?}", t);
        prop_assert!(t.iter().all(|&x| inside(x)), "outside [{}, {}]: {:?}", near, far, t);
        prop_assert!(t[0] == near && t[32] == far, "the domain [{}, {}] not kept: {:?}", near, far, t);
        let rays = [Ray { origin: Vec3::new(0.3, -0.2, 0.1), direction: Vec3::new(0.6, 0.8, -0.3), radius: 0.002, near, far, ..Ray::default() }];
        let mut fine = vec![0.0; 33];
        let mode = if randomized { Mode::Train { seed, step: 3 } } else { Mode::Eval };
        stages::resample_intervals(&t, &weights, stages::Resample { n_samples: 32, spacing: Spacing::Unbounded, padding: RESAMPLE_PADDING, level: 1, mode }, &[ray], &mut fine);
        prop_assert!(fine.windows(2).all(|p| p[0] <= p[1]), "not sorted: {:?}", fine);
        prop_assert!(fine.iter().all(|&x| inside(x)), "outside [{}, {}]: {:?}", near, far, fine);
        let mut gs = vec![Gaussian::default(); 32];
        cast_ray_contracted(&fine, rays[0].origin, rays[0].direction, rays[0].radius, RayShape::Cone, &mut gs);
        for g in &gs {
            prop_assert!(g.mean.length() <= 2.0 + 1e-5 && g.cov_diag.is_finite() && g.cov_diag.min_element() >= 0.0, "{:?}", g);
        }
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

/// The fine level of an unbounded scene resamples the coarse histogram in `s`, as the successor
/// does: all the weight in the last coarse interval (from a few units out to infinity) gives fine
/// edges spread evenly in `s` across it, most of them at moderate distances. Resampled in `t`
/// they would be spread evenly in `t`, nearly all beyond `1e5`.
#[test]
fn unbounded_resampling_is_even_in_s_not_in_t() {
    use mipnerf_core::contract::ray_distance_to_s;
    let n = 16;
    let mut t = vec![0.0; n + 1];
    sample_spaced(0.1, UNBOUNDED_FAR, Spacing::Unbounded, None, &mut t);
    let mut weights = vec![0.0f32; n];
    weights[n - 1] = 1.0;
    let mut fine = vec![0.0; n + 1];
    stages::resample_intervals(
        &t,
        &weights,
        stages::Resample { n_samples: n, spacing: Spacing::Unbounded, padding: 0.0, level: 1, mode: Mode::Eval },
        &[0],
        &mut fine,
    );
    let (s0, s1) = (ray_distance_to_s(t[n - 1]), ray_distance_to_s(t[n]));
    // The blur spreads the weight onto the interval before the last: look at the last one's.
    let last: Vec<f32> = fine.iter().copied().filter(|&x| x >= t[n - 1]).collect();
    assert!(last.len() >= n / 2, "{fine:?}");
    let s: Vec<f32> = last.iter().map(|&x| ray_distance_to_s(x)).collect();
    for pair in s.windows(2) {
        let step = pair[1] - pair[0];
        assert!((step - (s1 - s0) / (s.len() - 1) as f32).abs() < 0.2 * (s1 - s0) / (s.len() - 1) as f32, "{s:?}");
    }
    let median = last[last.len() / 2];
    assert!(median < 100.0, "fine edges {last:?}: median {median} (in t they would be near {})", 0.5 * UNBOUNDED_FAR);
}
