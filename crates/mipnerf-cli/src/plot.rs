//! PNG charts: training curves and per-image PSNR bars (plotters, with an embedded DejaVu Sans so
//! that no system fonts are needed).

use std::path::Path;
use std::sync::OnceLock;

use anyhow::{Context, Result, anyhow};
use plotters::prelude::*;

static FONT: OnceLock<bool> = OnceLock::new();

pub(crate) fn ensure_font() {
    FONT.get_or_init(|| {
        plotters::style::register_font("sans-serif", FontStyle::Normal, include_bytes!("../assets/DejaVuSans.ttf"))
            .is_ok()
    });
}

fn plot_err<E: std::fmt::Debug>(path: &Path) -> impl Fn(E) -> anyhow::Error + '_ {
    move |e| anyhow!("drawing {}: {e:?}", path.display())
}

/// Draws a `w x h` chart on white through `draw` and writes it to `path` as PNG, whole or not at
/// all ([`crate::images::write_png`]).
fn chart_png(
    path: &Path,
    (w, h): (u32, u32),
    draw: impl FnOnce(&DrawingArea<BitMapBackend<'_>, plotters::coord::Shift>) -> Result<()>,
) -> Result<()> {
    ensure_font();
    let err = plot_err(path);
    let mut pixels = vec![0u8; w as usize * h as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut pixels, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(&err)?;
        draw(&root)?;
        root.present().map_err(&err)?;
    }
    crate::images::write_png(path, w, h, &pixels)
}

/// The legend of every chart with several series: lower right, on a white box with a black border.
fn legend_lower_right<'a, DB: DrawingBackend + 'a, CT: plotters::coord::CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
    path: &Path,
) -> Result<()> {
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::LowerRight)
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK)
        .draw()
        .map_err(plot_err(path))
}

/// Curves against the step, one per named series (a legend when there is more than one).
fn line_chart(
    path: &Path,
    title: &str,
    y_label: &str,
    series: &[(String, Vec<(f64, f64)>)],
    log_y: bool,
) -> Result<()> {
    let err = plot_err(path);
    chart_png(path, (800, 480), |root| {
        let all = || series.iter().flat_map(|(_, p)| p.iter());
        let (x0, x1) = all().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| (a.min(p.0), b.max(p.0)));
        let (x0, x1) = if x0.is_finite() { (x0, x1.max(x0 + 1.0)) } else { (0.0, 1.0) };
        let ys = all().map(|p| p.1).filter(|y| y.is_finite() && (!log_y || *y > 0.0));
        let (lo, hi) = ys.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), y| (a.min(y), b.max(y)));
        let (lo, hi) = if lo.is_finite() { (lo, hi.max(lo * 1.0001 + 1e-12)) } else { (0.1, 1.0) };
        let mut chart = ChartBuilder::on(root);
        chart.caption(title, ("sans-serif", 22)).margin(12).x_label_area_size(40).y_label_area_size(70);
        let points = |p: &[(f64, f64)]| -> Vec<(f64, f64)> {
            p.iter().copied().filter(|p| p.1.is_finite() && (!log_y || p.1 > 0.0)).collect()
        };
        let palette = [RED, BLUE, GREEN, MAGENTA, CYAN, BLACK];
        let step_label = |x: &f64| format!("{}", x.round() as i64);
        macro_rules! draw {
            ($c:expr) => {{
                for (i, (name, p)) in series.iter().enumerate() {
                    let colour = palette[i % palette.len()];
                    let s = $c.draw_series(LineSeries::new(points(p), colour.stroke_width(2))).map_err(&err)?;
                    if series.len() > 1 {
                        s.label(name.as_str())
                            .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], colour.stroke_width(2)));
                    }
                }
                if series.len() > 1 {
                    legend_lower_right(&mut $c, path)?;
                }
            }};
        }
        if log_y {
            let mut c = chart.build_cartesian_2d(x0..x1, (lo..hi).log_scale()).map_err(&err)?;
            c.configure_mesh()
                .x_desc("step")
                .y_desc(y_label)
                .x_labels(8)
                .x_label_formatter(&step_label)
                .y_labels(8)
                .y_label_formatter(&|y| format!("{y:.1e}"))
                .draw()
                .map_err(&err)?;
            draw!(c);
        } else {
            let pad = 0.05 * (hi - lo);
            let mut c = chart.build_cartesian_2d(x0..x1, (lo - pad)..(hi + pad)).map_err(&err)?;
            c.configure_mesh()
                .x_desc("step")
                .y_desc(y_label)
                .x_labels(8)
                .x_label_formatter(&step_label)
                .y_label_formatter(&|y| format!("{y:.1}"))
                .draw()
                .map_err(&err)?;
            draw!(c);
        }
        Ok(())
    })
}

/// `loss.png` and `psnr.png` in `out` from a run's `metrics.csv`: the training loss, and the
/// training PSNR with, where the run validated (`val_psnr`), the test PSNR of every scale.
///
/// # Errors
/// An unreadable CSV or unwritable PNGs.
pub fn training_curves(csv: &Path, out: &Path) -> Result<()> {
    let text = mipnerf_core::io::read_regular_text(csv, mipnerf_core::io::cap::JSON)
        .with_context(|| format!("reading {}", csv.display()))?;
    let m = crate::metrics_csv::MetricsRows::parse(&text);
    let col = |f: fn(&crate::metrics_csv::TrainRow) -> f64| -> Vec<(f64, f64)> {
        m.train.iter().map(|r| (r.step as f64, f(r))).collect()
    };
    let loss = [("training loss".to_string(), col(|r| r.loss))];
    line_chart(&out.join("loss.png"), "Training loss (coarse x 0.1 + fine, per-channel MSE)", "loss", &loss, true)?;
    let mut psnr = vec![("training (fine level, batch)".to_string(), col(|r| r.psnr))];
    let scales = m.scales();
    for j in 0..scales {
        let name =
            if j == 0 { "test, full resolution".to_string() } else { format!("test, 1/{} resolution", 1u64 << j) };
        psnr.push((name, m.val.iter().filter_map(|(s, v)| Some((*s as f64, *v.get(j)?))).collect()));
    }
    let title = if scales > 0 { "PSNR: training batch and test images" } else { "Training PSNR (fine level, batch)" };
    line_chart(&out.join("psnr.png"), title, "PSNR (dB)", &psnr, false)?;
    Ok(())
}

/// A bar chart of PSNR per image, coloured by scale.
///
/// # Errors
/// Unwritable PNG.
pub fn psnr_bars(path: &Path, bars: &[(String, u32, f64)]) -> Result<()> {
    let err = plot_err(path);
    let width = (60 + 18 * bars.len()).clamp(640, 4000) as u32;
    chart_png(path, (width, 480), |root| {
        let hi = bars.iter().map(|b| b.2).filter(|v| v.is_finite()).fold(10.0, f64::max) * 1.1;
        let mut chart = ChartBuilder::on(root)
            .caption("PSNR per test image", ("sans-serif", 22))
            .margin(12)
            .x_label_area_size(30)
            .y_label_area_size(60)
            .build_cartesian_2d(0.0..bars.len() as f64, 0.0..hi)
            .map_err(&err)?;
        chart.configure_mesh().disable_x_mesh().x_desc("image").y_desc("PSNR (dB)").draw().map_err(&err)?;
        let palette = [BLUE, RED, GREEN, MAGENTA, CYAN];
        let mut scales: Vec<u32> = bars.iter().map(|b| b.1).collect();
        scales.sort_unstable();
        scales.dedup();
        // One series per scale, so that the legend names each colour.
        for scale in scales {
            let c = palette[scale as usize % palette.len()];
            let name = if scale == 0 {
                "full resolution".to_string()
            } else {
                format!("1/{} resolution", 1u64 << scale.min(63))
            };
            chart
                .draw_series(bars.iter().enumerate().filter(|(_, b)| b.1 == scale).map(|(i, (_, _, v))| {
                    Rectangle::new([(i as f64 + 0.1, 0.0), (i as f64 + 0.9, v.max(0.0))], c.filled())
                }))
                .map_err(&err)?
                .label(name)
                .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 12, y + 5)], c.filled()));
        }
        legend_lower_right(&mut chart, path)?;
        Ok(())
    })
}

/// The caption of [`quality_vs_time`]'s chart: what its mean is over (`scales` test scales).
fn quality_vs_time_caption(scales: usize) -> String {
    match scales {
        1 => "Mean test PSNR against training time".to_owned(),
        n => format!("Mean test PSNR over the {n} scales against training time"),
    }
}

/// Mean test PSNR (over `scales` test scales) against minutes of training, one curve per run
/// (points marked), with a dashed horizontal reference line. The machine is the table's to name:
/// the axis says only minutes.
///
/// # Errors
/// Unwritable PNG.
pub fn quality_vs_time(
    path: &Path,
    curves: &[(String, Vec<(f64, f64)>)],
    scales: usize,
    reference: Option<(f64, &str)>,
) -> Result<()> {
    let err = plot_err(path);
    chart_png(path, (900, 540), |root| {
        let all = curves.iter().flat_map(|c| c.1.iter().copied()).filter(|p| p.0.is_finite() && p.1.is_finite());
        let (x1, lo, hi) =
            all.fold((1.0f64, f64::INFINITY, f64::NEG_INFINITY), |(x, a, b), p| (x.max(p.0), a.min(p.1), b.max(p.1)));
        let (lo, hi) = if lo.is_finite() { (lo.floor() - 1.0, hi.ceil() + 1.0) } else { (0.0, 1.0) };
        let mut c = ChartBuilder::on(root)
            .caption(quality_vs_time_caption(scales), ("sans-serif", 22))
            .margin(14)
            .x_label_area_size(44)
            .y_label_area_size(60)
            .build_cartesian_2d(0.0..x1 * 1.04, lo..hi)
            .map_err(&err)?;
        c.configure_mesh().x_desc("minutes of training").y_desc("mean PSNR (dB)").draw().map_err(&err)?;
        let colours = [RED, BLUE, GREEN, MAGENTA, CYAN];
        for (k, (label, pts)) in curves.iter().enumerate() {
            let col = colours[k % colours.len()];
            c.draw_series(LineSeries::new(pts.iter().copied(), col.stroke_width(2)))
                .map_err(&err)?
                .label(label.as_str())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], col.stroke_width(2)));
            c.draw_series(pts.iter().map(|&p| Circle::new(p, 4, col.filled()))).map_err(&err)?;
        }
        if let Some((y, label)) = reference {
            let dashes = (0..60).map(|i| {
                let (a, b) = (x1 * 1.04 * f64::from(i) / 60.0, x1 * 1.04 * (f64::from(i) + 0.5) / 60.0);
                PathElement::new(vec![(a, y), (b, y)], BLACK.stroke_width(1))
            });
            c.draw_series(dashes)
                .map_err(&err)?
                .label(label)
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], BLACK));
        }
        legend_lower_right(&mut c, path)?;
        Ok(())
    })
}

/// A colour bar for a colour map: `ticks` labels from `lo` (bottom) to `hi` (top), with a title,
/// as a small PNG beside the images it explains.
///
/// # Errors
/// Unwritable PNG.
pub fn colour_bar(path: &Path, title: &str, lo: f64, hi: f64, map: impl Fn(f32) -> [u8; 3]) -> Result<()> {
    let err = plot_err(path);
    let (w, h) = (220u32, 320u32);
    chart_png(path, (w, h), |root| {
        root.draw(&Text::new(title.to_string(), (10, 8), ("sans-serif", 15).into_font())).map_err(&err)?;
        let (top, bottom, x0, x1) = (36i32, h as i32 - 16, 14i32, 44i32);
        for y in top..bottom {
            let t = (bottom - 1 - y) as f32 / (bottom - top - 1).max(1) as f32;
            let [r, g, b] = map(t);
            root.draw(&PathElement::new(vec![(x0, y), (x1, y)], RGBColor(r, g, b))).map_err(&err)?;
        }
        for k in 0..=4 {
            let t = f64::from(k) / 4.0;
            let y = bottom - 1 - (t * f64::from(bottom - top - 1)).round() as i32;
            root.draw(&PathElement::new(vec![(x1, y), (x1 + 6, y)], BLACK)).map_err(&err)?;
            let v = lo + t * (hi - lo);
            root.draw(&Text::new(format!("{v:.3}"), (x1 + 10, y - 7), ("sans-serif", 14).into_font())).map_err(&err)?;
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::quality_vs_time_caption;

    /// A single-scale experiment (fern, the 360 captures) must not be captioned as the
    /// multiscale table's mean over 4 scales, as every chart once was.
    #[test]
    fn the_time_chart_names_the_scales_its_mean_is_over() {
        assert_eq!(quality_vs_time_caption(1), "Mean test PSNR against training time");
        assert_eq!(quality_vs_time_caption(4), "Mean test PSNR over the 4 scales against training time");
    }
}
