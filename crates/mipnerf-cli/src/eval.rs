//! `mipnerf eval`: render a split, measure it, and write metrics.json, a markdown table and a
//! per-image PSNR chart.

use crate::session::Session;
use std::path::Path;

use anyhow::{Context, Result};
use mipnerf_core::backend::ImageSpec;
use mipnerf_core::dataset::Split;
use mipnerf_core::metrics::average_error;
use mipnerf_core::model::Levels;
use serde::Serialize;

use crate::images::{rgb_to_png, write_png};
use crate::lpips::LpipsWeights;
use crate::outputs::save_keeping_the_old;
use crate::run::{RunOn, load_split, open_trained, read_config};
use crate::run_dir::RunDir;
use crate::scores::{ImageScore, Metrics, ScaleScore};
use crate::scores::{flat_clamped, pixel_scores};

/// Renders and scores every image of `split`; writes `RUN/eval/` for the test split, and
/// `RUN/eval_train/` or `RUN/eval_val/` for the others (so the test scores are never replaced by
/// another split's).
///
/// LPIPS is computed when `weights` lead to weights; otherwise it is `null`, the average error is
/// the two-term variant (named so in `avg_error_terms`), and one line says how to get them.
///
/// # Errors
/// Missing run files or data, or weights that are present but unusable.
pub fn eval(run: &Path, split: Split, on: RunOn<'_>, weights: &LpipsWeights, session: &Session) -> Result<Metrics> {
    let s = read_config(run)?;
    let (lpips, lpips_absent) = match weights.open()? {
        Ok(l) => (Some(l), None),
        Err(why) => {
            eprintln!("LPIPS: not computed: {why}");
            (None, Some(why))
        }
    };
    let lpips = lpips.as_ref();
    let lpips_absent = lpips_absent.as_deref();
    let ds = load_split(&s, split)?;
    let (mut be, step, precision) = open_trained(run, &s, on, session)?;
    // Everything goes to eval.partial/, renamed to eval/ once whole: an interrupted or failed
    // eval leaves the previous results as they were and nothing that looks complete.
    let out = RunDir::new(run).eval_partial_of(split);
    if out.is_dir() {
        std::fs::remove_dir_all(&out).with_context(|| format!("removing the unfinished {}", out.display()))?;
    }
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    let k = be.model().config().supersample;
    let mut per_image = Vec::new();
    let mut entries = Vec::new();
    let mut pb = session.progress("eval", 0, ds.views().len() as u64);
    for v in 0..ds.views().len() {
        let view = &ds.views()[v];
        let (w, h) = (view.camera.width as usize, view.camera.height as usize);
        let image = ImageSpec::of_view(&ds, v, k);
        let rendered: Vec<[f32; 3]> = be
            .render(&image, Levels::Last)
            .with_context(|| view.file.display().to_string())?
            .fine
            .iter()
            .map(|o| o.rgb)
            .collect();
        let target = ds.view_targets(v);
        let (a, b) = (flat_clamped(&rendered), flat_clamped(&target));
        let (mse, psnr, ss) = pixel_scores(&a, &b, w, h);
        // LPIPS of images smaller than the backbone takes (the coarse scales of a tiny scene) is
        // left out, image by image; the scale then has no LPIPS.
        let lp = lpips
            .filter(|l| w.min(h) >= l.min_side())
            .map(|l| l.distance(&a, &b, w, h))
            .transpose()
            .with_context(|| view.file.display().to_string())?;
        let stem = view.file.file_stem().map_or_else(|| format!("{v:04}"), |s| s.to_string_lossy().to_string());
        write_png(&out.join(format!("{stem}.png")), w as u32, h as u32, &rgb_to_png(&rendered))?;
        write_png(&out.join(format!("{stem}_gt.png")), w as u32, h as u32, &rgb_to_png(&target))?;
        write_png(&out.join(format!("{stem}_error.png")), w as u32, h as u32, &crate::html::error_map(&a, &b))?;
        entries.push(crate::html::Entry {
            name: stem.clone(),
            scale: view.scale,
            size: (w, h),
            scores: (psnr, ss, lp),
            files: [format!("{stem}_gt.png"), format!("{stem}.png"), format!("{stem}_error.png")],
        });
        per_image.push(ImageScore {
            file: view.file.display().to_string(),
            scale: view.scale,
            psnr,
            ssim: ss,
            lpips: lp,
            mse,
        });
        pb.inc();
    }
    pb.finish();
    let per_scale = per_scale_scores(&ds.scales(), &per_image);
    let over_scales = |f: fn(&ScaleScore) -> f64| per_scale.iter().map(f).sum::<f64>() / per_scale.len().max(1) as f64;
    let lpips_mean = per_scale.iter().map(|s| s.lpips).sum::<Option<f64>>().map(|sum| sum / per_scale.len() as f64);
    let lpips_absent = match (lpips, lpips_mean) {
        (Some(l), None) => Some(format!(
            "some images are smaller than LPIPS-{} takes ({} px a side); those images and their scales have no LPIPS",
            l.net().name(),
            l.min_side()
        )),
        _ => lpips_absent.map(str::to_string),
    };
    let avg_error = average_error(over_scales(|s| s.psnr), over_scales(|s| s.ssim), lpips_mean);
    let metrics = Metrics {
        per_scale,
        per_image,
        avg_error,
        avg_error_terms: if lpips_mean.is_some() {
            vec!["mse", "sqrt(1 - ssim)", "lpips"]
        } else {
            vec!["mse", "sqrt(1 - ssim)"]
        },
        lpips_net: lpips.map(|l| l.net().name().to_string()),
        lpips_absent,
        ssim_settings: "official: 11-tap Gaussian filter, sigma 1.5, k1 0.01, k2 0.03, valid filtering, mean over \
                        channels; images smaller than 11 px use the largest odd filter that fits, sigma scaled alike",
        split,
        step,
        precision,
    };
    write_reports(&out, run, &metrics, &entries)?;
    swap_in(&out, &RunDir::new(run).eval_of(split))?;
    Ok(metrics)
}

/// The mean scores of each scale's images.
fn per_scale_scores(scales: &[u32], per_image: &[ImageScore]) -> Vec<ScaleScore> {
    let mut per_scale = Vec::new();
    for &scale in scales {
        let imgs: Vec<&ImageScore> = per_image.iter().filter(|i| i.scale == scale).collect();
        let n = imgs.len() as f64;
        let mean = |f: fn(&ImageScore) -> f64| imgs.iter().map(|i| f(i)).sum::<f64>() / n;
        let (psnr, ss) = (mean(|i| i.psnr), mean(|i| i.ssim));
        let lp = imgs.iter().map(|i| i.lpips).sum::<Option<f64>>().map(|sum| sum / n);
        per_scale.push(ScaleScore {
            scale,
            psnr,
            ssim: ss,
            lpips: lp,
            avg_error: average_error(psnr, ss, lp),
            images: imgs.len(),
        });
    }
    per_scale
}

/// The evaluation's reports in `out`: metrics.json and .md, the PSNR bars, the error map's
/// colour bar and the page of every image.
fn write_reports(out: &Path, run: &Path, metrics: &Metrics, entries: &[crate::html::Entry]) -> Result<()> {
    let json = serde_json::to_string_pretty(metrics)?;
    save_keeping_the_old(&out.join("metrics.json"), json.as_bytes())?;
    save_keeping_the_old(&out.join("metrics.md"), markdown(metrics).as_bytes())?;
    let bars: Vec<(String, u32, f64)> = metrics.per_image.iter().map(|i| (i.file.clone(), i.scale, i.psnr)).collect();
    crate::plot::psnr_bars(&out.join("psnr_per_image.png"), &bars)?;
    crate::plot::colour_bar(
        &out.join("error_scale.png"),
        "error |render - truth|",
        0.0,
        f64::from(crate::html::ERROR_MAP_MAX),
        crate::images::turbo,
    )?;
    crate::html::write_index(out, run, metrics, entries)
}

/// Puts the finished `partial` folder in place of `dest`: `dest` is renamed aside (`.old`),
/// `partial` renamed to `dest`, and the old one removed. A failure before the second rename
/// leaves `dest` as it was, and the error says so.
///
/// # Errors
/// A rename that fails.
fn swap_in(partial: &Path, dest: &Path) -> Result<()> {
    let mut old = dest.as_os_str().to_owned();
    old.push(".old");
    let old = std::path::PathBuf::from(old);
    let unchanged =
        || format!("{} (the previous results) is unchanged; the new ones are in {}", dest.display(), partial.display());
    if old.is_dir() {
        std::fs::remove_dir_all(&old).with_context(|| format!("removing {}; {}", old.display(), unchanged()))?;
    }
    if dest.exists() {
        std::fs::rename(dest, &old).with_context(|| format!("moving {} aside; {}", dest.display(), unchanged()))?;
    }
    std::fs::rename(partial, dest).with_context(|| format!("renaming {} to {}", partial.display(), dest.display()))?;
    if old.is_dir() {
        std::fs::remove_dir_all(&old).with_context(|| format!("removing {}", old.display()))?;
    }
    Ok(())
}

/// The paper's table layout: PSNR, SSIM and LPIPS per scale, then the average error.
#[must_use]
pub fn markdown(m: &Metrics) -> String {
    let scale_name = |s: u32| if s == 0 { "full".to_string() } else { format!("1/{}", 1 << s) };
    let mut head = String::from("| run |");
    let mut rule = String::from("|---|");
    let mut row = format!("| step {} |", m.step);
    for metric in ["PSNR", "SSIM", "LPIPS"] {
        for s in &m.per_scale {
            head += &format!(" {metric} {} |", scale_name(s.scale));
            rule += "---|";
            row += &match metric {
                "PSNR" => format!(" {:.3} |", s.psnr),
                "SSIM" => format!(" {:.4} |", s.ssim),
                _ => s.lpips.map_or(" n/a |".to_string(), |l| format!(" {l:.4} |")),
            };
        }
    }
    head += " Avg. error |";
    rule += "---|";
    row += &format!(" {:.4} |", m.avg_error);
    let avg = match m.lpips_net.as_ref().filter(|_| m.avg_error_terms.len() == 3) {
        Some(net) => format!(
            "Average error: the paper's, the geometric mean of MSE = 10^(-PSNR/10), sqrt(1 - SSIM) and LPIPS ({net}), \
             each averaged over the scales."
        ),
        None => "Average error (two-term variant, LPIPS absent): the geometric mean of MSE = 10^(-PSNR/10) and \
                 sqrt(1 - SSIM), each averaged over the scales; not comparable with the paper's."
            .to_string(),
    };
    format!("{head}\n{rule}\n{row}\n\n{avg} Split: {}.\n", m.split)
}

/// Reads an image as RGB in `[0, 1]`, composited on white when it has alpha.
pub(crate) fn read_rgb(path: &Path) -> Result<(usize, usize, Vec<f32>)> {
    let file =
        mipnerf_core::io::open_regular(path).with_context(|| format!("{}: cannot open the image", path.display()))?;
    let img = image::ImageReader::new(std::io::BufReader::new(file))
        .with_guessed_format()
        .with_context(|| format!("{}: cannot read the image", path.display()))?
        .decode()
        .with_context(|| format!("{}: cannot decode the image", path.display()))?;
    let alpha = img.color().has_alpha();
    let rgba = img.to_rgba32f();
    let (w, h) = (rgba.width() as usize, rgba.height() as usize);
    let rgb = rgba
        .pixels()
        .flat_map(|p| {
            let a = if alpha { p.0[3] } else { 1.0 };
            [0, 1, 2].map(|c| p.0[c] * a + (1.0 - a))
        })
        .collect();
    Ok((w, h, rgb))
}

/// The scores `mipnerf compare` prints.
#[derive(Serialize, Debug)]
pub struct Comparison {
    /// PSNR in dB; `null` in JSON when the images are identical (`mse` 0, PSNR infinite).
    pub psnr: f64,
    /// The mean squared error over the pixels' channels, in [0, 1].
    pub mse: f64,
    /// SSIM, official settings.
    pub ssim: f64,
    /// LPIPS, or `null` when not computed (no weights, or images smaller than the backbone takes).
    pub lpips: Option<f64>,
    /// The LPIPS backbone (`vgg16` or `alexnet`) when LPIPS was computed.
    pub lpips_net: Option<&'static str>,
}

/// `mipnerf compare A B`: PSNR, SSIM and LPIPS of two images of one size.
///
/// # Errors
/// Unreadable files, different sizes, unusable LPIPS weights, or (with `require_lpips`) missing
/// ones, after PSNR and SSIM are printed.
pub fn compare(a: &Path, b: &Path, json: bool, weights: &LpipsWeights, require_lpips: bool) -> Result<()> {
    let (wa, ha, ia) = read_rgb(a)?;
    let (wb, hb, ib) = read_rgb(b)?;
    if (wa, ha) != (wb, hb) {
        anyhow::bail!("{} is {wa}x{ha} but {} is {wb}x{hb}: the images must have one size", a.display(), b.display());
    }
    let (mse, psnr, ss) = pixel_scores(&ia, &ib, wa, ha);
    let net: mipnerf_core::lpips::Net = weights.net.into();
    let (lpips, absent) = match weights.open()? {
        // As eval leaves out images smaller than the backbone takes.
        Ok(l) if wa.min(ha) < l.min_side() => (
            None,
            Some(format!(
                "the images ({wa}x{ha}) are smaller than LPIPS-{} takes ({} px a side)",
                net.name(),
                l.min_side()
            )),
        ),
        Ok(l) => (Some(l.distance(&ia, &ib, wa, ha)?), None),
        Err(why) => (None, Some(why)),
    };
    if let Some(why) = &absent
        && require_lpips
    {
        anyhow::bail!("LPIPS not computed (--require-lpips): {why}");
    }
    let c = Comparison { psnr, mse, ssim: ss, lpips, lpips_net: lpips.map(|_| net.name()) };
    if json {
        println!("{}", serde_json::to_string(&c)?);
    } else {
        println!("PSNR  {psnr:.4} dB{}", if mse == 0.0 { " (the images are identical)" } else { "" });
        println!("SSIM  {ss:.6}");
        match lpips {
            Some(l) => println!("LPIPS {l:.6} ({})", net.name()),
            None => println!("LPIPS n/a"),
        }
    }
    if let Some(why) = absent {
        eprintln!("LPIPS skipped: {why}");
    }
    Ok(())
}
