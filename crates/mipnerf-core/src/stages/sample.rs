//! The coarse level's interval edges (stratified, or within an occupancy grid's spans) and the
//! fine level's (resampled from the coarse weights). Kernels: `sample.wgsl`, `occupancy.wgsl`.

use crate::cone::Ray;
use crate::config::Mode;
use crate::rng::{RayRng, Stream, ray_level_index};
use crate::sampling::{self, PdfSamples, Spacing};

/// How the coarse level's edges are drawn ([`sample_intervals`], [`sample_occupied_intervals`];
/// their kernels, `sample.wgsl`'s `stratified` and `occupancy.wgsl`, take the same settings):
/// intervals a ray, their spacing, and training's jitter or rendering's even edges.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    /// Intervals a ray.
    pub n_samples: usize,
    /// Linear in depth, in disparity, or in the unbounded scene's normalised distance.
    pub spacing: Spacing,
    /// Training (jittered edges) or rendering (even ones).
    pub mode: Mode,
}

/// The interval edges of the coarse level: `n_samples + 1` edges per ray between its `near` and
/// `far`, spaced as `spacing` says ([`sampling::sample_spaced`]), jittered in training by the
/// ray's `SampleJitter` stream (`ray_ids[r]`: the ray's index in the batch, which picks its
/// random numbers). Kernel: `sample.wgsl`, entry point `stratified`.
///
/// # Panics
/// If `t` is not `rays.len() * (n_samples + 1)` long or `ray_ids` is shorter than `rays`.
pub fn sample_intervals(rays: &[Ray], how: Sample, ray_ids: &[u32], t: &mut [f32]) {
    let Sample { n_samples, spacing, mode } = how;
    assert_eq!(t.len(), rays.len() * (n_samples + 1), "sample_intervals: t values");
    assert!(ray_ids.len() >= rays.len(), "sample_intervals: {} ray ids for {} rays", ray_ids.len(), rays.len());
    for ((ray, &id), t) in rays.iter().zip(ray_ids).zip(t.chunks_exact_mut(n_samples + 1)) {
        sampling::sample_spaced(ray.near, ray.far, spacing, jitter(mode, id), t);
    }
}

/// The coarse edges of rays guided by an occupancy grid: ray `r`'s edges spread over its occupied
/// spans `spans[starts[r]..starts[r + 1]]` ([`sampling::sample_along_segments`]), jittered as in
/// [`sample_intervals`]; a ray with no span has every edge at its `near` (it renders the
/// background). In an unbounded scene ([`Spacing::Unbounded`]) the spans are shared out and
/// stratified in the normalised distance `s` and the edges mapped back to `t`, the first and
/// last kept at the spans' ends. Kernel: `occupancy.wgsl`.
///
/// # Panics
/// If `starts` has fewer than `rays.len() + 1` entries, `ray_ids` fewer than `rays.len()`, or `t`
/// is not `rays.len() * (n_samples + 1)` long.
pub fn sample_occupied_intervals(
    rays: &[Ray],
    (starts, spans): (&[u32], &[[f32; 2]]),
    how: Sample,
    ray_ids: &[u32],
    t: &mut [f32],
) {
    let Sample { n_samples, spacing, mode } = how;
    use crate::contract::{ray_distance_to_s, s_to_ray_distance};
    assert_eq!(t.len(), rays.len() * (n_samples + 1), "sample_occupied_intervals: t values");
    assert!(
        ray_ids.len() >= rays.len() && starts.len() > rays.len(),
        "sample_occupied_intervals: {} ray ids and {} span starts for {} rays",
        ray_ids.len(),
        starts.len(),
        rays.len()
    );
    let mut in_s: Vec<[f32; 2]> = Vec::new();
    for (r, ((ray, &id), t)) in rays.iter().zip(ray_ids).zip(t.chunks_exact_mut(n_samples + 1)).enumerate() {
        match &spans[starts[r] as usize..starts[r + 1] as usize] {
            [] => t.fill(ray.near),
            own if spacing == Spacing::Unbounded => {
                in_s.clear();
                in_s.extend(own.iter().map(|&[a, b]| [ray_distance_to_s(a), ray_distance_to_s(b)]));
                sampling::sample_along_segments(&in_s, false, jitter(mode, id), t);
                t.iter_mut().for_each(|v| *v = s_to_ray_distance(*v));
                (t[0], t[n_samples]) = (own[0][0], own[own.len() - 1][1]);
            }
            own => sampling::sample_along_segments(own, spacing == Spacing::Disparity, jitter(mode, id), t),
        }
    }
}

/// The stratified jitter of a ray in training, none in evaluation.
fn jitter(mode: Mode, id: u32) -> Option<RayRng> {
    match mode {
        Mode::Train { seed, step } => Some(RayRng::new(seed, step, Stream::SampleJitter, id)),
        Mode::Eval => None,
    }
}

/// How [`resample_intervals`] draws a level's edges (`sample.wgsl`'s `resample` takes the same
/// settings in its uniform block): intervals a ray, their spacing, the weights' padding, the
/// level (its random stream), and training's jitter or rendering's even offsets.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Resample {
    /// Intervals a ray.
    pub n_samples: usize,
    /// Linear in depth, in disparity, or in the unbounded scene's normalised distance.
    pub spacing: Spacing,
    /// Added to the coarse weights before they are normalised (the official `resample_padding`).
    pub padding: f32,
    /// The level drawn (1 for the fine level), which picks its random stream.
    pub level: usize,
    /// Training (random offsets) or rendering (even ones).
    pub mode: Mode,
}

/// The edges of level `level` (1 or more) drawn from the previous level's: per ray, the inverse
/// CDF of its `weights` (blurred and padded by `padding`, [`sampling::resample_along_rays`]) at
/// stratified random offsets in training (the ray's `ResampleOffsets` stream at this level), at
/// evenly spaced ones in evaluation. With [`Spacing::Unbounded`] the histogram is taken over the
/// edges' normalised distances `s` ([`crate::contract::ray_distance_to_s`]) and the new edges
/// mapped back to `t`, as the successor resamples (in `t` the last interval reaches infinity),
/// the first and last kept at the coarse level's (the ray's whole domain, as
/// [`sampling::sample_spaced`] keeps it).
/// Kernel: `sample.wgsl`, entry point `resample`.
///
/// # Panics
/// If the lengths disagree with `ray_ids.len()` rays of `n_samples` intervals.
pub fn resample_intervals(t_coarse: &[f32], weights: &[f32], how: Resample, ray_ids: &[u32], t_fine: &mut [f32]) {
    let Resample { n_samples, spacing, padding, level, mode } = how;
    use crate::contract::{ray_distance_to_s, s_to_ray_distance};
    let (s, nr) = (n_samples, ray_ids.len());
    assert!(
        t_coarse.len() == nr * (s + 1) && t_fine.len() == nr * (s + 1) && weights.len() == nr * s,
        "resample_intervals: lengths"
    );
    let unbounded = spacing == Spacing::Unbounded;
    let mut s_coarse = vec![0.0f32; if unbounded { s + 1 } else { 0 }];
    for (r, &id) in ray_ids.iter().enumerate() {
        let samples = match mode {
            Mode::Train { seed, step } => PdfSamples::Stratified(RayRng::new(
                seed,
                step,
                Stream::ResampleOffsets,
                ray_level_index(id, level as u32),
            )),
            Mode::Eval => PdfSamples::Deterministic,
        };
        let edges = &t_coarse[r * (s + 1)..(r + 1) * (s + 1)];
        let out = &mut t_fine[r * (s + 1)..(r + 1) * (s + 1)];
        let w = &weights[r * s..(r + 1) * s];
        if unbounded {
            s_coarse.iter_mut().zip(edges).for_each(|(sv, &t)| *sv = ray_distance_to_s(t));
            sampling::resample_along_rays(&s_coarse, w, padding, samples, out);
            out.iter_mut().for_each(|t| *t = s_to_ray_distance(*t));
            (out[0], out[s]) = (edges[0], edges[s]);
        } else {
            sampling::resample_along_rays(edges, w, padding, samples, out);
        }
    }
}
