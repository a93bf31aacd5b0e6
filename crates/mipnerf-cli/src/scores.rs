//! The scores `mipnerf eval` writes (the types of `metrics.json`) and how a rendered image is
//! scored against its photo: PSNR, SSIM with the official settings, and the clamping both use.

use mipnerf_core::bf16::Precision;
use mipnerf_core::dataset::Split;
use mipnerf_core::metrics::{SsimConfig, mse_to_psnr, ssim};
use serde::Serialize;

/// One image's scores.
#[derive(Serialize, Debug, Clone)]
pub struct ImageScore {
    /// The image file.
    pub file: String,
    /// Its scale (downsampled by `2^scale`).
    pub scale: u32,
    /// PSNR in dB.
    pub psnr: f64,
    /// SSIM (official settings).
    pub ssim: f64,
    /// LPIPS (`lpips_net`), or `null` without the weights.
    pub lpips: Option<f64>,
    /// Mean squared error.
    pub mse: f64,
}

/// Mean scores of one scale.
#[derive(Serialize, Debug, Clone)]
pub struct ScaleScore {
    /// The scale.
    pub scale: u32,
    /// Mean PSNR.
    pub psnr: f64,
    /// Mean SSIM.
    pub ssim: f64,
    /// Mean LPIPS, or `null` without the weights.
    pub lpips: Option<f64>,
    /// The average error of this scale's means ([`mipnerf_core::metrics::average_error`]; its
    /// terms are `avg_error_terms`).
    pub avg_error: f64,
    /// Images averaged.
    pub images: usize,
}

/// The contents of `metrics.json`.
#[derive(Serialize, Debug)]
pub struct Metrics {
    /// Per scale means.
    pub per_scale: Vec<ScaleScore>,
    /// Per image scores.
    pub per_image: Vec<ImageScore>,
    /// The paper's single "average error" of the run: the geometric mean of MSE (from the PSNR
    /// averaged over scales), sqrt(1 - SSIM) and LPIPS, each averaged over the scales.
    pub avg_error: f64,
    /// Which terms the average error's geometric mean has: the paper's three, or the two-term
    /// variant without LPIPS.
    pub avg_error_terms: Vec<&'static str>,
    /// The LPIPS backbone (`vgg16` or `alexnet`), or `null` when LPIPS was not computed.
    pub lpips_net: Option<String>,
    /// Why LPIPS is absent, when it is.
    pub lpips_absent: Option<String>,
    /// How SSIM was computed.
    pub ssim_settings: &'static str,
    /// The split evaluated.
    pub split: Split,
    /// The training step of the checkpoint.
    pub step: u64,
    /// The precision of the MLP's products in this evaluation.
    pub precision: Precision,
}

impl Metrics {
    /// Per-scale values of one metric, full resolution first.
    #[must_use]
    pub fn column(&self, f: impl Fn(&ScaleScore) -> f64) -> Vec<f64> {
        self.per_scale.iter().map(f).collect()
    }

    /// Per-scale LPIPS, or `None` when it was not computed.
    #[must_use]
    pub fn lpips_column(&self) -> Option<Vec<f64>> {
        self.per_scale.iter().map(|s| s.lpips).collect()
    }
}

/// The official SSIM settings, or for an image smaller than the 11-tap filter (the 1/8 scale of a
/// small scene) the largest odd filter that fits, with sigma scaled alike: the official code would
/// return NaN there.
pub(crate) fn ssim_config(w: usize, h: usize) -> SsimConfig {
    let d = SsimConfig::default();
    let side = w.min(h);
    if side >= d.filter_size {
        return d;
    }
    let fs = if side % 2 == 1 { side } else { side.saturating_sub(1) }.max(1);
    SsimConfig { filter_size: fs, filter_sigma: d.filter_sigma * fs as f64 / d.filter_size as f64, ..d }
}

/// MSE, PSNR (dB) and SSIM (official settings) of two `w x h` RGB images in `[0, 1]`: the scores
/// `eval` and `compare` share.
pub(crate) fn pixel_scores(a: &[f32], b: &[f32], w: usize, h: usize) -> (f64, f64, f64) {
    let mse = mse(a, b);
    (mse, f64::from(mse_to_psnr(mse as f32)), ssim(a, b, h, w, 3, &ssim_config(w, h)))
}

pub(crate) fn mse(a: &[f32], b: &[f32]) -> f64 {
    a.iter().zip(b).map(|(x, y)| f64::from(x - y).powi(2)).sum::<f64>() / a.len() as f64
}

/// A rendered image's colours clamped to `[0, 1]` and flattened, as `eval` scores them.
pub(crate) fn flat_clamped(img: &[[f32; 3]]) -> Vec<f32> {
    img.iter().flat_map(|p| p.map(|c| c.clamp(0.0, 1.0))).collect()
}

/// The PSNR (dB) of a rendered image against its target, exactly as `eval` scores it (training's
/// validation uses it, so its curve ends where `eval` starts).
pub(crate) fn render_psnr(rendered: &[[f32; 3]], target: &[[f32; 3]]) -> f64 {
    f64::from(mse_to_psnr(mse(&flat_clamped(rendered), &flat_clamped(target)) as f32))
}
