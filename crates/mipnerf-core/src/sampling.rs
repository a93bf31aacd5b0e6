//! Sampling interval edges along rays: stratified (coarse level) and inverse-CDF (fine level).
//!
//! `t` values are distances in units of the ray's (unnormalised) direction. `n` samples use `n + 1`
//! edges ("fence posts"); sample `i` is the frustum between edges `i` and `i + 1`.

use crate::rng::RayRng;

/// `f32::EPSILON` (`2^-23`), the `jnp.finfo('float32').eps` of the official code.
pub const F32_EPS: f32 = f32::EPSILON;

/// The official `resample_padding`: a constant added to the blurred coarse weights so that the fine
/// level always spends some samples everywhere between near and far.
pub const RESAMPLE_PADDING: f32 = 0.01;

/// Weight vectors are padded so that their sum is at least this (avoids NaN for empty rays).
pub const PDF_WEIGHT_EPS: f32 = 1e-5;

/// Fills `t_vals` (`num_samples + 1` edges) between `near` and `far` for the coarse level.
///
/// Without `jitter` the edges are `linspace(0, 1)` mapped linearly (or linearly in disparity with
/// `lindisp`: `1 / ((1-s)/near + s/far)`). With `jitter` (training) each edge is drawn uniformly
/// between the midpoints to its neighbours (the first and last edge between near/far and their
/// midpoint), using numbers `0..=num_samples` of the ray's stream.
///
/// # Panics
/// If `t_vals.len() < 2`.
pub fn sample_along_rays(near: f32, far: f32, lindisp: bool, jitter: Option<RayRng>, t_vals: &mut [f32]) {
    assert!(t_vals.len() >= 2, "sample_along_rays: need at least two edges");
    debug_assert!(near.is_finite() && far.is_finite(), "sample_along_rays: near {near} far {far}");
    let n = (t_vals.len() - 1) as f32;
    for (i, t) in t_vals.iter_mut().enumerate() {
        let s = i as f32 / n;
        *t = if lindisp { 1.0 / (1.0 / near * (1.0 - s) + 1.0 / far * s) } else { near * (1.0 - s) + far * s };
    }
    if let Some(rng) = jitter {
        // Each new edge depends on the old neighbours, so carry the previous old value.
        let last = t_vals.len() - 1;
        let mut prev_old = t_vals[0];
        for i in 0..=last {
            let cur = t_vals[i];
            let lower = if i == 0 { cur } else { 0.5 * (cur + prev_old) };
            let upper = if i == last { cur } else { 0.5 * (t_vals[i + 1] + cur) };
            prev_old = cur;
            t_vals[i] = lower + (upper - lower) * rng.uniform(i as u32);
        }
    }
}

/// How the coarse level spaces a ray's edges between its near and far bounds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Spacing {
    /// Linearly in depth (`t`), the paper's.
    #[default]
    Depth,
    /// Linearly in disparity (`1/t`), the official `lindisp`.
    Disparity,
    /// Unbounded scenes: linearly in the normalised distance `s` of [`crate::contract`] (linear
    /// in `t` up to 1, in disparity beyond, out to infinity); the fine level resamples in `s` too.
    Unbounded,
}

impl Spacing {
    /// The kernels' code for it (`sample.wgsl`'s `spacing`): 0, 1, 2.
    #[must_use]
    pub fn code(self) -> u32 {
        match self {
            Self::Depth => 0,
            Self::Disparity => 1,
            Self::Unbounded => 2,
        }
    }
}

/// Fills `t_vals` (`num_samples + 1` edges) between `near` and `far` as `spacing` says:
/// [`sample_along_rays`] for depth and disparity; for unbounded scenes, the same stratification
/// between `s(near)` and `s(far)` ([`crate::contract::ray_distance_to_s`]), each edge mapped back
/// to `t`, except the first and the last, which stay at `near` and `far` (the successor's
/// intervals always span the ray's whole domain; jittered, the last edge would stop short of
/// infinity, as far in as `t ≈ n` on some steps, and drop the background beyond it).
///
/// # Panics
/// If `t_vals.len() < 2`.
pub fn sample_spaced(near: f32, far: f32, spacing: Spacing, jitter: Option<RayRng>, t_vals: &mut [f32]) {
    use crate::contract::{ray_distance_to_s, s_to_ray_distance};
    match spacing {
        Spacing::Depth | Spacing::Disparity => {
            sample_along_rays(near, far, spacing == Spacing::Disparity, jitter, t_vals);
        }
        Spacing::Unbounded => {
            sample_along_rays(ray_distance_to_s(near), ray_distance_to_s(far), false, jitter, t_vals);
            let last = t_vals.len() - 1;
            for (i, t) in t_vals.iter_mut().enumerate() {
                *t = match i {
                    0 => near,
                    i if i == last => far,
                    _ => s_to_ray_distance(*t),
                };
            }
        }
    }
}

/// Fills `t_vals` for the coarse level of a ray cut to the occupied `spans` (sorted, disjoint
/// `[t0, t1]`, at least one), with an edge at each end of every span, so that no interval
/// straddles an empty gap: each gap between two spans is one interval of its own (its sample
/// is run like any other, so the model learns it empty, or fills it and the grid follows), and
/// the others are shared out among the spans by length ([`span_intervals`]), at least one each,
/// stratified inside each span: evenly spaced, each inner edge jittered in training between the
/// midpoints to its neighbours (edge `i` of the ray uses number `i` of its stream), the span's
/// ends fixed. When the spans need more intervals than there are (`2 spans - 1 > n`), the spans
/// with the narrowest gaps between them are joined first (the gap then lies inside a span).
///
/// With one span `[near, far]` this is exactly [`sample_along_rays`]`(near, far, ...)`, bit for
/// bit. `lindisp` applies only then (several spans are spaced linearly in depth).
///
/// # Panics
/// If `spans` is empty or `t_vals.len() < 2`.
pub fn sample_along_segments(spans: &[[f32; 2]], lindisp: bool, jitter: Option<RayRng>, t_vals: &mut [f32]) {
    assert!(!spans.is_empty(), "sample_along_segments: no span");
    assert!(t_vals.len() >= 2, "sample_along_segments: need at least two edges");
    if let [[near, far]] = *spans {
        sample_along_rays(near, far, lindisp, jitter, t_vals);
        return;
    }
    let n = t_vals.len() - 1;
    let mut spans = spans.to_vec();
    join_narrowest_gaps(&mut spans, n);
    if let [[near, far]] = *spans {
        sample_along_rays(near, far, false, jitter, t_vals);
        return;
    }
    let mut e = 0; // the ray's edge index where the current span starts
    for (k, &[t0, t1]) in spans.iter().enumerate() {
        let m = span_intervals(&spans, n, k);
        for j in 0..=m {
            let edge = |j: usize| {
                let s = j as f32 / m as f32;
                t0 * (1.0 - s) + t1 * s
            };
            let base = edge(j);
            t_vals[e + j] = match jitter {
                Some(rng) if j > 0 && j < m => {
                    let lower = 0.5 * (edge(j - 1) + base);
                    let upper = 0.5 * (edge(j + 1) + base);
                    lower + (upper - lower) * rng.uniform((e + j) as u32)
                }
                _ => base,
            };
        }
        e += m + 1;
    }
    debug_assert_eq!(e, n + 1);
}

/// Joins the spans with the narrowest gap between them (the first on a tie) until every span
/// can have an interval and every gap one: `2 spans - 1 <= n`.
pub fn join_narrowest_gaps(spans: &mut Vec<[f32; 2]>, n: usize) {
    while spans.len() > 1 && 2 * spans.len() - 1 > n {
        let mut k = 0;
        for i in 1..spans.len() - 1 {
            if spans[i + 1][0] - spans[i][1] < spans[k + 1][0] - spans[k][1] {
                k = i;
            }
        }
        spans[k][1] = spans[k + 1][1];
        spans.remove(k + 1);
    }
}

/// The intervals span `k` of `spans` gets out of a ray's `n` (after
/// [`join_narrowest_gaps`]): one, plus its share by length of the `n - (2 spans - 1)` spare ones,
/// by cumulative rounding (`floor(spare · cumulative length / total + 1/2)`, the last span's
/// cumulative share exactly `spare`), so the shares add up to `n - (spans - 1)`.
#[must_use]
pub fn span_intervals(spans: &[[f32; 2]], n: usize, k: usize) -> usize {
    let s = spans.len();
    let spare = n - (2 * s - 1);
    let total: f32 = spans.iter().map(|v| v[1] - v[0]).sum();
    let share = |k: usize| -> usize {
        if k + 1 == s {
            return spare;
        }
        let cum: f32 = spans[..=k].iter().map(|v| v[1] - v[0]).sum();
        ((spare as f32 * (cum / total) + 0.5).floor() as usize).min(spare)
    };
    1 + share(k) - if k == 0 { 0 } else { share(k - 1) }
}

/// Where the inverse-CDF samples come from.
#[derive(Clone, Copy, Debug)]
pub enum PdfSamples {
    /// Evaluation: `u = linspace(0, 1 - eps, n)`.
    Deterministic,
    /// Training: `u_i = i/n + U[0, 1/n - eps)`, clamped below `1 - eps`, from this stream.
    Stratified(RayRng),
}

/// Draws `out.len()` sorted samples from the piecewise-constant pdf with edges `bins`
/// (`weights.len() + 1` of them, sorted) and unnormalised non-negative `weights`, by inverting
/// its CDF, exactly as the official `sorted_piecewise_constant_pdf`.
///
/// Weights are padded (spread evenly) so that they sum to at least [`PDF_WEIGHT_EPS`]; an all-zero
/// weight vector therefore samples the bins uniformly.
///
/// # Panics
/// If `bins.len() != weights.len() + 1` or `weights` is empty.
pub fn sorted_piecewise_constant_pdf(bins: &[f32], weights: &[f32], samples: PdfSamples, out: &mut [f32]) {
    let nw = weights.len();
    assert!(nw > 0 && bins.len() == nw + 1, "sorted_piecewise_constant_pdf: shapes");
    // Pad weights so their sum is at least eps.
    let weight_sum: f32 = weights.iter().sum();
    let padding = (PDF_WEIGHT_EPS - weight_sum).max(0.0);
    let per_weight = padding / nw as f32;
    let weight_sum = weight_sum + padding;
    // CDF with exactly 0 first and exactly 1 last: nw + 1 entries, like `bins`.
    let mut cdf = [0.0f32; MAX_EDGES];
    let mut cdf_vec;
    let cdf: &mut [f32] = if nw < MAX_EDGES {
        &mut cdf[..=nw]
    } else {
        cdf_vec = vec![0.0f32; nw + 1];
        &mut cdf_vec
    };
    let mut acc = 0.0f32;
    for i in 0..nw - 1 {
        acc += (weights[i] + per_weight) / weight_sum;
        cdf[i + 1] = acc.min(1.0);
    }
    cdf[nw] = 1.0;

    let n = out.len();
    for (i, o) in out.iter_mut().enumerate() {
        let u = match samples {
            PdfSamples::Deterministic => linspace_value(0.0, 1.0 - F32_EPS, n, i),
            PdfSamples::Stratified(rng) => {
                let s = 1.0 / n as f32;
                let u = i as f32 * s + rng.uniform(i as u32) * (s - F32_EPS);
                u.min(1.0 - F32_EPS)
            }
        };
        // The last edge whose cdf is <= u starts the interval; the first one above u ends it.
        let k = cdf.partition_point(|&c| c <= u); // number of cdf entries <= u (>= 1 as cdf[0] = 0 <= u)
        let (b0, c0) = if k == 0 { (bins[0], cdf[0]) } else { (bins[k - 1], cdf[k - 1]) };
        let (b1, c1) = if k > nw { (bins[nw], cdf[nw]) } else { (bins[k], cdf[k]) };
        let t = (u - c0) / (c1 - c0);
        let t = if t.is_nan() { 0.0 } else { t }.clamp(0.0, 1.0);
        *o = b0 + t * (b1 - b0);
    }
    // Sorted by construction (u increases, the CDF is monotone); make it a guarantee.
    for i in 1..n {
        if out[i] < out[i - 1] {
            out[i] = out[i - 1];
        }
    }
}

/// Rays with more edges than this use a heap buffer for their CDF.
const MAX_EDGES: usize = 513;

/// `jnp.linspace(start, stop, n)[i]`: `start * (1 - s) + stop * s` with `s = i / (n - 1)`, the last
/// value exactly `stop`, and `[start]` when `n == 1`.
#[must_use]
#[inline]
pub fn linspace_value(start: f32, stop: f32, n: usize, i: usize) -> f32 {
    if n <= 1 {
        return start;
    }
    if i == n - 1 {
        return stop;
    }
    let s = i as f32 / (n - 1) as f32;
    start * (1.0 - s) + stop * s
}

/// The fine level's interval edges from the coarse level's `t_vals` and `weights`, written to
/// `out` (the same length as `t_vals`).
///
/// The coarse weights are padded at both ends, max-pooled over 2 taps, averaged over 2 taps
/// ("blurred"), raised by `resample_padding`, and inverted by [`sorted_piecewise_constant_pdf`].
/// The new edges are sorted, lie in `[t_vals[0], t_vals[last]]`, and carry no gradient
/// (the official `stop_grad`).
///
/// # Panics
/// If `weights.len() + 1 != t_vals.len()` or `out.len() != t_vals.len()`.
pub fn resample_along_rays(
    t_vals: &[f32],
    weights: &[f32],
    resample_padding: f32,
    samples: PdfSamples,
    out: &mut [f32],
) {
    let n = weights.len();
    assert!(n > 0 && t_vals.len() == n + 1 && out.len() == n + 1, "resample_along_rays: shapes");
    let mut buf = [0.0f32; MAX_EDGES];
    let mut heap;
    let blurred: &mut [f32] = if n <= MAX_EDGES {
        &mut buf[..n]
    } else {
        heap = vec![0.0f32; n];
        &mut heap
    };
    // weights_pad = [w0, w0..w_{n-1}, w_{n-1}]; max over pairs gives n + 1 values; blur gives n.
    let padded = |i: usize| weights[i.saturating_sub(1).min(n - 1)];
    let maxed = |j: usize| padded(j).max(padded(j + 1));
    for (i, b) in blurred.iter_mut().enumerate() {
        *b = 0.5 * (maxed(i) + maxed(i + 1)) + resample_padding;
    }
    sorted_piecewise_constant_pdf(t_vals, blurred, samples, out);
}
