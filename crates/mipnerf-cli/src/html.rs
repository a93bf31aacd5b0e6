//! `eval/index.html`: one page with a run's scores, its training curves and every test image as
//! ground truth | render | error map, per scale. The images sit beside the page; nothing is
//! fetched from the network. A small inline script checks that every image decoded and records
//! the count on the page (`data-images-ok`), which the browser test reads.

use std::fmt::Write as _;
use std::path::Path;

use anyhow::{Context, Result};
use mipnerf_core::dataset::Split;

use crate::scores::Metrics;

/// One test image on the page: the files beside `index.html` and its scores.
pub struct Entry {
    /// Shown name (the file stem).
    pub name: String,
    /// Scale (0 = full).
    pub scale: u32,
    /// Width and height in pixels.
    pub size: (usize, usize),
    /// PSNR (dB), SSIM, LPIPS.
    pub scores: (f64, f64, Option<f64>),
    /// File names of the ground truth, the render and the error map.
    pub files: [String; 3],
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

fn scale_name(s: u32) -> String {
    if s == 0 { "full".to_string() } else { format!("1/{}", 1u32 << s) }
}

/// The error an error map's top colour stands for (and above).
pub const ERROR_MAP_MAX: f32 = 0.25;

/// The error map of a render: per pixel, the mean absolute difference over the channels, 0 to
/// 0.25 (and above) mapped through the turbo colour map; RGB8.
#[must_use]
pub fn error_map(render: &[f32], truth: &[f32]) -> Vec<u8> {
    let max = ERROR_MAP_MAX;
    render
        .chunks_exact(3)
        .zip(truth.chunks_exact(3))
        .flat_map(|(a, b)| {
            let e = a.iter().zip(b).map(|(x, y)| (x - y).abs()).sum::<f32>() / 3.0;
            crate::images::turbo((e / max).clamp(0.0, 1.0))
        })
        .collect()
}

/// Writes `out/index.html` for `metrics` of the run `run` (its training curves, when present, are
/// copied beside the page).
///
/// # Errors
/// Unwritable files.
pub fn write_index(out: &Path, run: &Path, metrics: &Metrics, entries: &[Entry]) -> Result<()> {
    let mut curves = Vec::new();
    for (src, dst) in [("loss.png", "training_loss.png"), ("psnr.png", "training_psnr.png")] {
        if run.join(src).is_file() {
            std::fs::copy(run.join(src), out.join(dst)).with_context(|| format!("copying {src}"))?;
            curves.push(dst);
        }
    }
    let mut h = String::new();
    let title = format!("mipnerf eval: {} (step {}, {} split)", run.display(), metrics.step, metrics.split);
    let _ = write!(
        h,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{t}</title>\n<style>\
         body{{font-family:sans-serif;margin:1.5em;color:#222}} table{{border-collapse:collapse;margin:.5em 0}}\
         td,th{{border:1px solid #ccc;padding:.25em .6em;text-align:right}} th{{background:#f3f3f3}}\
         td.img{{padding:2px}} img.px{{width:160px;image-rendering:pixelated}} .n{{text-align:left}}\
         </style></head>\n<body>\n<h1>{t}</h1>\n",
        t = escape(&title)
    );
    h += "<h2>Scores per scale</h2>\n<table><tr><th>scale</th><th>images</th><th>PSNR (dB)</th><th>SSIM</th>\
          <th>LPIPS</th><th>avg. error</th></tr>\n";
    for s in &metrics.per_scale {
        let lp = s.lpips.map_or("n/a".to_string(), |l| format!("{l:.4}"));
        let _ = writeln!(
            h,
            "<tr><td>{}</td><td>{}</td><td>{:.2}</td><td>{:.4}</td><td>{lp}</td><td>{:.4}</td></tr>",
            scale_name(s.scale),
            s.images,
            s.psnr,
            s.ssim,
            s.avg_error
        );
    }
    let terms = if metrics.avg_error_terms.len() == 3 { "the paper's" } else { "two-term variant, without LPIPS" };
    let _ = writeln!(h, "</table>\n<p>Average error over the scales ({terms}): {:.4}</p>", metrics.avg_error);
    h += "<h2>Training</h2>\n<p>";
    for c in &curves {
        let _ = write!(h, "<img src=\"{c}\" alt=\"{c}\" style=\"max-width:48%\"> ");
    }
    if curves.is_empty() {
        h += "(no training curves in the run directory)";
    }
    h += "</p>\n<p><img src=\"psnr_per_image.png\" alt=\"PSNR per image\" style=\"max-width:96%\"></p>\n";
    let images = match metrics.split {
        Split::Train => "Training images",
        Split::Val => "Validation images",
        Split::Test => "Test images",
    };
    let _ = writeln!(h, "<h2>{images}: ground truth | render | error (|render - truth|, 0 to 0.25, turbo)</h2>");
    h += "<p><img src=\"error_scale.png\" alt=\"error colour scale: 0 to 0.25\"></p>\n\
          <table><tr><th class=\"n\">image</th><th>scale</th><th>PSNR</th><th>SSIM</th><th>LPIPS</th>\
          <th>ground truth</th><th>render</th><th>error</th></tr>\n";
    for e in entries {
        let lp = e.scores.2.map_or("n/a".to_string(), |l| format!("{l:.4}"));
        let _ = write!(
            h,
            "<tr><td class=\"n\">{}</td><td>{} ({}x{})</td><td>{:.2}</td><td>{:.4}</td><td>{lp}</td>",
            escape(&e.name),
            scale_name(e.scale),
            e.size.0,
            e.size.1,
            e.scores.0,
            e.scores.1
        );
        for f in &e.files {
            let _ = write!(h, "<td class=\"img\"><img class=\"px\" src=\"{}\" alt=\"{}\"></td>", escape(f), escape(f));
        }
        h += "</tr>\n";
    }
    h += "</table>\n<script>\nwindow.addEventListener('load', () => {\n  const imgs = [...document.images];\n  \
          const bad = imgs.filter(i => !(i.complete && i.naturalWidth > 0));\n  \
          bad.forEach(i => console.error('image failed to load: ' + i.getAttribute('src')));\n  \
          document.body.dataset.imagesOk = String(imgs.length - bad.length);\n  \
          document.body.dataset.imagesTotal = String(imgs.length);\n});\n</script>\n</body></html>\n";
    crate::outputs::save_keeping_the_old(&out.join("index.html"), h.as_bytes())
}
