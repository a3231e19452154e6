//! Which thread ran on which CPU over a span, one lane per CPU, with the loop's stamps on top:
//! the figure of a run's worst missed tick (`<law>.worst-miss.svg`).

use super::latency::PALETTE;
use super::{Canvas, register_font};
use anyhow::{Result, anyhow};
use plotters::prelude::*;
use std::path::Path;

/// One bar of a lane: [`from_us`, `to_us`) on CPU `cpu`, what ran (a command name and pid, an
/// interrupt, `idle`), and whether a loop thread ran.
pub struct Bar<'a> {
    pub cpu: usize,
    pub from_us: f64,
    pub to_us: f64,
    pub label: &'a str,
    pub is_loop: bool,
}

/// Writes `path` (SVG): one lane per CPU of `cpus` over [`t0_us`, `t1_us`] (µs from the figure's
/// origin), each bar coloured by what ran (loop threads blue, idle blank, interrupts grey, any
/// other thread in its own colour, named in the legend), and each `(µs, name)` of `marks` a
/// vertical line across the lanes, named at its top.
pub fn cpu_lanes(
    path: &Path,
    title: &str,
    cpus: &[usize],
    (t0_us, t1_us): (f64, f64),
    bars: &[Bar],
    marks: &[(f64, &str)],
) -> Result<()> {
    register_font();
    let lanes = cpus.len().max(1) as f64;
    let root = Canvas::Svg(SVGBackend::new(path, (1100, 200 + 90 * cpus.len() as u32)))
        .into_drawing_area();
    let e = |e: &dyn std::fmt::Display| anyhow!("{}: {e}", path.display());
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d(t0_us..t1_us, 0.0..lanes)
        .map_err(|x| e(&x))?;
    chart
        .configure_mesh()
        .disable_y_mesh()
        .x_desc("time from the state's publication, µs")
        .y_labels(cpus.len() + 1)
        .y_label_formatter(&|y| {
            let i = y.floor() as usize;
            cpus.get(i)
                .filter(|_| (y - y.floor() - 0.5).abs() < 0.26)
                .map_or(String::new(), |c| format!("CPU {c}"))
        })
        .draw()
        .map_err(|x| e(&x))?;
    // Colours: the loop blue, interrupts grey, others from the palette in order of appearance.
    let mut others: Vec<String> = Vec::new();
    let colour = |b: &Bar, others: &mut Vec<String>| -> Option<RGBColor> {
        if b.is_loop {
            return Some(RGBColor(31, 119, 180));
        }
        if b.label == "idle" {
            return None;
        }
        if b.label.starts_with("irq") || b.label.starts_with("softirq") {
            return Some(RGBColor(150, 150, 150));
        }
        let name = b.label.rsplit_once(' ').map_or(b.label, |(n, _)| n);
        let i = others.iter().position(|o| o == name).unwrap_or_else(|| {
            others.push(name.to_string());
            others.len() - 1
        });
        Some(PALETTE[(i + 1) % PALETTE.len()])
    };
    let mut legend: Vec<(String, RGBColor)> = Vec::new();
    for b in bars {
        let Some(lane) = cpus.iter().position(|&c| c == b.cpu) else {
            continue;
        };
        let Some(c) = colour(b, &mut others) else {
            continue;
        };
        let y = lane as f64;
        chart
            .draw_series(std::iter::once(Rectangle::new(
                [(b.from_us, y + 0.2), (b.to_us, y + 0.8)],
                c.filled(),
            )))
            .map_err(|x| e(&x))?;
        let name = if b.is_loop || c == RGBColor(150, 150, 150) {
            b.label.to_string()
        } else {
            b.label
                .rsplit_once(' ')
                .map_or(b.label, |(n, _)| n)
                .to_string()
        };
        if !legend.iter().any(|(n, _)| *n == name) {
            legend.push((name, c));
        }
    }
    for (name, c) in legend {
        chart
            .draw_series(std::iter::empty::<Rectangle<(f64, f64)>>())
            .map_err(|x| e(&x))?
            .label(name)
            .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 14, y + 5)], c.filled()));
    }
    for &(t, name) in marks {
        chart
            .draw_series(std::iter::once(PathElement::new(
                vec![(t, 0.0), (t, lanes)],
                BLACK.stroke_width(1),
            )))
            .map_err(|x| e(&x))?;
        chart
            .draw_series(std::iter::once(Text::new(
                name.to_string(),
                (t, lanes - 0.05),
                ("sans-serif", 12).into_font(),
            )))
            .map_err(|x| e(&x))?;
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(SeriesLabelPosition::LowerRight)
        .draw()
        .map_err(|x| e(&x))?;
    root.present().map_err(|x| e(&x))?;
    Ok(())
}
