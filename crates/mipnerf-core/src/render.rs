//! Volume rendering along one ray (the paper's Eq. 1 with per-interval densities), its analytic
//! backward pass, and the network's output activations with theirs.

use glam::Vec3;

/// `x` limited to `[lo, hi]`, as `f32::clamp` for ordered bounds, without its panic when the
/// bounds are NaN or reversed (values at the edge of `f32`'s range): then `x` passes through
/// whichever test it fails first.
#[must_use]
pub(crate) fn clamp_to(x: f32, lo: f32, hi: f32) -> f32 {
    if x < lo {
        lo
    } else if x > hi {
        hi
    } else {
        x
    }
}

/// What [`volumetric_rendering`] returns for one ray.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct RenderedRay {
    /// Composited colour (linear, usually in `[0, 1]`), with the background added if requested.
    pub rgb: [f32; 3],
    /// Expected depth `sum(w t_mid) / acc`, clipped to `[t_first, t_last]`. A ray with no
    /// opacity reports `t_first` (the official code's `nan_to_num` quirk).
    pub distance: f32,
    /// Accumulated opacity `sum(w)`, clamped to `[0, 1]` (rounding can otherwise exceed 1 by an ulp).
    pub acc: f32,
}

/// Renders one ray from per-interval colours `rgb` and densities `density` (`n` each) on the
/// interval edges `t_vals` (`n + 1`), writing the per-interval weights to `weights`.
///
/// `delta_i = (t_{i+1} - t_i) |dir|`, `alpha_i = 1 - exp(-density_i delta_i)`,
/// `T_i = exp(-sum_{j<i} density_j delta_j)`, `w_i = alpha_i T_i`. The colour is composited on
/// the background colour `bg`: `rgb + (1 - acc) bg` (the official `white_bkgd` is
/// `bg = [1, 1, 1]`, see [`background`]; Blender scenes are composited on white).
///
/// # Panics
/// If the lengths disagree.
pub fn volumetric_rendering(
    rgb: &[[f32; 3]],
    density: &[f32],
    t_vals: &[f32],
    dir: Vec3,
    bg: [f32; 3],
    weights: &mut [f32],
) -> RenderedRay {
    let n = density.len();
    assert!(rgb.len() == n && t_vals.len() == n + 1 && weights.len() == n, "volumetric_rendering: shapes");
    // A diverging run can bring non-finite densities here: they flow into the loss, which the
    // training loop checks (and the checkpoint writer refuses), so they are not asserted away.
    let dir_norm = dir.length();
    let mut cum = 0.0f32; // sum of density * delta before interval i
    let mut out = RenderedRay::default();
    let mut dist_num = 0.0f32;
    for i in 0..n {
        let delta = (t_vals[i + 1] - t_vals[i]) * dir_norm;
        let dd = density[i] * delta;
        let alpha = 1.0 - (-dd).exp();
        let trans = (-cum).exp();
        cum += dd;
        let w = alpha * trans;
        weights[i] = w;
        for c in 0..3 {
            out.rgb[c] += w * rgb[i][c];
        }
        out.acc += w;
        dist_num += w * (0.5 * (t_vals[i] + t_vals[i + 1]));
    }
    // Rounding can push the sum of weights one ulp past 1 (the official code lets it); clamp so
    // that the accumulated opacity is always an opacity. This changes nothing but that last ulp.
    out.acc = out.acc.min(1.0);
    let d = dist_num / out.acc;
    let d = if d.is_nan() {
        0.0
    } else if d == f32::INFINITY {
        f32::MAX
    } else if d == f32::NEG_INFINITY {
        f32::MIN
    } else {
        d
    };
    out.distance = clamp_to(d, t_vals[0], t_vals[n]);
    for (c, b) in out.rgb.iter_mut().zip(bg) {
        *c += (1.0 - out.acc) * b;
    }
    out
}

/// The official background flag as a colour: white (`[1, 1, 1]`) with `white_bkgd`, else black.
#[must_use]
#[inline]
pub const fn background(white_bkgd: bool) -> [f32; 3] {
    if white_bkgd { [1.0; 3] } else { [0.0; 3] }
}

/// What [`volumetric_rendering`] composites along one ray: the samples' colours and densities,
/// the interval edges, the ray's direction (its length scales the intervals) and the background.
#[derive(Clone, Copy, Debug)]
pub struct RayComposite<'a> {
    /// A colour a sample.
    pub rgb: &'a [[f32; 3]],
    /// A density a sample.
    pub density: &'a [f32],
    /// `n + 1` interval edges.
    pub t_vals: &'a [f32],
    /// The ray's direction.
    pub dir: Vec3,
    /// The background colour.
    pub bg: [f32; 3],
}

/// The loss gradient with respect to a ray's composited colour and accumulated opacity.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Upstream {
    /// Of the colour.
    pub d_rgb: [f32; 3],
    /// Of the opacity.
    pub d_acc: f32,
}

/// The backward pass of [`volumetric_rendering`] with respect to the colours and densities.
///
/// Given the upstream gradients `d_rgb` (of the composited colour) and `d_acc` (of the accumulated
/// opacity), writes `dL/d rgb_i = w_i d_rgb` to `grad_rgb` and `dL/d density_i` to `grad_density`:
/// with `g_i = d_rgb · (rgb_i - bg) + d_acc` (`bg` the background colour of the forward pass),
/// `dL/d s_k = g_k T_{k+1} - sum_{i>k} g_i w_i` and `dL/d density_k = delta_k dL/d s_k`,
/// where `s_k = density_k delta_k`. `weights` must be the forward pass's. The edges `t_vals` get
/// no gradient (they are sampled, not learnt).
///
/// # Panics
/// If the lengths disagree.
pub fn volumetric_rendering_backward(
    ray: RayComposite<'_>,
    weights: &[f32],
    upstream: Upstream,
    grad_rgb: &mut [[f32; 3]],
    grad_density: &mut [f32],
) {
    let RayComposite { rgb, density, t_vals, dir, bg } = ray;
    let Upstream { d_rgb, d_acc } = upstream;
    let n = density.len();
    assert!(
        rgb.len() == n && t_vals.len() == n + 1 && weights.len() == n && grad_rgb.len() == n && grad_density.len() == n,
        "volumetric_rendering_backward: shapes"
    );
    let dir_norm = dir.length();
    let g = |k: usize| {
        d_rgb[0] * (rgb[k][0] - bg[0]) + d_rgb[1] * (rgb[k][1] - bg[1]) + d_rgb[2] * (rgb[k][2] - bg[2]) + d_acc
    };
    density_gradient(density, t_vals, dir_norm, weights, g, grad_density, false);
    for (grad, &w) in grad_rgb.iter_mut().zip(weights) {
        *grad = d_rgb.map(|d| w * d);
    }
}

/// `dL/d density_k = delta_k (g_k T_{k+1} - sum_{i>k} g_i w_i)` from `g_k = dL/dw_k`, written to
/// `grad_density` or added to it: the weights' Jacobian, which the colour loss
/// ([`volumetric_rendering_backward`]) and losses on the weights ([`weights_backward`]) share.
/// `T_{k+1}` is recomputed with the forward pass's prefix sums.
fn density_gradient(
    density: &[f32],
    t_vals: &[f32],
    dir_norm: f32,
    weights: &[f32],
    g: impl Fn(usize) -> f32,
    grad_density: &mut [f32],
    accumulate: bool,
) {
    let n = density.len();
    let mut cum = 0.0f32;
    let mut trans_next = Vec::with_capacity(n);
    let mut deltas = Vec::with_capacity(n);
    for k in 0..n {
        let delta = (t_vals[k + 1] - t_vals[k]) * dir_norm;
        cum += density[k] * delta;
        trans_next.push((-cum).exp());
        deltas.push(delta);
    }
    let mut suffix = 0.0f32; // sum_{i>k} g_i w_i
    for k in (0..n).rev() {
        let gk = g(k);
        let ds = gk * trans_next[k] - suffix;
        suffix += gk * weights[k];
        let grad = ds * deltas[k];
        grad_density[k] = if accumulate { grad_density[k] + grad } else { grad };
    }
}

/// The gradient with respect to each interval's density of a loss whose gradient with respect
/// to the weights of [`volumetric_rendering`] is `d_weights`, added to `grad_density`:
/// `dL/d density_k = delta_k (d_weights_k T_{k+1} - sum_{i>k} d_weights_i w_i)` (the weights'
/// Jacobian, as in [`volumetric_rendering_backward`], whose `g_i` is the colour loss's
/// `dL/dw_i`). For losses on the weights themselves, such as mip-NeRF 360's distortion loss
/// ([`crate::stages::distortion_loss`]).
///
/// # Panics
/// If the lengths disagree.
pub fn weights_backward(
    density: &[f32],
    t_vals: &[f32],
    dir: Vec3,
    weights: &[f32],
    d_weights: &[f32],
    grad_density: &mut [f32],
) {
    let n = density.len();
    assert!(
        t_vals.len() == n + 1 && weights.len() == n && d_weights.len() == n && grad_density.len() == n,
        "weights_backward: shapes"
    );
    density_gradient(density, t_vals, dir.length(), weights, |k| d_weights[k], grad_density, true);
}

/// How raw density becomes density.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
#[repr(u32)]
pub enum DensityActivation {
    /// `softplus(raw + bias)`: Mip-NeRF's choice (with bias -1).
    #[default]
    Softplus = 0,
    /// `relu(raw + bias)`: NeRF's choice (the "w/o misc" ablation, bias 0).
    Relu = 1,
}

/// `log(1 + exp(x))`, computed stably as `max(x, 0) + log1p(exp(-|x|))`.
#[must_use]
#[inline]
pub fn softplus(x: f32) -> f32 {
    x.max(0.0) + (-x.abs()).exp().ln_1p()
}

/// `1 / (1 + exp(-x))`.
#[must_use]
#[inline]
pub fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

impl DensityActivation {
    /// Density from the network's raw output: `act(raw + bias)`.
    #[must_use]
    #[inline]
    pub fn forward(self, raw: f32, bias: f32) -> f32 {
        let x = raw + bias;
        match self {
            Self::Softplus => softplus(x),
            Self::Relu => x.max(0.0),
        }
    }

    /// `d density / d raw` at `raw`: `sigmoid(raw + bias)` for softplus, the step for ReLU
    /// (0 at the kink).
    #[must_use]
    #[inline]
    pub fn derivative(self, raw: f32, bias: f32) -> f32 {
        let x = raw + bias;
        match self {
            Self::Softplus => sigmoid(x),
            Self::Relu => {
                if x > 0.0 {
                    1.0
                } else {
                    0.0
                }
            }
        }
    }
}

/// Colour from the network's raw output: `sigmoid(raw) (1 + 2 padding) - padding`, so that the
/// network can reach exact black and white without infinite raw values (padding 0.001 in Mip-NeRF,
/// 0 in NeRF).
#[must_use]
#[inline]
pub fn rgb_activation(raw: f32, padding: f32) -> f32 {
    sigmoid(raw) * (1.0 + 2.0 * padding) - padding
}

/// `d rgb / d raw` of [`rgb_activation`]: `sigmoid(raw) (1 - sigmoid(raw)) (1 + 2 padding)`.
#[must_use]
#[inline]
pub fn rgb_activation_derivative(raw: f32, padding: f32) -> f32 {
    let s = sigmoid(raw);
    s * (1.0 - s) * (1.0 + 2.0 * padding)
}
