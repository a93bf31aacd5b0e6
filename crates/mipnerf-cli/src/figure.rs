//! `mipnerf figure`: the paper's figure 1 for evaluated runs: one test view at every scale,
//! ground truth beside each run's render (each scale blown up to one size with square pixels, so
//! aliasing shows as it would on screen), a zoomed crop of each, and the PSNR on every render.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use plotters::prelude::*;

use crate::run_dir::RunDir;

/// What the figure shows.
pub struct FigureArgs {
    /// Evaluated run directories (`mipnerf eval` done), one column each.
    pub runs: Vec<PathBuf>,
    /// Column titles, one per run [default: the run directories' names].
    pub labels: Vec<String>,
    /// Which test view (index within each scale).
    pub view: usize,
    /// Width of one cell in pixels (its height in the images' aspect ratio).
    pub cell: u32,
    /// Crop `(x, y, side)` as fractions of the image's width and height (so the crop has the
    /// image's aspect ratio); `None` picks the window where the first run's error exceeds the
    /// last run's the most at the coarsest scale.
    pub crop: Option<(f64, f64, f64)>,
    /// The PNG to write.
    pub out: PathBuf,
    /// Replace `out` even when mipnerf did not write it.
    pub overwrite: bool,
}

/// One image: `w x h` RGB in `[0, 1]`.
struct Img {
    w: usize,
    h: usize,
    rgb: Vec<f32>,
}

impl Img {
    fn read(path: &Path) -> Result<Self> {
        let (w, h, rgb) = crate::eval::read_rgb(path)?;
        Ok(Self { w, h, rgb })
    }

    fn px(&self, x: usize, y: usize) -> [f32; 3] {
        let i = (y.min(self.h - 1) * self.w + x.min(self.w - 1)) * 3;
        [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]]
    }
}

/// One column's images at every scale, with their PSNRs.
struct Column {
    title: String,
    images: Vec<Img>,
    psnr: Vec<Option<f64>>,
}

/// The per-scale PSNRs of each run's whole test split, for the caller to print.
pub struct FigureSummary {
    /// `(label, mean PSNR per scale)` of each run.
    pub runs: Vec<(String, Vec<f64>)>,
}

fn read_metrics(run: &Path) -> Result<serde_json::Value> {
    let path = RunDir::new(run).eval_metrics();
    let text = mipnerf_core::io::read_regular_text(&path, mipnerf_core::io::cap::JSON)
        .with_context(|| format!("{}: run `mipnerf eval` on it first", path.display()))?;
    serde_json::from_str(&text).with_context(|| format!("{}: malformed JSON", path.display()))
}

/// The chosen view's entry at every scale: `(data file, scale, psnr)`.
fn view_entries(m: &serde_json::Value, view: usize, path: &Path) -> Result<Vec<(String, u64, Option<f64>)>> {
    let per_image = m["per_image"].as_array().with_context(|| format!("{}: no per_image list", path.display()))?;
    let mut scales: Vec<u64> = per_image.iter().filter_map(|i| i["scale"].as_u64()).collect();
    scales.sort_unstable();
    scales.dedup();
    scales
        .iter()
        .map(|&s| {
            let at: Vec<&serde_json::Value> = per_image.iter().filter(|i| i["scale"].as_u64() == Some(s)).collect();
            let e = at.get(view).with_context(|| {
                format!("{}: view {view} does not exist at scale {s} ({} views)", path.display(), at.len())
            })?;
            let file = e["file"].as_str().with_context(|| format!("{}: an image without a file", path.display()))?;
            Ok((file.to_string(), s, e["psnr"].as_f64()))
        })
        .collect()
}

/// The crop window (fractions) where `a`'s squared error exceeds `b`'s the most, or without `b`
/// where `a`'s is largest.
fn pick_crop(gt: &Img, a: &Img, b: Option<&Img>, side: f64) -> (f64, f64, f64) {
    let win = ((gt.w.min(gt.h) as f64 * side).round() as usize).max(1);
    let err = |img: &Img, x: usize, y: usize| -> f32 {
        let (p, q) = (img.px(x, y), gt.px(x, y));
        (0..3).map(|c| (p[c] - q[c]).powi(2)).sum()
    };
    let mut best = (f32::NEG_INFINITY, 0, 0);
    for y0 in 0..=gt.h.saturating_sub(win) {
        for x0 in 0..=gt.w.saturating_sub(win) {
            let mut s = 0.0;
            for y in y0..y0 + win {
                for x in x0..x0 + win {
                    s += err(a, x, y) - b.map_or(0.0, |b| err(b, x, y));
                }
            }
            if s > best.0 {
                best = (s, x0, y0);
            }
        }
    }
    (best.1 as f64 / gt.w as f64, best.2 as f64 / gt.h as f64, win as f64 / gt.w.min(gt.h) as f64)
}

/// Writes the figure; returns each run's per-scale PSNR.
///
/// # Errors
/// Runs that are not evaluated, runs of different data, unreadable images, or an unwritable PNG.
pub fn figure(args: &FigureArgs) -> Result<FigureSummary> {
    if args.runs.is_empty() || args.runs.len() > 4 {
        bail!("--run: give 1 to 4 evaluated runs, got {}", args.runs.len());
    }
    if !args.labels.is_empty() && args.labels.len() != args.runs.len() {
        bail!("--label: give one per --run ({} runs, {} labels)", args.runs.len(), args.labels.len());
    }
    crate::outputs::check_file(&args.out, "--out", args.overwrite)?;
    if let Some((x, y, s)) = args.crop
        && !(s > 0.0 && x >= 0.0 && y >= 0.0 && x + s <= 1.0 && y + s <= 1.0)
    {
        bail!("--crop {x},{y},{s}: the window must lie inside the image (fractions in [0, 1])");
    }
    let mut columns = Vec::new();
    let mut summary = Vec::new();
    let mut gt_files: Option<Vec<String>> = None;
    let mut scales = Vec::new();
    for (k, run) in args.runs.iter().enumerate() {
        let m = read_metrics(run)?;
        let entries = view_entries(&m, args.view, &RunDir::new(run).eval_metrics())?;
        let files: Vec<String> = entries.iter().map(|e| e.0.clone()).collect();
        scales = entries.iter().map(|e| e.1).collect();
        match &gt_files {
            None => gt_files = Some(files.clone()),
            Some(g) if *g != files => {
                bail!("{}: evaluated on other images than {}", run.display(), args.runs[0].display())
            }
            Some(_) => {}
        }
        let title = args.labels.get(k).cloned().unwrap_or_else(|| {
            run.file_name().map_or_else(|| run.display().to_string(), |n| n.to_string_lossy().to_string())
        });
        let images = files
            .iter()
            .map(|f| {
                let stem = Path::new(f).file_stem().map_or_else(String::new, |s| s.to_string_lossy().to_string());
                Img::read(&RunDir::new(run).eval().join(format!("{stem}.png")))
            })
            .collect::<Result<Vec<_>>>()?;
        let per_scale =
            m["per_scale"].as_array().map_or_else(Vec::new, |a| a.iter().filter_map(|s| s["psnr"].as_f64()).collect());
        summary.push((title.clone(), per_scale));
        columns.push(Column { title, images, psnr: entries.iter().map(|e| e.2).collect() });
    }
    let gt_files = gt_files.unwrap_or_default();
    let gt = Column {
        title: "ground truth".to_string(),
        images: gt_files.iter().map(|f| Img::read(Path::new(f))).collect::<Result<Vec<_>>>()?,
        psnr: vec![None; gt_files.len()],
    };
    let coarsest = gt_files.len() - 1;
    let crop = args.crop.unwrap_or_else(|| {
        let (a, b) = (&columns[0].images[coarsest], &columns[columns.len() - 1].images[coarsest]);
        // With one run, where its error is largest (the detail it has not learnt yet).
        pick_crop(&gt.images[coarsest], a, (columns.len() > 1).then_some(b), 0.3)
    });
    columns.insert(0, gt);
    draw(args, &columns, &scales, crop)?;
    Ok(FigureSummary { runs: summary })
}

const HEADER: u32 = 34;
const ROW_LABEL: u32 = 30;
const GAP: u32 = 4;

fn draw(args: &FigureArgs, columns: &[Column], scales: &[u64], crop: (f64, f64, f64)) -> Result<()> {
    crate::plot::ensure_font();
    let n_cols = columns.len() as u32 * 2;
    let n_rows = columns[0].images.len() as u32;
    let cell = args.cell;
    // Cells keep the images' aspect ratio (the truth at full scale's): `cell` wide.
    let first = &columns[0].images[0];
    let cell_h = ((f64::from(cell) * first.h as f64 / first.w as f64).round() as u32).max(1);
    let (w, h) = (ROW_LABEL + n_cols * (cell + GAP), HEADER + n_rows * (cell_h + GAP));
    let mut buf = vec![255u8; (w * h * 3) as usize];
    // Pixels: each image blown up with square pixels (nearest), then its crop.
    for (ci, col) in columns.iter().enumerate() {
        for (r, img) in col.images.iter().enumerate() {
            let y0 = HEADER + r as u32 * (cell_h + GAP);
            for (half, window) in [(0, (0.0, 0.0, 1.0)), (1, crop)] {
                let x0 = ROW_LABEL + (half * columns.len() as u32 + ci as u32) * (cell + GAP);
                for y in 0..cell_h {
                    for x in 0..cell {
                        let fx = window.0 + window.2 * (f64::from(x) + 0.5) / f64::from(cell);
                        let fy = window.1 + window.2 * (f64::from(y) + 0.5) / f64::from(cell_h);
                        let p = img.px((fx * img.w as f64) as usize, (fy * img.h as f64) as usize);
                        let i = (((y0 + y) * w + x0 + x) * 3) as usize;
                        for c in 0..3 {
                            buf[i + c] = (p[c].clamp(0.0, 1.0) * 255.0).round() as u8;
                        }
                    }
                }
            }
        }
    }
    let err = |e: &dyn std::fmt::Debug| anyhow::anyhow!("drawing {}: {e:?}", args.out.display());
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        let font = ("sans-serif", 15).into_font().color(&BLACK);
        let small = ("sans-serif", 15).into_font().color(&BLACK);
        for (ci, col) in columns.iter().enumerate() {
            for half in 0..2 {
                let x0 = ROW_LABEL + (half * columns.len() as u32 + ci as u32) * (cell + GAP);
                let t = if half == 0 { col.title.clone() } else { format!("{} (zoom)", col.title) };
                root.draw(&Text::new(t, (x0 as i32 + 4, 8), font.clone())).map_err(|e| err(&e))?;
                for (r, psnr) in col.psnr.iter().enumerate() {
                    let y0 = (HEADER + r as u32 * (cell_h + GAP)) as i32;
                    if half == 0 {
                        let (cx, cy, cs) = crop;
                        let (a, b) = (
                            (x0 as i32 + (cx * f64::from(cell)) as i32, y0 + (cy * f64::from(cell_h)) as i32),
                            (
                                x0 as i32 + ((cx + cs) * f64::from(cell)) as i32,
                                y0 + ((cy + cs) * f64::from(cell_h)) as i32,
                            ),
                        );
                        root.draw(&Rectangle::new([a, b], RGBColor(230, 160, 0).stroke_width(2)))
                            .map_err(|e| err(&e))?;
                    }
                    if let Some(p) = psnr {
                        let label = format!("{p:.2} dB");
                        let (bx, by) = (x0 as i32 + 3, y0 + cell_h as i32 - 22);
                        root.draw(&Rectangle::new([(bx, by), (bx + 72, by + 19)], WHITE.mix(0.8).filled()))
                            .map_err(|e| err(&e))?;
                        root.draw(&Text::new(label, (bx + 4, by + 2), small.clone())).map_err(|e| err(&e))?;
                    }
                }
            }
        }
        // Each row's scale and the size of the renders shown in it (the first run's column).
        for (r, img) in columns[1].images.iter().enumerate() {
            let y0 = (HEADER + r as u32 * (cell_h + GAP) + cell_h / 2) as i32;
            let scale = match scales.get(r).copied().unwrap_or(0) {
                0 => "full".to_string(),
                s => format!("1/{}", 1u64 << s.min(63)),
            };
            let style = small.clone().transform(FontTransform::Rotate270);
            root.draw(&Text::new(format!("{scale}, {} px", img.w), (6, y0 + 40), style)).map_err(|e| err(&e))?;
        }
        root.present().map_err(|e| err(&e))?;
    }
    let parent = args.out.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let name = args.out.file_name().map(|n| n.to_string_lossy().to_string()).unwrap_or_default();
    crate::outputs::record(parent, "figure", [name])?;
    crate::images::write_png(&args.out, w, h, &buf)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `side x side` image, black but for a white square at `(x0, y0)` of `s` pixels.
    fn square(side: usize, x0: usize, y0: usize, s: usize) -> Img {
        let mut rgb = vec![0.0; side * side * 3];
        for y in y0..y0 + s {
            for x in x0..x0 + s {
                rgb[(y * side + x) * 3..(y * side + x) * 3 + 3].copy_from_slice(&[1.0; 3]);
            }
        }
        Img { w: side, h: side, rgb }
    }

    /// A 4:3 capture (fern's 504 x 378) is drawn in 4:3 cells, not squeezed into squares.
    #[test]
    fn cells_keep_the_images_aspect_ratio() {
        let dir = tempfile::tempdir().unwrap();
        let img = || Img { w: 40, h: 30, rgb: vec![0.5; 40 * 30 * 3] };
        let column = |title: &str| Column { title: title.into(), images: vec![img()], psnr: vec![None] };
        let out = dir.path().join("figure.png");
        let args = FigureArgs {
            runs: vec![],
            labels: vec![],
            view: 0,
            cell: 192,
            crop: None,
            out: out.clone(),
            overwrite: false,
        };
        draw(&args, &[column("ground truth"), column("run")], &[0], (0.1, 0.1, 0.3)).unwrap();
        let (w, h) = image::image_dimensions(&out).unwrap();
        assert_eq!((w, h), (ROW_LABEL + 4 * (192 + GAP), HEADER + 144 + GAP));
    }

    #[test]
    fn one_run_is_cropped_where_it_errs_two_where_the_first_errs_more() {
        // The truth has detail at the bottom right; a blank render misses it there.
        let gt = square(40, 26, 26, 12);
        let blank = square(40, 0, 0, 0);
        let (x, y, side) = pick_crop(&gt, &blank, None, 0.3);
        assert!(x > 0.3 && y > 0.3 && (side - 0.3).abs() < 1e-9, "crop ({x}, {y}, {side}) misses the detail");
        // Two runs: where the first errs more than the second (the second got the detail).
        let (x, y, _) = pick_crop(&gt, &blank, Some(&gt), 0.3);
        assert!(x > 0.3 && y > 0.3, "crop ({x}, {y}) misses where the runs differ");
    }
}
