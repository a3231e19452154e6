//! Line charts with plotters, written as SVG and PNG. The PNG text uses a bundled font
//! (DejaVu Sans, see `supervisor/plot/assets/DejaVuSans.LICENSE`), so it renders on machines without
//! fonts.
//!
//! Plain-data calls (series of points, histograms, timeline bins) and nothing of a run: the
//! report, the timing and the studies draw their figures with it.

use anyhow::{Context, Result, anyhow};
use deltaloop_config::Law;
use plotters::coord::Shift;
pub use plotters::prelude::RGBColor;
use plotters::prelude::*;
use std::path::Path;
use std::sync::Once;

mod canvas;
mod latency;
use canvas::Canvas;
pub mod lanes;
pub mod timeline;
pub use latency::{
    TimeBin, latency_percentiles, latency_percentiles_colored, quantity_color, timeline, with_ext,
};

static FONT: Once = Once::new();

fn register_font() {
    FONT.call_once(|| {
        let bytes: &'static [u8] = include_bytes!("../assets/DejaVuSans.ttf");
        // The bundled font is valid; if registration ever failed, plotters would report it when drawing.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, bytes);
    });
}

/// One colour per law, the same in every figure.
pub fn law_color(law: Law) -> RGBColor {
    match law {
        Law::Tdc => RGBColor(31, 119, 180),
        Law::TdeIs => RGBColor(255, 127, 14),
        Law::TdcIsSta => RGBColor(44, 160, 44),
        Law::TdcIsIsta => RGBColor(148, 103, 189),
        Law::Pid => RGBColor(214, 39, 40),
    }
}

/// A lighter tone of `c` (halfway to white), for a second series of the same law.
pub fn lighter(c: RGBColor) -> RGBColor {
    let up = |x: u8| x + (255 - x) / 2;
    RGBColor(up(c.0), up(c.1), up(c.2))
}

/// A series: its legend name, colour, and (x, y) points.
pub struct Series {
    pub name: String,
    pub color: RGBColor,
    pub points: Vec<(f64, f64)>,
    /// Error bars (x, low, high): a confidence interval at each point, drawn as a vertical bar
    /// with caps. Empty: none.
    pub bars: Vec<(f64, f64, f64)>,
    /// Drawn dashed: the second variant of a law (e.g. compensated), beside its solid line.
    pub dashed: bool,
}

/// One panel of a figure.
pub struct Panel {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub log_x: bool,
    pub log_y: bool,
    pub series: Vec<Series>,
}

fn range(values: impl Iterator<Item = f64>, log: bool) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.filter(|v| v.is_finite() && (!log || *v > 0.0)) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return if log { (0.1, 1.0) } else { (0.0, 1.0) };
    }
    if log {
        let (lo, hi) = (lo / 1.5, hi * 1.5);
        // Within one decade a log axis would carry one label or none: widen it to the decades
        // around the data, so at least two decade ticks are labelled.
        if hi / lo < 10.0 {
            let below = 10f64.powf(lo.log10().floor());
            (below, (10f64.powf(hi.log10().ceil())).max(below * 10.0))
        } else {
            (lo, hi)
        }
    } else {
        let pad = ((hi - lo) * 0.05).max(1e-12);
        (lo - pad, hi + pad)
    }
}

/// Tick labels: plain for moderate magnitudes, 1e3-style otherwise.
fn compact(v: f64) -> String {
    let a = v.abs();
    if a < 1e-12 {
        "0".into()
    } else if (0.01..10_000.0).contains(&a) {
        let s = format!("{v:.3}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        format!("{v:.0e}")
    }
}

fn e<E: std::fmt::Debug>(err: E) -> anyhow::Error {
    anyhow!("plot: {err:?}")
}

macro_rules! draw_panel {
    ($area:expr, $p:expr, $xr:expr, $yr:expr, $y_floor:expr) => {{
        let mut chart = ChartBuilder::on($area)
            .caption(&$p.title, ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(45)
            .y_label_area_size(75)
            .build_cartesian_2d($xr, $yr)
            .map_err(e)?;
        chart
            .configure_mesh()
            .light_line_style(TRANSPARENT)
            .bold_line_style(RGBColor(225, 225, 225))
            .x_labels(8)
            .y_labels(7)
            .x_label_formatter(&|v| compact(*v))
            .y_label_formatter(&|v| compact(*v))
            .x_desc($p.x_label.as_str())
            .y_desc($p.y_label.as_str())
            .label_style(("sans-serif", 14))
            .axis_desc_style(("sans-serif", 15))
            .draw()
            .map_err(e)?;
        for s in &$p.series {
            let color = s.color;
            let pts: Vec<(f64, f64)> = s
                .points
                .iter()
                .copied()
                .filter(|(x, y)| {
                    x.is_finite()
                        && y.is_finite()
                        && (!$p.log_y || *y > 0.0)
                        && (!$p.log_x || *x > 0.0)
                })
                .collect();
            let style = color.stroke_width(2);
            let drawn = if s.dashed {
                chart.draw_series(DashedLineSeries::new(pts.clone(), 6, 4, style))
            } else {
                chart.draw_series(LineSeries::new(pts.clone(), style))
            };
            let dashed = s.dashed;
            drawn
                .map_err(e)?
                .label(s.name.as_str())
                .legend(move |(x, y)| {
                    // Two strokes with a gap for a dashed series, one for a solid one.
                    let (a, b) = if dashed { (8, 12) } else { (20, 20) };
                    EmptyElement::at((x, y))
                        + PathElement::new(vec![(0, 0), (a, 0)], style)
                        + PathElement::new(vec![(b, 0), (20, 0)], style)
                });
            let bars: Vec<(f64, f64, f64)> = s
                .bars
                .iter()
                .copied()
                // On a log axis a bar whose low end is at or below 0 runs to the axis floor
                // (dropping it would make the least certain points look the most certain).
                .map(|(x, lo, hi)| (x, if $p.log_y && lo <= 0.0 { $y_floor } else { lo }, hi))
                .filter(|(x, lo, hi)| {
                    x.is_finite()
                        && lo.is_finite()
                        && hi.is_finite()
                        && (!$p.log_y || *hi > 0.0)
                        && (!$p.log_x || *x > 0.0)
                })
                .collect();
            if !bars.is_empty() {
                chart
                    .draw_series(bars.iter().map(|&(x, lo, hi)| {
                        ErrorBar::new_vertical(x, lo, (lo + hi) / 2.0, hi, color.stroke_width(1), 8)
                    }))
                    .map_err(e)?;
            }
            // Markers only where they help: sparse series (sweeps), not dense time series.
            if pts.len() <= 60 {
                chart
                    .draw_series(pts.iter().map(|&p| Circle::new(p, 3, color.filled())))
                    .map_err(e)?;
            }
        }
        chart
            .configure_series_labels()
            .label_font(("sans-serif", 14))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .position(SeriesLabelPosition::UpperLeft)
            .draw()
            .map_err(e)?;
    }};
}

fn draw<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    title: &str,
    panels: &[Panel],
    cols: usize,
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(e)?;
    let root = root.titled(title, ("sans-serif", 24)).map_err(e)?;
    let rows = panels.len().div_ceil(cols.max(1));
    let areas = root.split_evenly((rows, cols.max(1)));
    for (area, p) in areas.iter().zip(panels) {
        let (x0, x1) = range(
            p.series.iter().flat_map(|s| s.points.iter().map(|q| q.0)),
            p.log_x,
        );
        let (y0, y1) = range(
            p.series.iter().flat_map(|s| {
                let bars = s.bars.iter().flat_map(|b| [b.1, b.2]);
                s.points.iter().map(|q| q.1).chain(bars)
            }),
            p.log_y,
        );
        match (p.log_x, p.log_y) {
            (true, true) => draw_panel!(area, p, (x0..x1).log_scale(), (y0..y1).log_scale(), y0),
            (true, false) => draw_panel!(area, p, (x0..x1).log_scale(), y0..y1, y0),
            (false, true) => draw_panel!(area, p, x0..x1, (y0..y1).log_scale(), y0),
            (false, false) => draw_panel!(area, p, x0..x1, y0..y1, y0),
        }
    }
    root.present().map_err(e)?;
    Ok(())
}

/// Draws with `draw` into an RGB buffer of `size` (pixels) and writes it to `path` as a PNG:
/// plotters' bitmap backend draws, the `png` crate encodes.
fn png(
    path: &Path,
    size: (u32, u32),
    draw: impl for<'a> FnOnce(DrawingArea<Canvas<'a>, Shift>) -> Result<()>,
) -> Result<()> {
    let mut buf = vec![0u8; size.0 as usize * size.1 as usize * 3];
    draw(Canvas::Bitmap(BitMapBackend::with_buffer(&mut buf, size)).into_drawing_area())?;
    let named = || format!("cannot write {}", path.display());
    let file = std::fs::File::create(path).with_context(named)?;
    let mut enc = ::png::Encoder::new(std::io::BufWriter::new(file), size.0, size.1);
    enc.set_color(::png::ColorType::Rgb);
    enc.set_depth(::png::BitDepth::Eight);
    enc.write_header()
        .and_then(|mut w| w.write_image_data(&buf))
        .with_context(named)
}

/// Writes `<stem>.svg` and `<stem>.png` with the panels in a grid of `cols` columns.
pub fn figure(stem: &Path, title: &str, panels: &[Panel], cols: usize) -> Result<()> {
    register_font();
    let rows = panels.len().div_ceil(cols.max(1)) as u32;
    let size = (620 * cols as u32, 440 * rows + 40);
    draw(
        Canvas::Svg(SVGBackend::new(&stem.with_extension("svg"), size)).into_drawing_area(),
        title,
        panels,
        cols,
    )?;
    png(&stem.with_extension("png"), size, |area| {
        draw(area, title, panels, cols)
    })?;
    Ok(())
}

/// A 3-D polyline: legend name, colour, (x, y, z) points in m, z up.
pub struct Series3 {
    pub name: String,
    pub color: RGBColor,
    pub points: Vec<(f64, f64, f64)>,
    /// Draw thicker (the reference) or thinner.
    pub width: u32,
}

fn draw3<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    title: &str,
    series: &[Series3],
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(e)?;
    let all = || series.iter().flat_map(|s| s.points.iter());
    let (x0, x1) = range(all().map(|p| p.0), false);
    let (y0, y1) = range(all().map(|p| p.1), false);
    let (z0, z1) = range(all().map(|p| p.2), false);
    // plotters' 3-D axes are (x, up, depth): map (x, y, z) → (x, z, y).
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 22))
        .margin(20)
        .build_cartesian_3d(x0..x1, z0..z1, y0..y1)
        .map_err(e)?;
    chart.with_projection(|mut p| {
        p.pitch = 0.35;
        p.yaw = 0.6;
        p.scale = 0.85;
        p.into_matrix()
    });
    chart
        .configure_axes()
        .label_style(("sans-serif", 13))
        .x_formatter(&|v| format!("x {}", compact(*v)))
        .y_formatter(&|v| format!("z {}", compact(*v)))
        .z_formatter(&|v| format!("y {}", compact(*v)))
        .draw()
        .map_err(e)?;
    for s in series {
        let color = s.color;
        let width = s.width;
        chart
            .draw_series(LineSeries::new(
                s.points.iter().map(|&(x, y, z)| (x, z, y)),
                color.stroke_width(width),
            ))
            .map_err(e)?
            .label(s.name.as_str())
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(width))
            });
    }
    chart
        .configure_series_labels()
        .label_font(("sans-serif", 15))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(e)?;
    root.present().map_err(e)?;
    Ok(())
}

/// Writes `<stem>.svg` and `<stem>.png` of a 3-D path plot (task space, m).
pub fn figure3(stem: &Path, title: &str, series: &[Series3]) -> Result<()> {
    register_font();
    let size = (900, 720);
    draw3(
        Canvas::Svg(SVGBackend::new(&stem.with_extension("svg"), size)).into_drawing_area(),
        title,
        series,
    )?;
    png(&stem.with_extension("png"), size, |area| {
        draw3(area, title, series)
    })?;
    Ok(())
}
