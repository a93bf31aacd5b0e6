//! `mipnerf eval`: render a split, measure it, and write metrics.json, a markdown table and a
//! per-image PSNR chart.

use std::path::Path;

use anyhow::{Context, Result};
use mipnerf_core::backend::ImageSpec;
use mipnerf_core::data::Split;
use mipnerf_core::metrics::{SsimConfig, mse_to_psnr, ssim};
use serde::Serialize;

use crate::config::Backend;
use crate::images::{rgb_to_png, write_png};
use crate::run::{load_split, open_trained, read_config};

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
    /// Geometric mean of the mean MSE and sqrt(1 - mean SSIM) (no LPIPS: see `avg_error_terms`).
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
    /// Which terms the average error's geometric mean has.
    pub avg_error_terms: Vec<&'static str>,
    /// Why LPIPS is absent.
    pub lpips: &'static str,
    /// How SSIM was computed.
    pub ssim_settings: &'static str,
    /// The split evaluated.
    pub split: Split,
    /// The training step of the checkpoint.
    pub step: u64,
}

/// The official SSIM settings, or for an image smaller than the 11-tap filter (the 1/8 scale of a
/// small scene) the largest odd filter that fits, with sigma scaled alike: the official code would
/// return NaN there.
fn ssim_config(w: usize, h: usize) -> SsimConfig {
    let d = SsimConfig::default();
    let side = w.min(h);
    if side >= d.filter_size {
        return d;
    }
    let fs = if side % 2 == 1 { side } else { side.saturating_sub(1) }.max(1);
    SsimConfig { filter_size: fs, filter_sigma: d.filter_sigma * fs as f64 / d.filter_size as f64, ..d }
}

/// Renders and scores every image of `split`; writes `RUN/eval/`.
///
/// # Errors
/// Missing run files or data.
pub fn eval(run: &Path, split: Split, backend: Backend) -> Result<Metrics> {
    let s = read_config(run)?;
    let ds = load_split(&s, split)?;
    let (mut be, step) = open_trained(run, &s, backend)?;
    let out = run.join("eval");
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    let k = be.model().config.supersample;
    let levels = be.model().config.num_levels;
    let mut per_image = Vec::new();
    let pb = indicatif::ProgressBar::new(ds.views.len() as u64);
    for v in 0..ds.views.len() {
        let view = &ds.views[v];
        let (w, h) = (view.camera.width as usize, view.camera.height as usize);
        let image = ImageSpec::of_view(&ds, v, k);
        let rendered: Vec<[f32; 3]> = be
            .render_image(&image)
            .with_context(|| view.file.display().to_string())?
            .chunks(levels)
            .map(|l| l[levels - 1].rgb)
            .collect();
        let target = ds.view_targets(v);
        let flat = |img: &[[f32; 3]]| img.iter().flat_map(|p| p.map(|c| c.clamp(0.0, 1.0))).collect::<Vec<f32>>();
        let (a, b) = (flat(&rendered), flat(&target));
        let mse = a.iter().zip(&b).map(|(x, y)| f64::from(x - y).powi(2)).sum::<f64>() / a.len() as f64;
        let ss = ssim(&a, &b, h, w, 3, &ssim_config(w, h));
        let stem = view.file.file_stem().map_or_else(|| format!("{v:04}"), |s| s.to_string_lossy().to_string());
        write_png(&out.join(format!("{stem}.png")), w as u32, h as u32, &rgb_to_png(&rendered))?;
        per_image.push(ImageScore {
            file: view.file.display().to_string(),
            scale: view.scale,
            psnr: f64::from(mse_to_psnr(mse as f32)),
            ssim: ss,
            mse,
        });
        pb.inc(1);
    }
    pb.finish_and_clear();
    let mut per_scale = Vec::new();
    for scale in ds.scales() {
        let imgs: Vec<&ImageScore> = per_image.iter().filter(|i| i.scale == scale).collect();
        let n = imgs.len() as f64;
        let mean = |f: fn(&ImageScore) -> f64| imgs.iter().map(|i| f(i)).sum::<f64>() / n;
        let (mse, ss) = (mean(|i| i.mse), mean(|i| i.ssim));
        per_scale.push(ScaleScore {
            scale,
            psnr: mean(|i| i.psnr),
            ssim: ss,
            avg_error: (mse * (1.0 - ss).max(0.0).sqrt()).sqrt(),
            images: imgs.len(),
        });
    }
    let metrics = Metrics {
        per_scale,
        per_image,
        avg_error_terms: vec!["mse", "sqrt(1 - ssim)"],
        lpips: "not computed: LPIPS needs pretrained VGG/AlexNet weights, which no crate on this \
                project's registries ships and which cannot be fetched at run time",
        ssim_settings: "official: 11-tap Gaussian filter, sigma 1.5, k1 0.01, k2 0.03, valid filtering, mean over \
                        channels; images smaller than 11 px use the largest odd filter that fits, sigma scaled alike",
        split,
        step,
    };
    let json = serde_json::to_string_pretty(&metrics)?;
    std::fs::write(out.join("metrics.json"), json).context("writing metrics.json")?;
    std::fs::write(out.join("metrics.md"), markdown(&metrics)).context("writing metrics.md")?;
    let bars: Vec<(String, u32, f64)> = metrics.per_image.iter().map(|i| (i.file.clone(), i.scale, i.psnr)).collect();
    crate::plot::psnr_bars(&out.join("psnr_per_image.png"), &bars)?;
    Ok(metrics)
}

/// The paper's table layout: PSNR and SSIM per scale, then the average error.
#[must_use]
pub fn markdown(m: &Metrics) -> String {
    let scale_name = |s: u32| if s == 0 { "full".to_string() } else { format!("1/{}", 1 << s) };
    let mut head = String::from("| run |");
    let mut rule = String::from("|---|");
    let mut row = format!("| step {} |", m.step);
    for metric in ["PSNR", "SSIM"] {
        for s in &m.per_scale {
            head += &format!(" {metric} {} |", scale_name(s.scale));
            rule += "---|";
            row += &if metric == "PSNR" { format!(" {:.3} |", s.psnr) } else { format!(" {:.4} |", s.ssim) };
        }
    }
    let avg = m.per_scale.iter().map(|s| s.avg_error.ln()).sum::<f64>() / m.per_scale.len().max(1) as f64;
    head += " Avg. error |";
    rule += "---|";
    row += &format!(" {:.4} |", avg.exp());
    format!(
        "{head}\n{rule}\n{row}\n\nAverage error: geometric mean of MSE and sqrt(1 - SSIM) per scale, then over scales \
         (LPIPS not computed). Split: {}.\n",
        m.split
    )
}
