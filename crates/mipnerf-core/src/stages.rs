//! The paper's stages over a batch of rays: one public function per WGSL kernel, on flat arrays
//! laid out as the kernel's buffers are. [`crate::model::Model`] composes them (its chunk loop is
//! these calls in order), and each GPU kernel's test compares the kernel with its function here
//! through [`crate::compare::check_kernel`]. The one lookup path:
//!
//! | paper stage | CPU reference (here) | WGSL kernel (`shaders/`) and its Rust wrapper (`mipnerf-gpu/src/kernels/`) |
//! |---|---|---|
//! | stratified sampling along the ray | [`sample_intervals`], [`sample_occupied_intervals`] | `sample.wgsl` `stratified`, `occupancy.wgsl` (`sample.rs`, `occupancy.rs`) |
//! | hierarchical resampling | [`resample_intervals`] | `sample.wgsl` `resample` (`sample.rs`) |
//! | cast cones, conical frustum to Gaussian, IPE | [`cast_and_encode`] | `cast_ipe.wgsl` (`cast_ipe.rs`) |
//! | view-direction encoding | [`encode_view_directions`] | `view_enc.wgsl` (`view_enc.rs`) |
//! | the MLP's layers, forward and backward | [`crate::mlp::MlpShape::forward`], [`crate::mlp::MlpShape::backward`] | `matmul.wgsl`, `mlp_aux.wgsl` (`matmul.rs`, `mlp_aux.rs`) |
//! | density noise, activations, volume rendering, area loss and their backward pass | [`add_density_noise`], [`render_rays`], [`render_rays_backward`], [`crate::model::pixel_loss_gradient`] | `render.wgsl` (`render.rs`) |
//! | gradient clipping and Adam | [`adam_step`] | `adam.wgsl` (`adam.rs`) |
//!
//! Every function writes its outputs in place (allocating at most a per-call scratch the size of
//! one ray's samples) and runs in `f32`, in the order the paper's equations are written.

use glam::Vec3;

use crate::bf16::Precision;
use crate::cone::{Ray, RayShape, cast_ray, cast_ray_contracted};
use crate::config::{Mode, ModelConfig, PointEncoding};
use crate::mip::{self, Gaussian};
use crate::optim::{AdamConfig, AdamState, clip_gradients};
use crate::render::{self, RenderedRay};
use crate::rng::{RayRng, Stream, ray_level_index};
use crate::sampling::{self, PdfSamples, Spacing};
use crate::wide::wide;

/// The interval edges of the coarse level: `n_samples + 1` edges per ray between its `near` and
/// `far`, spaced as `spacing` says ([`sampling::sample_spaced`]), jittered in training by the
/// ray's `SampleJitter` stream (`ray_ids[r]`: the ray's index in the batch, which picks its
/// random numbers). Kernel: `sample.wgsl`, entry point `stratified`.
///
/// # Panics
/// If `t` is not `rays.len() * (n_samples + 1)` long or `ray_ids` is shorter than `rays`.
pub fn sample_intervals(rays: &[Ray], n_samples: usize, spacing: Spacing, mode: Mode, ray_ids: &[u32], t: &mut [f32]) {
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
    n_samples: usize,
    spacing: Spacing,
    mode: Mode,
    ray_ids: &[u32],
    t: &mut [f32],
) {
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
pub fn resample_intervals(
    t_coarse: &[f32],
    weights: &[f32],
    (n_samples, spacing): (usize, Spacing),
    padding: f32,
    level: usize,
    mode: Mode,
    ray_ids: &[u32],
    t_fine: &mut [f32],
) {
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

/// One Gaussian's features under a point encoding, into `dst`: the integrated positional
/// encoding (Mip-NeRF), the same with zero covariance (the "w/o IPE" ablation), or NeRF's
/// encoding of the mean with the identity.
#[inline(always)]
pub fn encode_gaussian(g: &Gaussian, encoding: PointEncoding, min_deg: u32, max_deg: u32, dst: &mut [f32]) {
    match encoding {
        PointEncoding::Integrated => mip::integrated_pos_enc(g, min_deg, max_deg, dst),
        PointEncoding::Mean => {
            let g0 = Gaussian { mean: g.mean, cov_diag: Vec3::ZERO };
            mip::integrated_pos_enc(&g0, min_deg, max_deg, dst);
        }
        PointEncoding::Nerf => mip::pos_enc(g.mean, min_deg, max_deg, true, dst),
    }
}

/// Casts each ray's intervals (`t`: `n_samples + 1` edges per ray) as conical frustums (or
/// cylinders), each a Gaussian ([`cast_ray`]; in an unbounded scene carried through the scene
/// contraction, [`cast_ray_contracted`]), and encodes them ([`encode_gaussian`]) into `x`:
/// `rays.len() * n_samples` rows of the encoding's width, sample after sample. Kernel:
/// `cast_ipe.wgsl`.
///
/// `precision` is that of the products the features feed: at [`Precision::Bf16`], which rounds
/// them to bf16 first, the IPE is evaluated in `f32` arithmetic
/// ([`mip::integrated_pos_enc_for_bf16`], within [`mip::IPE_FOR_BF16_MAX_ERROR`]); at
/// [`Precision::F32`] it is the reference, bit for bit. The encoding loop runs through
/// [`wide`]: 512-bit vectors on CPUs with AVX-512, the same bits.
///
/// # Panics
/// If `t` or `x` has the wrong length for `rays.len()` rays.
pub fn cast_and_encode(
    rays: &[Ray],
    t: &[f32],
    (n_samples, unbounded): (usize, bool),
    shape: RayShape,
    (encoding, precision): (PointEncoding, Precision),
    (min_deg, max_deg): (u32, u32),
    x: &mut [f32],
) {
    assert_eq!(t.len(), rays.len() * (n_samples + 1), "cast_and_encode: t values");
    let width = encoding.width(min_deg, max_deg);
    assert_eq!(x.len(), rays.len() * n_samples * width, "cast_and_encode: features");
    let mut gauss = vec![Gaussian::default(); n_samples];
    let cast = if unbounded { cast_ray_contracted } else { cast_ray };
    let encoding = GaussianEncoding { encoding, precision, degrees: (min_deg, max_deg) };
    for (r, ray) in rays.iter().enumerate() {
        cast(
            &t[r * (n_samples + 1)..(r + 1) * (n_samples + 1)],
            ray.origin,
            ray.direction,
            ray.radius,
            shape,
            &mut gauss,
        );
        encoding.encode(&gauss, &mut x[r * n_samples * width..(r + 1) * n_samples * width]);
    }
}

/// How [`cast_and_encode`] encodes a ray's Gaussians: the point encoding, its degrees, and the
/// precision of the products the features feed.
#[derive(Clone, Copy)]
struct GaussianEncoding {
    encoding: PointEncoding,
    precision: Precision,
    degrees: (u32, u32),
}

impl GaussianEncoding {
    /// Encodes `gauss` into `x`, one row each, through [`wide`]'s 512-bit vectors where the CPU
    /// has them.
    fn encode(self, gauss: &[Gaussian], x: &mut [f32]) {
        wide(
            #[inline(always)]
            || self.encode_rows(gauss, x),
        );
    }

    #[inline(always)]
    fn encode_rows(self, gauss: &[Gaussian], x: &mut [f32]) {
        let (min_deg, max_deg) = self.degrees;
        let width = x.len() / gauss.len().max(1);
        for (g, row) in gauss.iter().zip(x.chunks_exact_mut(width.max(1))) {
            match (self.encoding, self.precision) {
                (PointEncoding::Integrated, Precision::Bf16) => {
                    mip::integrated_pos_enc_for_bf16(g, min_deg, max_deg, row)
                }
                (PointEncoding::Mean, Precision::Bf16) => {
                    let g0 = Gaussian { mean: g.mean, cov_diag: Vec3::ZERO };
                    mip::integrated_pos_enc_for_bf16(&g0, min_deg, max_deg, row);
                }
                _ => encode_gaussian(g, self.encoding, min_deg, max_deg, row),
            }
        }
    }
}

/// The positional encoding of each ray's unit view direction (degrees `0..deg_view`, with the
/// identity: `3 + 6 deg_view` values per ray), the colour branch's input. Kernel:
/// `view_enc.wgsl`.
///
/// # Panics
/// If `out` is not `rays.len() * (3 + 6 deg_view)` long.
pub fn encode_view_directions(rays: &[Ray], deg_view: u32, out: &mut [f32]) {
    let width = mip::pos_enc_len(0, deg_view, true);
    assert_eq!(out.len(), rays.len() * width, "encode_view_directions: output");
    for (ray, dst) in rays.iter().zip(out.chunks_exact_mut(width)) {
        mip::pos_enc(ray.viewdir, 0, deg_view, true, dst);
    }
}

/// Training only: Gaussian noise of standard deviation `std` on each ray's `n_samples` raw
/// densities, from the ray's `DensityNoise` stream at `level`. Nothing in evaluation or for
/// `std <= 0`. Kernel: `render.wgsl` (before the activations).
///
/// # Panics
/// If `raw_density` is not `ray_ids.len() * n_samples` long.
pub fn add_density_noise(
    std: f32,
    level: usize,
    mode: Mode,
    ray_ids: &[u32],
    n_samples: usize,
    raw_density: &mut [f32],
) {
    assert_eq!(raw_density.len(), ray_ids.len() * n_samples, "add_density_noise: raw densities");
    let (Mode::Train { seed, step }, true) = (mode, std > 0.0) else {
        return;
    };
    for (&id, raw) in ray_ids.iter().zip(raw_density.chunks_exact_mut(n_samples)) {
        let rng = RayRng::new(seed, step, Stream::DensityNoise, ray_level_index(id, level as u32));
        for (i, d) in raw.iter_mut().enumerate() {
            *d += std * rng.normal(i as u32);
        }
    }
}

/// The activated samples and their rendering weights, what [`render_rays`] writes and
/// [`render_rays_backward`] reads.
#[derive(Clone, Debug, Default)]
pub struct RenderedSamples {
    /// Colour per sample, after the sigmoid with padding.
    pub rgb: Vec<[f32; 3]>,
    /// Density per sample, after softplus or ReLU with the bias.
    pub density: Vec<f32>,
    /// Volume-rendering weight per sample (the next level resamples from these).
    pub weights: Vec<f32>,
}

impl RenderedSamples {
    /// Sized for `n` samples (contents unspecified until [`render_rays`] writes them).
    pub fn resize(&mut self, n: usize) {
        self.rgb.resize(n, [0.0; 3]);
        self.density.resize(n, 0.0);
        self.weights.resize(n, 0.0);
    }
}

/// The MLP's raw outputs activated (density: softplus or ReLU with `density_bias`; colour:
/// sigmoid with `rgb_padding`) and composited along each ray ([`render::volumetric_rendering`]
/// on `backgrounds[r]`): writes `samples` and each ray's colour, distance and opacity to `out`.
/// Kernel: `render.wgsl`, forward.
///
/// # Panics
/// If the lengths disagree with `rays.len()` rays of `cfg.num_samples` samples.
pub fn render_rays(
    cfg: &ModelConfig,
    raw_rgb: &[f32],
    raw_density: &[f32],
    t: &[f32],
    rays: &[Ray],
    backgrounds: &[[f32; 3]],
    samples: &mut RenderedSamples,
    out: &mut [RenderedRay],
) {
    let s = cfg.num_samples;
    let n = rays.len() * s;
    assert!(
        raw_rgb.len() == 3 * n
            && raw_density.len() == n
            && t.len() == rays.len() * (s + 1)
            && backgrounds.len() >= rays.len()
            && out.len() >= rays.len(),
        "render_rays: lengths"
    );
    samples.resize(n);
    for i in 0..n {
        samples.density[i] = cfg.density_activation.forward(raw_density[i], cfg.density_bias);
        for k in 0..3 {
            samples.rgb[i][k] = render::rgb_activation(raw_rgb[i * 3 + k], cfg.rgb_padding);
        }
    }
    for (r, ray) in rays.iter().enumerate() {
        let sl = r * s..(r + 1) * s;
        out[r] = render::volumetric_rendering(
            &samples.rgb[sl.clone()],
            &samples.density[sl.clone()],
            &t[r * (s + 1)..(r + 1) * (s + 1)],
            ray.direction,
            backgrounds[r],
            &mut samples.weights[sl],
        );
    }
}

/// The backward pass of [`render_rays`]: given each ray's loss gradient with respect to its
/// rendered colour (`d_ray_rgb`, from [`crate::model::pixel_loss_gradient`]: the area loss),
/// writes the gradients with respect to the raw outputs, `d_raw_rgb` (3 per sample) and
/// `d_raw_density`, through compositing ([`render::volumetric_rendering_backward`]) and the
/// activations. Kernel: `render.wgsl`, backward.
///
/// # Panics
/// If the lengths disagree with `rays.len()` rays of `cfg.num_samples` samples.
pub fn render_rays_backward(
    cfg: &ModelConfig,
    (raw_rgb, raw_density): (&[f32], &[f32]),
    t: &[f32],
    rays: &[Ray],
    backgrounds: &[[f32; 3]],
    samples: &RenderedSamples,
    d_ray_rgb: &[[f32; 3]],
    (d_raw_rgb, d_raw_density): (&mut [f32], &mut [f32]),
) {
    let s = cfg.num_samples;
    let n = rays.len() * s;
    assert!(
        d_raw_rgb.len() == 3 * n && d_raw_density.len() == n && d_ray_rgb.len() >= rays.len(),
        "render_rays_backward: lengths"
    );
    let (mut g_rgb, mut g_density) = (vec![[0.0f32; 3]; s], vec![0.0f32; s]);
    for (r, ray) in rays.iter().enumerate() {
        let sl = r * s..(r + 1) * s;
        render::volumetric_rendering_backward(
            &samples.rgb[sl.clone()],
            &samples.density[sl.clone()],
            &t[r * (s + 1)..(r + 1) * (s + 1)],
            ray.direction,
            backgrounds[r],
            &samples.weights[sl.clone()],
            d_ray_rgb[r],
            0.0,
            &mut g_rgb,
            &mut g_density,
        );
        for (j, i) in sl.enumerate() {
            d_raw_density[i] = g_density[j] * cfg.density_activation.derivative(raw_density[i], cfg.density_bias);
            for k in 0..3 {
                d_raw_rgb[i * 3 + k] =
                    g_rgb[j][k] * render::rgb_activation_derivative(raw_rgb[i * 3 + k], cfg.rgb_padding);
            }
        }
    }
}

/// A ray distance `t` (between the ray's `near` and `far`) as the normalised distance in
/// `[0, 1]` that `spacing` spaces edges evenly in, mip-NeRF 360's `s`: `(t - near) / (far -
/// near)` for depth, the same in inverse depth for disparity, and the contraction's spacing
/// ([`crate::contract::ray_distance_to_s`], `t/2` up to 1 and `1 - 1/(2t)` beyond) for an
/// unbounded scene.
#[must_use]
pub fn normalised_distance(t: f32, near: f32, far: f32, spacing: Spacing) -> f32 {
    match spacing {
        Spacing::Depth => (t - near) / (far - near),
        Spacing::Disparity => (1.0 / t - 1.0 / near) / (1.0 / far - 1.0 / near),
        Spacing::Unbounded => crate::contract::ray_distance_to_s(t),
    }
}

/// mip-NeRF 360's distortion loss of one ray (its Eq. 15) on its intervals' edges `s` in
/// normalised distance ([`normalised_distance`], `n + 1`, ascending) and their weights `w`
/// (`n`): `sum_ij w_i w_j |m_i - m_j| + 1/3 sum_i w_i² (s_{i+1} - s_i)`, `m_i` the intervals'
/// middles. It is least when the weight gathers in one short stretch: a surface, not a fog of
/// floaters along the ray. Computed in `O(n)` (the double sum from prefix sums of `w` and
/// `w m`, as the successor's code does), and its gradient with respect to each weight times
/// `scale` added to `d_w`: `2 sum_j w_j |m_k - m_j| + 2/3 w_k (s_{k+1} - s_k)`. Returns the loss.
///
/// # Panics
/// If the lengths disagree.
pub fn distortion_loss(s: &[f32], w: &[f32], scale: f32, d_w: &mut [f32]) -> f32 {
    let n = w.len();
    assert!(s.len() == n + 1 && d_w.len() == n, "distortion_loss: shapes");
    let mid = |i: usize| 0.5 * (s[i] + s[i + 1]);
    let (w_total, wm_total) = (0..n).fold((0.0f32, 0.0f32), |(a, b), i| (a + w[i], b + w[i] * mid(i)));
    let (mut w_before, mut wm_before, mut loss) = (0.0f32, 0.0f32, 0.0f32);
    for i in 0..n {
        let (m, width) = (mid(i), s[i + 1] - s[i]);
        let (w_after, wm_after) = (w_total - w_before - w[i], wm_total - wm_before - w[i] * m);
        // sum_j w_j |m_i - m_j|: the weight before the middle pulls back, the weight after forward.
        let spread = (m * w_before - wm_before) + (wm_after - m * w_after);
        loss += w[i] * spread + w[i] * w[i] * width / 3.0;
        d_w[i] += scale * (2.0 * spread + 2.0 / 3.0 * w[i] * width);
        w_before += w[i];
        wm_before += w[i] * m;
    }
    loss
}

/// One optimiser step: the gradient clipped by value then by norm ([`clip_gradients`], as the
/// official `train_step`), then the bias-corrected Adam update ([`AdamState::update`]) at
/// learning rate `lr`. Returns the gradient norm after value clipping, the quantity the official
/// code logs. Kernel: `adam.wgsl`.
///
/// # Panics
/// If the lengths differ.
pub fn adam_step(
    cfg: &AdamConfig,
    lr: f32,
    (max_val, max_norm): (f32, f32),
    state: &mut AdamState,
    params: &mut [f32],
    grads: &mut [f32],
) -> f32 {
    let norm = clip_gradients(grads, max_val, max_norm);
    state.update(cfg, lr, params, grads);
    norm
}
