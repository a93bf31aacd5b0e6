//! Density noise, the activations, volume rendering and its backward pass, and mip-NeRF 360's
//! distortion loss. Kernel: `render.wgsl`.

use crate::cone::Ray;
use crate::config::{Mode, ModelConfig};
use crate::render::{self, RenderedRay};
use crate::rng::{RayRng, Stream, ray_level_index};
use crate::sampling::Spacing;

/// The training noise on a level's raw densities, as [`add_density_noise`] and its kernel
/// (`render.wgsl`) take it: its standard deviation (the model's `density_noise`), the level (its
/// random stream), and the mode (noise in training only).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DensityNoise {
    /// Standard deviation; none at 0.
    pub std: f32,
    /// The level, which picks the stream.
    pub level: usize,
    /// Training (noise) or rendering (none).
    pub mode: Mode,
}

impl DensityNoise {
    /// The model's noise on `level` in a pass of `mode`: its standard deviation at the pass's
    /// step ([`ModelConfig::density_noise_at`]), as both backends add it.
    #[must_use]
    pub fn of(config: &ModelConfig, level: usize, mode: Mode) -> Self {
        Self { std: config.density_noise_at(mode), level, mode }
    }

    /// Whether any noise is added: in training, with a positive standard deviation.
    #[must_use]
    pub fn is_on(self) -> bool {
        matches!(self.mode, Mode::Train { .. }) && self.std > 0.0
    }
}

/// Training only: Gaussian noise of standard deviation `std` on each ray's `n_samples` raw
/// densities, from the ray's `DensityNoise` stream at `level`. Nothing in evaluation or for
/// `std <= 0`. Kernel: `render.wgsl` (before the activations).
///
/// # Panics
/// If `raw_density` is not `ray_ids.len() * n_samples` long.
pub fn add_density_noise(noise: DensityNoise, ray_ids: &[u32], n_samples: usize, raw_density: &mut [f32]) {
    let DensityNoise { std, level, mode } = noise;
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

/// The MLP's raw outputs of a level: three colour values and a density a sample, before their
/// activations.
#[derive(Clone, Copy, Debug)]
pub struct RawOutputs<'a> {
    /// `3 n` raw colour values.
    pub rgb: &'a [f32],
    /// `n` raw densities.
    pub density: &'a [f32],
}

/// The gradients of the loss with respect to a level's raw outputs, as [`RawOutputs`] holds them.
#[derive(Debug)]
pub struct RawGradients<'a> {
    /// `3 n` values.
    pub rgb: &'a mut [f32],
    /// `n` values.
    pub density: &'a mut [f32],
}

/// The rays a level renders: each ray's interval edges (`n_samples + 1`), the rays, and each
/// ray's background colour.
#[derive(Clone, Copy, Debug)]
pub struct LevelRays<'a> {
    /// The interval edges, ray after ray.
    pub t: &'a [f32],
    /// The rays.
    pub rays: &'a [Ray],
    /// A background a ray.
    pub backgrounds: &'a [[f32; 3]],
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
    raw: RawOutputs<'_>,
    level: LevelRays<'_>,
    samples: &mut RenderedSamples,
    out: &mut [RenderedRay],
) {
    let (RawOutputs { rgb: raw_rgb, density: raw_density }, LevelRays { t, rays, backgrounds }) = (raw, level);
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
    raw: RawOutputs<'_>,
    level: LevelRays<'_>,
    samples: &RenderedSamples,
    d_ray_rgb: &[[f32; 3]],
    d_raw: RawGradients<'_>,
) {
    let (RawOutputs { rgb: raw_rgb, density: raw_density }, LevelRays { t, rays, backgrounds }) = (raw, level);
    let RawGradients { rgb: d_raw_rgb, density: d_raw_density } = d_raw;
    let s = cfg.num_samples;
    let n = rays.len() * s;
    assert!(
        d_raw_rgb.len() == 3 * n && d_raw_density.len() == n && d_ray_rgb.len() >= rays.len(),
        "render_rays_backward: lengths"
    );
    let (mut g_rgb, mut g_density) = (vec![[0.0f32; 3]; s], vec![0.0f32; s]);
    for (r, ray) in rays.iter().enumerate() {
        let sl = r * s..(r + 1) * s;
        let composite = render::RayComposite {
            rgb: &samples.rgb[sl.clone()],
            density: &samples.density[sl.clone()],
            t_vals: &t[r * (s + 1)..(r + 1) * (s + 1)],
            dir: ray.direction,
            bg: backgrounds[r],
        };
        let upstream = render::Upstream { d_rgb: d_ray_rgb[r], d_acc: 0.0 };
        render::volumetric_rendering_backward(
            composite,
            &samples.weights[sl.clone()],
            upstream,
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
