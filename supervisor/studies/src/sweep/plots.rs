//! The sweep's figures: RMS error, TDE error and δ_N against each delay axis, and the
//! effective-delay figures of a sub-tick axis.

use super::point::{Metric, Row};
use super::schema::{SweepFile, variants};
use anyhow::Result;
use deltaloop_config::{Compensation, LoopMode};
use deltaloop_report::plot::{self, Panel, Series};
use deltaloop_study::record::RunStatus;
use std::path::Path;

/// A metric's 95 % confidence interval read off a row (NaN: a single repeat).
type Band = fn(&Row) -> (f64, f64);

/// (file stem, y label, metric, its interval) of the RMS and TDE error figures.
const RMS: (&str, &str, Metric, Band) = (
    "rms",
    "RMS joint error, max over joints (rad)",
    |r| r.rms_rad,
    |r| (r.rms_rad_ci95_lo, r.rms_rad_ci95_hi),
);
const TDE_ERR: (&str, &str, Metric, Band) = (
    "tde_err",
    "TDE error RMS, max over joints (rad/s²)",
    |r| r.tde_err_rms,
    |r| (r.tde_err_rms_ci95_lo, r.tde_err_rms_ci95_hi),
);

/// The error bars of a series: each row's interval where it has one (repeats > 1).
fn bars(rows: &[&Row], x: impl Fn(&Row) -> f64, band: Band) -> Vec<(f64, f64, f64)> {
    rows.iter()
        .map(|r| {
            let (lo, hi) = band(r);
            (x(r), lo, hi)
        })
        .filter(|b| b.1.is_finite() && b.2.is_finite())
        .collect()
}

/// (file stem, x axis, metric) of every figure written.
pub(super) fn plots(sw: &SweepFile, rows: &[Row], out: &Path) -> Result<Vec<(String, String)>> {
    let mut written = Vec::new();
    let metrics: [(&str, &str, Metric, Band); 3] = [
        RMS,
        TDE_ERR,
        (
            "delta_n",
            "δ_N max, max over joints (rad/s³)",
            |r| r.delta_n_max,
            |_| (f64::NAN, f64::NAN),
        ),
    ];
    let axes: [(&str, &str, bool); 3] = [
        ("tde_delay", "TDE delay ℓ (ticks)", true),
        ("transport_delay", "transport delay d (ticks)", false),
        ("compute_delay", "controller compute delay (µs)", false),
    ];
    for (axis, x_label, log_x) in axes {
        let x_of = |r: &Row| -> f64 {
            match axis {
                "tde_delay" => f64::from(r.tde_delay_samples),
                "transport_delay" => f64::from(r.transport_delay_samples),
                _ => f64::from(r.compute_delay_us),
            }
        };
        // Hold the other axes at their first value.
        let on_axis = |r: &Row| -> bool {
            let (l0, d0) = (sw.tde_delay_samples[0], sw.transport_delay_samples[0]);
            match axis {
                "tde_delay" => r.on_grid() && r.transport_delay_samples == d0,
                "transport_delay" => r.on_grid() && r.tde_delay_samples == l0,
                _ => r.mode == LoopMode::Realtime && r.link_delay_us.is_none(),
            }
        };
        let values: Vec<f64> = rows.iter().filter(|r| on_axis(r)).map(x_of).collect();
        let distinct = {
            let mut v = values.clone();
            v.sort_by(f64::total_cmp);
            v.dedup();
            v.len()
        };
        if distinct < 2 {
            continue;
        }
        for (mname, y_label, get, band) in metrics {
            let mut panels = Vec::new();
            for &sc in &sw.scenarios {
                for &pr in &sw.presets {
                    let scn = sc.name();
                    let series = variants(sw)
                        .into_iter()
                        .map(|law| {
                            let here: Vec<&Row> = rows
                                .iter()
                                .filter(|r| {
                                    on_axis(r)
                                        && r.scenario == sc
                                        && r.preset == pr
                                        && r.law == law
                                        && r.status == RunStatus::Ok
                                })
                                .collect();
                            Series {
                                dashed: law.compensate != Compensation::None,
                                name: law.to_string(),
                                color: plot::law_color(law.law),
                                points: here.iter().map(|r| (x_of(r), get(r))).collect(),
                                bars: bars(&here, x_of, band),
                            }
                        })
                        .collect();
                    panels.push(Panel {
                        title: format!("{} — preset {}", scn.to_uppercase(), pr.name()),
                        x_label: x_label.to_string(),
                        y_label: y_label.to_string(),
                        log_x: log_x && values.iter().all(|&v| v > 0.0),
                        log_y: true,
                        series,
                    });
                }
            }
            let stem = format!("{mname}_vs_{axis}");
            plot::figure(
                &out.join(&stem),
                &format!("{} vs {}", y_label, x_label),
                &panels,
                sw.presets.len(),
            )?;
            written.push((stem, format!("{y_label} vs {x_label}")));
        }
    }
    if !sw.transport_delay_us.is_empty() {
        written.extend(effective_delay_figures(sw, rows, out)?);
    }
    if super::compensation::compares(sw) {
        written.push(super::compensation::figure(sw, rows, out)?);
    }
    Ok(written)
}

/// The delay study's headline: tracking and TDE error against the effective estimation delay
/// L_eff/Ts = ℓ + D/Ts from 1 to 3 ticks, integer ℓ (D = d·Ts at the first d) and the transport
/// delay D (at the first ℓ, whole and sub-tick) as two series per law on the same axes.
fn effective_delay_figures(
    sw: &SweepFile,
    rows: &[Row],
    out: &Path,
) -> Result<Vec<(String, String)>> {
    let (l0, d0) = (sw.tde_delay_samples[0], sw.transport_delay_samples[0]);
    let max_x = f64::from(l0) + f64::from(d0) + 2.0 + 1e-9;
    let mut written = Vec::new();
    for (mname, y_label, get, band) in [RMS, TDE_ERR] {
        let mut panels = Vec::new();
        for &sc in &sw.scenarios {
            for &pr in &sw.presets {
                let here = |r: &&Row| {
                    r.mode != LoopMode::Realtime
                        && r.scenario == sc
                        && r.preset == pr
                        && r.status == RunStatus::Ok
                        && r.effective_delay_ticks <= max_x
                };
                let mut series = Vec::new();
                for law in variants(sw) {
                    let points = |by_ell: bool| -> Vec<&Row> {
                        let mut p: Vec<&Row> = rows
                            .iter()
                            .filter(here)
                            .filter(|r| r.law == law)
                            .filter(|r| {
                                if by_ell {
                                    r.on_grid() && r.transport_delay_samples == d0
                                } else {
                                    r.tde_delay_samples == l0
                                }
                            })
                            .collect();
                        p.sort_by(|a, b| {
                            a.effective_delay_ticks.total_cmp(&b.effective_delay_ticks)
                        });
                        p
                    };
                    let x = |r: &Row| r.effective_delay_ticks;
                    for (by_ell, name, color) in [
                        (true, format!("{law}: ℓ"), plot::law_color(law.law)),
                        (
                            false,
                            format!("{law}: D (µs)"),
                            plot::lighter(plot::law_color(law.law)),
                        ),
                    ] {
                        let p = points(by_ell);
                        series.push(Series {
                            dashed: law.compensate != Compensation::None,
                            name,
                            color,
                            points: p.iter().map(|r| (x(r), get(r))).collect(),
                            bars: bars(&p, x, band),
                        });
                    }
                }
                panels.push(Panel {
                    title: format!("{} — preset {}", sc.name().to_uppercase(), pr.name()),
                    x_label: "effective estimation delay L_eff/Ts = ℓ + D/Ts".into(),
                    y_label: y_label.to_string(),
                    log_x: false,
                    log_y: true,
                    series,
                });
            }
        }
        let stem = format!("{mname}_vs_effective_delay");
        let title = format!("{y_label} vs the effective delay ℓ + D/Ts");
        plot::figure(&out.join(&stem), &title, &panels, sw.presets.len())?;
        written.push((stem, title));
    }
    Ok(written)
}
