//! Loop-timing figures: latency by percentile in the HdrHistogram style, and latency over run
//! time. Both are drawn from what the run kept in fixed memory (histograms, a binned timeline).

use super::{compact, e, register_font};
use crate::timeline::{Bin, Stat};
use anyhow::Result;
use hdrhistogram::Histogram;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::{Path, PathBuf};

/// Deepest percentile drawn: 99.999 %, i.e. 1/(1 − p) = 10⁵.
const MAX_NINES: f64 = 5.0;

const RED: RGBColor = RGBColor(214, 39, 40);

/// The colour of a timing quantity, by its `.hgrm` name (the same in every figure).
pub fn quantity_color(name: &str) -> RGBColor {
    match name {
        "round_trip" => RGBColor(31, 119, 180),
        "wake_lateness" => RGBColor(255, 127, 14),
        "state_to_controller" => RGBColor(44, 160, 44),
        "controller_compute" => RGBColor(148, 103, 189),
        "period_jitter" => RGBColor(140, 86, 75),
        _ => RGBColor(90, 90, 90),
    }
}

/// Other lines get these, in turn.
pub(crate) const PALETTE: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
];

/// The percentile axis label at n nines (x = log10(1/(1 − p)) = n).
fn nines_label(x: f64) -> String {
    let n = x.round();
    if (x - n).abs() > 1e-6 || !(0.0..=MAX_NINES).contains(&n) {
        return String::new();
    }
    match n as u32 {
        0 => "0%".into(),
        1 => "90%".into(),
        n => format!("{:.*}%", n as usize - 2, 100.0 - 10f64.powi(2 - n as i32)),
    }
}

/// How a legend entry is drawn.
#[derive(Clone, Copy)]
enum Mark {
    Line(RGBColor),
    Dashed(RGBColor),
    Band(RGBColor),
    Triangle(RGBColor),
}

/// Legend row height, px.
const ROW: i32 = 24;

/// A legend outside the plot (so it hides no data): `entries` in a grid of `cols` columns.
fn draw_legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    entries: &[(Mark, String)],
    cols: usize,
    left: i32,
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    let cols = cols.max(1);
    let width = (area.dim_in_pixel().0 as i32 - left) / cols as i32;
    for (i, (mark, text)) in entries.iter().enumerate() {
        let x = left + (i % cols) as i32 * width;
        let y = (i / cols) as i32 * ROW + ROW / 2;
        match *mark {
            Mark::Line(c) => area.draw(&PathElement::new(
                vec![(x, y), (x + 26, y)],
                c.stroke_width(3),
            )),
            Mark::Dashed(c) => {
                area.draw(&PathElement::new(
                    vec![(x, y), (x + 10, y)],
                    c.stroke_width(3),
                ))?;
                area.draw(&PathElement::new(
                    vec![(x + 16, y), (x + 26, y)],
                    c.stroke_width(3),
                ))
            }
            Mark::Band(c) => area.draw(&Rectangle::new([(x, y - 6), (x + 26, y + 6)], c.filled())),
            Mark::Triangle(c) => area.draw(&TriangleMarker::new((x + 13, y), 7, c.filled())),
        }
        .map_err(e)?;
        area.draw(&Text::new(
            text.clone(),
            (x + 34, y - 9),
            ("sans-serif", 15).into_font(),
        ))
        .map_err(e)?;
    }
    Ok(())
}

/// One line of a percentile plot: legend text, colour, (nines, µs) points.
struct Line {
    name: String,
    color: RGBColor,
    points: Vec<(f64, f64)>,
}

/// The percentile curve of `h` (ns) as (log10(1/(1 − p)), µs), up to 99.999 % or as deep as
/// the count resolves (1/(1 − p) ≤ count), where it rises to the max (as the HdrHistogram
/// plotter's last, infinite, point does).
fn percentile_curve(h: &Histogram<u64>) -> Vec<(f64, f64)> {
    let deepest = (h.len() as f64).log10().min(MAX_NINES);
    let steps = (deepest * 100.0).ceil() as usize;
    let xs: Vec<f64> = (0..=steps)
        .map(|i| (i as f64 / 100.0).min(deepest))
        .collect();
    // The quantiles rise with x: one pass over the counts for all of them (one scan each was
    // most of a short run's figure time).
    let values = h.value_at_quantiles(xs.iter().map(|x| 1.0 - 10f64.powf(-x)));
    let mut curve: Vec<(f64, f64)> = xs
        .iter()
        .zip(values)
        .map(|(&x, v)| (x, v as f64 / 1e3))
        .collect();
    curve.push((deepest, h.max() as f64 / 1e3));
    curve
}

/// Labels of a log axis: plotters puts a key point at every 1..9 × 10ⁿ when the range spans
/// less than two decades; only 1, 2 and 5 × 10ⁿ get a label, so they never crowd.
fn log_label(v: f64) -> String {
    if v <= 0.0 {
        return String::new();
    }
    let m = v / 10f64.powf(v.log10().floor());
    if [1.0, 2.0, 5.0, 10.0]
        .iter()
        .any(|k| (m - k).abs() < 1e-6 * k)
    {
        if v >= 10_000.0 {
            format!("{v:.0}")
        } else {
            compact(v)
        }
    } else {
        String::new()
    }
}

/// A latency in µs to three significant digits or whole µs.
fn us_text(v: f64) -> String {
    match v.abs() {
        a if a < 10.0 => format!("{v:.2}"),
        a if a < 100.0 => format!("{v:.1}"),
        _ => format!("{v:.0}"),
    }
}

fn log_range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = values
        .filter(|v| v.is_finite() && *v > 0.0)
        .fold((f64::INFINITY, 0.0f64), |(l, h), v| (l.min(v), h.max(v)));
    if !lo.is_finite() {
        return (0.1, 10.0);
    }
    (lo / 1.6, hi * 1.6)
}

fn draw_percentiles<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    title: &str,
    lines: &[Line],
    budget_us: Option<f64>,
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(e)?;
    let mut legend: Vec<(Mark, String)> = lines
        .iter()
        .map(|l| (Mark::Line(l.color), l.name.clone()))
        .collect();
    if let Some(b) = budget_us {
        legend.push((
            Mark::Dashed(RED),
            format!("torque budget {} µs", us_text(b)),
        ));
    }
    let rows = legend.len().div_ceil(2) as u32;
    let h = root.dim_in_pixel().1;
    let (root, strip) = root.split_vertically(h - rows * ROW as u32 - 10);
    draw_legend(&strip, &legend, 2, 86)?;
    let (y0, y1) = log_range(
        lines
            .iter()
            .flat_map(|l| l.points.iter().map(|p| p.1))
            .chain(budget_us),
    );
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 20))
        .margin(16)
        .margin_right(40)
        .x_label_area_size(50)
        .y_label_area_size(70)
        .build_cartesian_2d(0.0..MAX_NINES, (y0..y1).log_scale())
        .map_err(e)?;
    chart
        .configure_mesh()
        .light_line_style(TRANSPARENT)
        .bold_line_style(RGBColor(225, 225, 225))
        .x_labels(6)
        .y_labels(20)
        .x_label_formatter(&|v| nines_label(*v))
        .y_label_formatter(&|v| log_label(*v))
        .x_desc("percentile (log scale of 1/(1 − p))")
        .y_desc("latency (µs, log scale)")
        .label_style(("sans-serif", 15))
        .axis_desc_style(("sans-serif", 16))
        .draw()
        .map_err(e)?;
    for l in lines {
        chart
            .draw_series(LineSeries::new(l.points.clone(), l.color.stroke_width(2)))
            .map_err(e)?;
    }
    if let Some(b) = budget_us {
        chart
            .draw_series(DashedLineSeries::new(
                [(0.0, b), (MAX_NINES, b)],
                8,
                5,
                RED.stroke_width(2),
            ))
            .map_err(e)?;
    }
    root.present().map_err(e)?;
    Ok(())
}

/// `<stem>.<ext>` (a stem may hold dots: `tdc.latency`).
pub fn with_ext(stem: &Path, ext: &str) -> PathBuf {
    let mut s = stem.as_os_str().to_owned();
    s.push(".");
    s.push(ext);
    s.into()
}

/// Draws with `$draw(root)` into `<stem>.svg` and `<stem>.png`.
macro_rules! write_both {
    ($stem:expr, $size:expr, $draw:expr) => {{
        register_font();
        $draw(
            super::Canvas::Svg(SVGBackend::new(&with_ext($stem, "svg"), $size)).into_drawing_area(),
        )?;
        super::png(&with_ext($stem, "png"), $size, |area| $draw(area))?;
        Ok(())
    }};
}

/// Writes `<stem>.svg` and `<stem>.png`: latency by percentile in the HdrHistogram style, one
/// line per `(legend name, histogram of ns)` (empty histograms are left out), x the percentile on
/// a log 1/(1 − p) axis from 0 % to 99.999 % (a line stops where its count stops resolving: at
/// 1/(1 − p) = count), y µs on a log axis, `budget_us` (µs) as a dashed line. The legend gives
/// each line's p50, p99.9 and max.
///
/// This is the call for any set of latency histograms (e.g. `bench loop`'s own loops):
/// `plot::latency_percentiles(&dir.join("machine.latency"), "title", &[("sleep-only wake", &h)], None)`.
pub fn latency_percentiles(
    stem: &Path,
    title: &str,
    hists: &[(&str, &Histogram<u64>)],
    budget_us: Option<f64>,
) -> Result<()> {
    latency_percentiles_colored(stem, title, hists, &PALETTE, budget_us)
}

/// [`latency_percentiles`] with line i in `colors[i % len]`.
pub fn latency_percentiles_colored(
    stem: &Path,
    title: &str,
    hists: &[(&str, &Histogram<u64>)],
    colors: &[RGBColor],
    budget_us: Option<f64>,
) -> Result<()> {
    let lines: Vec<Line> = hists
        .iter()
        .enumerate()
        .filter(|(_, (_, h))| !h.is_empty())
        .map(|(i, (name, h))| {
            let q = |p: f64| us_text(h.value_at_quantile(p) as f64 / 1e3);
            Line {
                name: format!(
                    "{name}: p50 {}, p99.9 {}, max {} µs",
                    q(0.5),
                    q(0.999),
                    us_text(h.max() as f64 / 1e3)
                ),
                color: colors[i % colors.len().max(1)],
                points: percentile_curve(h),
            }
        })
        .collect();
    write_both!(stem, (1000, 680), |root| draw_percentiles(
        root, title, &lines, budget_us
    ))
}

/// One panel of the timeline: a quantity's per-bin min–max band and mean, in µs.
struct Track<'a> {
    label: &'a str,
    color: RGBColor,
    stat: fn(&Bin) -> &Stat,
    /// Draw the budget line and the misses on this panel.
    budget_us: Option<f64>,
    misses: bool,
}

/// One bin of a timeline: its start and end (s of run time) and what it holds.
pub type TimeBin<'a> = (f64, f64, &'a Bin);

fn draw_timeline<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    title: &str,
    bins: &[TimeBin],
    tracks: &[Track],
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(e)?;
    let root = root.titled(title, ("sans-serif", 20)).map_err(e)?;
    let areas = root.split_evenly((tracks.len().max(1), 1));
    let misses: u64 = bins.iter().map(|b| b.2.misses).sum();
    for (area, t) in areas.iter().zip(tracks) {
        let legend = track_legend(t, bins, misses);
        let (strip, area) = area.split_vertically(ROW as u32 + 4);
        draw_legend(&strip, &legend, legend.len(), 86)?;
        draw_track(&area, t, bins, misses)?;
    }
    root.present().map_err(e)?;
    Ok(())
}

/// The legend of one panel: the band and the mean of its statistic, the budget, the misses.
fn track_legend(t: &Track, bins: &[TimeBin], misses: u64) -> Vec<(Mark, String)> {
    let bin_ms = bins.first().map_or(0.0, |b| (b.1 - b.0) * 1e3);
    let mut legend = vec![
        (
            Mark::Band(super::lighter(t.color)),
            format!("{}: min–max per {} ms", t.label, compact(bin_ms)),
        ),
        (Mark::Line(t.color), format!("{}: mean", t.label)),
    ];
    if let Some(b) = t.budget_us {
        legend.push((
            Mark::Dashed(RED),
            format!("torque budget {} µs", us_text(b)),
        ));
    }
    if t.misses {
        legend.push((
            Mark::Triangle(RED),
            format!("deadline miss ({misses} in all)"),
        ));
    }
    legend
}

/// One panel: per bin the min–max band and the mean of the track's statistic (µs, log scale),
/// the budget as a dashed line, the bins with misses as red triangles above the data.
fn draw_track<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    t: &Track,
    bins: &[TimeBin],
    misses: u64,
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    let us = |v: u64| v as f64 / 1e3;
    let x1 = bins.last().map_or(1.0, |b| b.1);
    let light = super::lighter(t.color);
    let (y0, mut y1) = log_range(
        bins.iter()
            .filter(|b| (t.stat)(b.2).n > 0)
            .flat_map(|b| [us((t.stat)(b.2).min.max(1)), us((t.stat)(b.2).max)])
            .chain(t.budget_us),
    );
    if t.misses && misses > 0 {
        // Room above the data for the miss markers.
        y1 *= 2.5;
    }
    let mut chart = ChartBuilder::on(area)
        .margin(12)
        .margin_right(30)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d(0.0..x1, (y0..y1).log_scale())
        .map_err(e)?;
    chart
        .configure_mesh()
        .light_line_style(TRANSPARENT)
        .bold_line_style(RGBColor(225, 225, 225))
        .x_labels(10)
        .y_labels(20)
        .x_label_formatter(&|v| compact(*v))
        .y_label_formatter(&|v| log_label(*v))
        .x_desc("run time k·Ts (s)")
        .y_desc(format!("{} (µs, log scale)", t.label))
        .label_style(("sans-serif", 14))
        .axis_desc_style(("sans-serif", 15))
        .draw()
        .map_err(e)?;
    chart
        .draw_series(bins.iter().filter(|b| (t.stat)(b.2).n > 0).map(|b| {
            let s = (t.stat)(b.2);
            Rectangle::new(
                [(b.0, us(s.min.max(1))), (b.1, us(s.max.max(1)))],
                light.filled(),
            )
        }))
        .map_err(e)?;
    chart
        .draw_series(LineSeries::new(
            bins.iter()
                .filter_map(|b| Some(((b.0 + b.1) / 2.0, (t.stat)(b.2).mean()? / 1e3))),
            t.color.stroke_width(1),
        ))
        .map_err(e)?;
    if let Some(b) = t.budget_us {
        chart
            .draw_series(DashedLineSeries::new(
                [(0.0, b), (x1, b)],
                8,
                5,
                RED.stroke_width(2),
            ))
            .map_err(e)?;
    }
    if t.misses && misses > 0 {
        let at = y1 / 1.6;
        chart
            .draw_series(
                bins.iter()
                    .filter(|b| b.2.misses > 0)
                    .map(|b| TriangleMarker::new(((b.0 + b.1) / 2.0, at), 6, RED.filled())),
            )
            .map_err(e)?;
    }
    Ok(())
}

/// Writes `<stem>.svg` and `<stem>.png`: round trip (and, in realtime, wake lateness) over run
/// time from a run's bins, misses as red triangles, `budget_us` as a dashed line.
pub fn timeline(
    stem: &Path,
    title: &str,
    bins: &[TimeBin],
    realtime: bool,
    budget_us: Option<f64>,
) -> Result<()> {
    let mut tracks = vec![Track {
        label: "round trip",
        color: quantity_color("round_trip"),
        stat: |b| &b.round_trip,
        budget_us,
        misses: realtime,
    }];
    if realtime {
        tracks.push(Track {
            label: "wake lateness",
            color: quantity_color("wake_lateness"),
            stat: |b| &b.wake_lateness,
            budget_us: None,
            misses: false,
        });
    }
    let h = 370 * tracks.len() as u32 + 40;
    write_both!(stem, (1100, h), |root| draw_timeline(
        root, title, bins, &tracks
    ))
}
