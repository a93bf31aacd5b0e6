//! The sampling kernels (`sample.wgsl`, `view_enc.wgsl`) against `stages::sample_intervals`, `resample_intervals` and the view encoding.
//! How every kernel test runs and compares: `tests/common/mod.rs`.
#![allow(clippy::unwrap_used, missing_docs)]

mod common;
use common::*;

/// GPU vs CPU fine edges of the wide resampling (32 invocations per ray), absolute, in scene
/// units: its CDF sums the weights by block, so CDF entries differ from the CPU's sequential sums
/// by a few ulp of 1 (~2e-7); an edge moves by that times its coarse interval over the CDF step,
/// which the near-zero weights here make small. Measured up to 4.2e-5 on edges of 0.5 to 8.
const TOL_GPU_RESAMPLE_WIDE_ABS: f32 = 1e-4;

/// The same for the fine edges of the wide resampling, whose CDF is summed by block (see
/// [`TOL_GPU_RESAMPLE_WIDE_ABS`]): measured up to 4.5e-6 in `s` on lavapipe.
const TOL_GPU_RESAMPLE_WIDE_S_ABS: f32 = 2e-5;

#[test]
fn sampling_and_resampling_match_cpu_reference() {
    use mipnerf_core::contract::ray_distance_to_s;
    use mipnerf_core::sampling::RESAMPLE_PADDING;
    use mipnerf_gpu::kernels::sample::{CoarseLevel, ResampleVariant, SampleKernels};
    use rand::{Rng, SeedableRng, rngs::SmallRng};
    let Some(ctx) = context_or_skip("sampling_and_resampling_match_cpu_reference") else { return };
    let mut bad = Vec::new();
    // Both resampling entry points, whatever the adapter would pick; 24 samples (fewer than the
    // wide kernel's 32 lanes) and 75 (blocks of 3, the last lanes short or empty).
    for (variant, s) in [
        (ResampleVariant::PerRay, 24usize),
        (ResampleVariant::Wide, 24),
        (ResampleVariant::PerRay, 75),
        (ResampleVariant::Wide, 75),
    ] {
        let k = SampleKernels::with_variant(&ctx, variant).unwrap();
        // Scattered batch indices, as the rays an occupancy grid lets through have.
        let (nr, seed, step) = (37usize, 5u32, 9u32);
        let ids: Vec<u32> = (0..nr as u32).map(|r| 100 + 3 * r).collect();
        let mut rng = SmallRng::seed_from_u64(s as u64);
        let bounded: Vec<Ray> = (0..nr)
            .map(|_| {
                let near = rng.random_range(0.5..3.0);
                Ray { near, far: near + rng.random_range(0.5..5.0), ..Ray::default() }
            })
            .collect();
        // Unbounded scenes: nears inside and outside the unit distance, every far at infinity's
        // stand-in.
        let unbounded: Vec<Ray> =
            (0..nr).map(|r| Ray { near: 0.05 + 0.07 * r as f32, far: UNBOUNDED_FAR, ..Ray::default() }).collect();
        // Weights with zeros and spikes.
        let weights: Vec<f32> =
            (0..nr * s).map(|i| if i % 7 == 0 { 0.0 } else { rng.random_range(0.0..1.0f32).powi(4) }).collect();
        let spacings = [Spacing::Depth, Spacing::Disparity, Spacing::Unbounded];
        for (spacing, randomized) in spacings.into_iter().flat_map(|sp| [(sp, false), (sp, true)]) {
            let mode = mode_of(randomized, seed, step);
            let coarse_how = stages::Sample { n_samples: s, spacing, mode };
            let fine_how = stages::Resample { n_samples: s, spacing, padding: RESAMPLE_PADDING, level: 1, mode };
            let rays = if spacing == Spacing::Unbounded { &unbounded } else { &bounded };
            // Unbounded edges are compared in s (TOL_GPU_SAMPLE_S_ABS).
            let compared = |name: &'static str, t: Vec<f32>| -> (&'static str, Vec<f32>) {
                if spacing == Spacing::Unbounded {
                    (name, t.into_iter().map(ray_distance_to_s).collect())
                } else {
                    (name, t)
                }
            };
            let cpu = |(rays, w): &(Vec<Ray>, Vec<f32>)| -> Outputs {
                let (mut coarse, mut fine) = (vec![0.0; nr * (s + 1)], vec![0.0; nr * (s + 1)]);
                stages::sample_intervals(rays, coarse_how, &ids, &mut coarse);
                stages::resample_intervals(&coarse, w, fine_how, &ids, &mut fine);
                vec![compared("coarse", coarse), compared("fine", fine)]
            };
            // GPU, outputs poisoned.
            let on_gpu = |(rays, w): &(Vec<Ray>, Vec<f32>)| -> Result<Outputs, GpuError> {
                let bounds: Vec<f32> = rays.iter().flat_map(|r| [r.near, r.far]).collect();
                let b_bounds = ctx.storage_buffer("bounds", &bounds, false);
                let b_w = ctx.storage_buffer("weights", w, false);
                let b_t = ctx.storage_buffer("t coarse", &vec![f32::NAN; nr * (s + 1)], true);
                let b_f = ctx.storage_buffer("t fine", &vec![f32::NAN; nr * (s + 1)], true);
                let b_ids = ctx.storage_buffer("ray ids", &ids, false);
                let mut rec = Recorder::new(&ctx, "sample test");
                k.stratified(&mut rec, nr, coarse_how, &b_bounds, &b_ids, &b_t)?;
                k.resample(&mut rec, nr, fine_how, CoarseLevel { t: &b_t, weights: &b_w }, &b_ids, &b_f)?;
                let _ = rec.submit();
                Ok(vec![
                    compared("coarse", ctx.read_f32(&b_t, nr * (s + 1))?),
                    compared("fine", ctx.read_f32(&b_f, nr * (s + 1))?),
                ])
            };
            let tol = |name: &str| match (name, variant) {
                ("fine", ResampleVariant::Wide) if spacing == Spacing::Unbounded => {
                    Tolerance::abs(TOL_GPU_RESAMPLE_WIDE_S_ABS)
                }
                _ if spacing == Spacing::Unbounded => Tolerance::abs(TOL_GPU_SAMPLE_S_ABS),
                ("coarse", _) => Tolerance::new(0.0, TOL_GPU_SAMPLE_REL),
                (_, ResampleVariant::PerRay) => Tolerance::new(1e-6, TOL_GPU_SAMPLE_REL),
                (_, ResampleVariant::Wide) => Tolerance::new(TOL_GPU_RESAMPLE_WIDE_ABS, TOL_GPU_SAMPLE_REL),
            };
            let label = format!("{variant:?} {s} samples {spacing:?} randomized {randomized}");
            // The inverse CDF divides by the density of the blurred weights, small between the
            // spikes: there an edge moves by 1e-5 when the weights and bounds move by a few ulps
            // (measured on an NVIDIA H100), as far as a hardware GPU's other rounding moves it.
            let inputs = (rays.clone(), weights.clone());
            let moved = hardware_perturbations(&ctx, 8, HARDWARE_ROUNDING_REL, |n| {
                let rays = rays
                    .iter()
                    .map(|r| Ray {
                        near: n.value(r.near),
                        far: if r.far == UNBOUNDED_FAR { r.far } else { n.value(r.far) },
                        ..*r
                    })
                    .collect();
                (rays, weights.iter().map(|&w| n.value(w)).collect())
            });
            bad.extend(
                check_kernel_conditioned(&label, cpu, on_gpu, (&inputs, &moved, SPREAD_FACTOR), tol).into_mismatches(),
            );
        }
    }
    assert_none(&bad);
}

#[test]
fn view_direction_encoding_matches_cpu_reference() {
    use mipnerf_gpu::kernels::view_enc::ViewEncKernel;
    let Some(ctx) = context_or_skip("view_direction_encoding_matches_cpu_reference") else { return };
    let k = ViewEncKernel::new(&ctx).unwrap();
    let rays = test_rays(9);
    let mut bad = Vec::new();
    // The paper's 4 degrees, and 12 (arguments up to 2^11 = 2048, as NeRF's positions reach):
    // the argument reduction holds far from [-pi, pi] without fused multiply-adds, on every vendor.
    for deg in [4u32, 12] {
        let len = rays.len() * mip::pos_enc_len(0, deg, true);
        let cpu = |rays: &[Ray]| -> Outputs {
            let mut out = vec![0.0; len];
            stages::encode_view_directions(rays, deg, &mut out);
            vec![("encoding", out)]
        };
        let on_gpu = |rays: &[Ray]| -> Result<Outputs, GpuError> {
            let dirs: Vec<f32> = rays.iter().flat_map(|r| r.viewdir.to_array()).collect();
            let b_in = ctx.storage_buffer("viewdirs", &dirs, false);
            let b_out = ctx.storage_buffer("view enc", &vec![f32::NAN; len], true);
            let mut rec = Recorder::new(&ctx, "view enc test");
            k.encode(&mut rec, rays.len(), deg, &b_in, &b_out)?;
            let _ = rec.submit();
            Ok(vec![("encoding", ctx.read_f32(&b_out, len)?)])
        };
        let tol = |_: &str| Tolerance::abs(sin_feature_tolerance(&ctx));
        let label = format!("view encoding, {deg} degrees, on {}", ctx.adapter().name);
        bad.extend(check_kernel(&label, cpu, on_gpu, &rays[..], tol).into_mismatches());
    }
    assert_none(&bad);
}
