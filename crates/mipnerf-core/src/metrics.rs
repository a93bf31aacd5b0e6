//! Image quality metrics with the official settings: PSNR and SSIM.

/// PSNR in dB of a mean squared error on `[0, 1]` images: `-10 log10(mse)` (`+inf` for 0).
#[must_use]
pub fn mse_to_psnr(mse: f32) -> f32 {
    -10.0 / std::f32::consts::LN_10 * mse.ln()
}

/// The mean squared error of a PSNR in dB: `10^(-psnr / 10)`.
#[must_use]
pub fn psnr_to_mse(psnr: f32) -> f32 {
    (-0.1 * std::f32::consts::LN_10 * psnr).exp()
}

/// The paper's "average error": the geometric mean of `MSE = 10^(-PSNR/10)`, `sqrt(1 - SSIM)` and
/// LPIPS, from a PSNR (dB), SSIM and LPIPS that are each already averaged (over images, and for the
/// table's single column, over scales). Without LPIPS (`None`) it is the geometric mean of the
/// first two terms only: a different number, to be named as such wherever it is shown.
///
/// Matches the paper's Table 1: Mip-NeRF's per-scale means (PSNR 34.51, SSIM 0.9725, LPIPS 0.0254)
/// give its printed 0.0114.
#[must_use]
pub fn average_error(psnr: f64, ssim: f64, lpips: Option<f64>) -> f64 {
    debug_assert!(psnr.is_finite() && ssim.is_finite(), "average_error: non-finite input");
    let mse = 10f64.powf(-psnr / 10.0);
    let dssim = (1.0 - ssim).max(0.0).sqrt();
    match lpips {
        Some(l) => (mse * dssim * l).cbrt(),
        None => (mse * dssim).sqrt(),
    }
}

/// Settings of [`ssim`]; the default is the official one (11 taps, sigma 1.5, k1 0.01, k2 0.03,
/// values in `[0, 1]`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SsimConfig {
    /// Largest possible value.
    pub max_val: f64,
    /// Gaussian filter taps.
    pub filter_size: usize,
    /// Gaussian filter standard deviation, pixels.
    pub filter_sigma: f64,
    /// Luminance stabiliser.
    pub k1: f64,
    /// Contrast stabiliser.
    pub k2: f64,
}

impl Default for SsimConfig {
    fn default() -> Self {
        Self { max_val: 1.0, filter_size: 11, filter_sigma: 1.5, k1: 0.01, k2: 0.03 }
    }
}

/// The SSIM map of two `height x width x channels` images (row-major, interleaved channels), with
/// a separable Gaussian blur and "valid" filtering: `(height - taps + 1) x (width - taps + 1) x
/// channels` values. Returns an empty map when the image is smaller than the filter.
///
/// # Panics
/// If the images' lengths differ from `height * width * channels`.
#[must_use]
pub fn ssim_map(a: &[f32], b: &[f32], height: usize, width: usize, channels: usize, cfg: &SsimConfig) -> Vec<f64> {
    assert!(a.len() == height * width * channels && b.len() == a.len(), "ssim: image sizes");
    let fs = cfg.filter_size;
    if height < fs || width < fs {
        return Vec::new();
    }
    let hw = (fs / 2) as f64;
    let shift = (2.0 * hw - fs as f64 + 1.0) / 2.0;
    let mut filt: Vec<f64> =
        (0..fs).map(|i| (-0.5 * ((i as f64 - hw + shift) / cfg.filter_sigma).powi(2)).exp()).collect();
    let total: f64 = filt.iter().sum();
    filt.iter_mut().for_each(|f| *f /= total);
    let (oh, ow) = (height - fs + 1, width - fs + 1);
    let blur = |img: &dyn Fn(usize) -> f64| -> Vec<f64> {
        // Along x, then along y; output oh x ow x channels.
        let mut tmp = vec![0.0; height * ow * channels];
        for y in 0..height {
            for x in 0..ow {
                for c in 0..channels {
                    tmp[(y * ow + x) * channels + c] =
                        (0..fs).map(|k| filt[k] * img((y * width + x + k) * channels + c)).sum();
                }
            }
        }
        let mut out = vec![0.0; oh * ow * channels];
        for y in 0..oh {
            for x in 0..ow {
                for c in 0..channels {
                    out[(y * ow + x) * channels + c] =
                        (0..fs).map(|k| filt[k] * tmp[((y + k) * ow + x) * channels + c]).sum();
                }
            }
        }
        out
    };
    let fa = |i: usize| f64::from(a[i]);
    let fb = |i: usize| f64::from(b[i]);
    let mu0 = blur(&fa);
    let mu1 = blur(&fb);
    let s00 = blur(&|i| fa(i) * fa(i));
    let s11 = blur(&|i| fb(i) * fb(i));
    let s01 = blur(&|i| fa(i) * fb(i));
    let c1 = (cfg.k1 * cfg.max_val).powi(2);
    let c2 = (cfg.k2 * cfg.max_val).powi(2);
    (0..mu0.len())
        .map(|i| {
            let (m0, m1) = (mu0[i], mu1[i]);
            let v00 = (s00[i] - m0 * m0).max(0.0);
            let v11 = (s11[i] - m1 * m1).max(0.0);
            let raw01 = s01[i] - m0 * m1;
            let v01 = raw01.signum() * (v00 * v11).sqrt().min(raw01.abs());
            let v01 = if raw01 == 0.0 { 0.0 } else { v01 };
            ((2.0 * m0 * m1 + c1) * (2.0 * v01 + c2)) / ((m0 * m0 + m1 * m1 + c1) * (v00 + v11 + c2))
        })
        .collect()
}

/// The mean SSIM of two images (see [`ssim_map`]); NaN when the image is smaller than the filter.
#[must_use]
pub fn ssim(a: &[f32], b: &[f32], height: usize, width: usize, channels: usize, cfg: &SsimConfig) -> f64 {
    let m = ssim_map(a, b, height, width, channels, cfg);
    if m.is_empty() { f64::NAN } else { m.iter().sum::<f64>() / m.len() as f64 }
}
