//! The cast-and-IPE stage's kernel (`cast_ipe.wgsl`) against `stages::cast_and_encode`.
//! How every kernel test runs and compares: `tests/common/mod.rs`.
#![allow(clippy::unwrap_used, missing_docs)]

mod common;
use common::*;

#[test]
fn cast_ipe_matches_cpu_reference() {
    let Some(ctx) = context_or_skip("cast_ipe_matches_cpu_reference") else {
        return;
    };
    let kernel = CastIpeKernel::new(&ctx).unwrap();
    let rays = test_rays(12);
    let n = 16usize;
    let mut t = vec![0.0; rays.len() * (n + 1)];
    let ids: Vec<u32> = (0..rays.len() as u32).collect();
    let mode = Mode::Train { seed: 7, step: 0 };
    stages::sample_intervals(&rays, stages::Sample { n_samples: n, spacing: Spacing::Depth, mode }, &ids, &mut t);
    // An unbounded scene: the same camera moved into the unit ball, edges out to infinity, so
    // that each ray has Gaussians inside the ball (unchanged) and outside it (contracted).
    let inside: Vec<Ray> = rays
        .iter()
        .map(|r| Ray { origin: r.origin * (0.9 / r.origin.length()), near: 0.1, far: UNBOUNDED_FAR, ..*r })
        .collect();
    let mut t_inside = vec![0.0; rays.len() * (n + 1)];
    stages::sample_intervals(
        &inside,
        stages::Sample { n_samples: n, spacing: Spacing::Unbounded, mode },
        &ids,
        &mut t_inside,
    );
    let degrees = (0, 16);
    let mut bad = Vec::new();
    // Unbounded scenes cast cones only (`Model::new` refuses cylinders there).
    for (shape, unbounded) in [(RayShape::Cone, false), (RayShape::Cylinder, false), (RayShape::Cone, true)] {
        let input = if unbounded { (&inside[..], &t_inside[..]) } else { (&rays[..], &t[..]) };
        let (min_deg, max_deg) = degrees;
        let stage =
            stages::CastIpe { n_samples: n, shape, unbounded, encoding: PointEncoding::Integrated, min_deg, max_deg };
        let check = check_kernel(
            &format!("cast_ipe {shape:?} unbounded {unbounded} on {}", ctx.adapter().name),
            |(rays, t): &(&[Ray], &[f32])| {
                let mut x = vec![0.0; rays.len() * n * ipe_len(degrees.0, degrees.1)];
                stages::cast_and_encode(rays, t, stage, Precision::F32, &mut x);
                vec![("features", x)]
            },
            |(rays, t)| kernel.run(&ctx, rays, t, stage).map(|x| vec![("features", x)]),
            &input,
            |_| Tolerance::abs(sin_feature_tolerance(&ctx)),
        );
        bad.extend(check.into_mismatches());
    }
    assert_none(&bad);
}

#[test]
fn cast_ipe_rejects_inconsistent_sizes() {
    let Some(ctx) = context_or_skip("cast_ipe_rejects_inconsistent_sizes") else {
        return;
    };
    let kernel = CastIpeKernel::new(&ctx).unwrap();
    let rays = vec![Ray { direction: Vec3::NEG_Z, ..Ray::default() }; 2];
    let stage = mipnerf_core::stages::CastIpe {
        n_samples: 2,
        shape: RayShape::Cone,
        unbounded: false,
        encoding: PointEncoding::Integrated,
        min_deg: 0,
        max_deg: 16,
    };
    let err = kernel.run(&ctx, &rays, &[2.0, 3.0, 4.0], stage).unwrap_err();
    assert!(err.to_string().contains("3 t values for 2 rays"), "{err}");
}
