//! What `whatif` prints and writes besides `whatif.json`: the per-law table, `report.md` and the
//! figure (the latency distribution drawn from, and each law's RMS distribution).

use super::draw::Pool;
use super::summary::{ByName, Dist, LawOut, Sample, WhatIfJson, as_measured, of_law};
use anyhow::Result;
use deltaloop_config::Law;
use deltaloop_plant_tick::ReplyOutcome;
use deltaloop_report::plot::{self, Panel, Series};
use deltaloop_study::record::RunStatus;
use std::fmt::Write as _;
use std::path::Path;

/// `p50 [p2.5, p97.5]` with 3 significant digits (the replicas' spread is far wider than
/// round-off).
fn band(d: &Option<Dist>) -> String {
    d.as_ref().map_or_else(
        || "—".into(),
        |d| format!("{:.3e} [{:.3e}, {:.3e}]", d.p50, d.p2_5, d.p97_5),
    )
}

fn mean_ci(d: &Option<Dist>) -> String {
    match d {
        Some(Dist {
            mean,
            ci95: Some([lo, hi]),
            ..
        }) => format!("{mean:.3e} [{lo:.3e}, {hi:.3e}]"),
        Some(d) => format!("{:.3e}", d.mean),
        None => "—".into(),
    }
}

fn count_band(d: &Option<Dist>) -> String {
    d.as_ref().map_or_else(
        || "—".into(),
        |d| format!("{:.1} [{:.1}, {:.1}]", d.p50, d.p2_5, d.p97_5),
    )
}

/// A distribution's median as `show` writes it, "—" without one.
fn p50(d: &Option<Dist>, show: fn(f64) -> String) -> String {
    d.as_ref().map_or_else(|| "—".into(), |d| show(d.p50))
}

fn pct(x: f64) -> String {
    format!("{:.1} %", x * 100.0)
}

/// The header and one row per law, as (cells) — shared by the terminal and report.md.
fn rows(json: &WhatIfJson, laws: &ByName<LawOut>) -> Vec<[String; 10]> {
    let mut v = vec![[
        "law".to_string(),
        "RMS max-joint, rad: p50 [2.5 %, 97.5 %]".into(),
        "mean [95 % CI]".into(),
        "max |e|, rad: p50 [band]".into(),
        "misses: p50 [band]".into(),
        "clamps: p50 [band]".into(),
        "max |τ|, N m: p50".into(),
        "τ total variation, N m: p50".into(),
        "HF share: p50".into(),
        "diverged / faulted".into(),
    ]];
    for (law, o) in laws.iter() {
        let ideal = json.ideal_rms_max_rad.get(law).copied().unwrap_or(f64::NAN);
        v.push([
            law.clone(),
            format!("{} (ideal {ideal:.3e})", band(&o.rms_max_rad.dist)),
            mean_ci(&o.rms_max_rad.dist),
            band(&o.max_err_rad.dist),
            count_band(&o.misses.dist),
            count_band(&o.clamps.dist),
            p50(&o.max_tau_nm.dist, |x| format!("{x:.1}")),
            p50(&o.torque_tv_nm.dist, |x| format!("{x:.3e}")),
            p50(&o.hf_share.dist, |x| format!("{x:.3}")),
            format!("{} / {}", pct(o.diverged_share), pct(o.faulted_share)),
        ]);
    }
    v
}

/// What the latencies were, in one line.
fn latency_line(json: &WhatIfJson) -> String {
    let l = &json.latency;
    let us = |x: Option<f64>| x.map_or("—".into(), |x| format!("{x:.1}"));
    format!(
        "latency: {} ticks from {} source(s), p50 {} / p99 {} / p99.9 {} / max {} µs, {} of ticks miss the {:.0} µs budget; draws: {}{}",
        l.ticks,
        l.sources.len(),
        us(l.p50_us),
        us(l.p99_us),
        us(l.p99_9_us),
        us(l.max_us),
        pct(l.miss_share),
        l.budget_us,
        l.draw,
        l.block_ticks
            .map_or(String::new(), |b| format!(" (blocks of {b} ticks)"))
    )
}

/// The budget rule, when it ended replicas: one line naming it and each law's share so ended
/// (at any scale); None when no replica faulted.
fn budget_rule(json: &WhatIfJson) -> Option<String> {
    let mut shares: Vec<String> = Vec::new();
    let mut note = |scale: &str, laws: &ByName<LawOut>| {
        for (law, o) in laws.iter().filter(|(_, o)| o.faulted_share > 0.0) {
            shares.push(format!(
                "{} of `{law}`'s replicas{scale}",
                pct(o.faulted_share)
            ));
        }
    };
    match &json.scales {
        Some(sc) => sc
            .iter()
            .for_each(|(k, laws)| note(&format!(" at latency ×{k}"), laws)),
        None => note("", &json.laws),
    }
    (!shares.is_empty()).then(|| {
        format!(
            "the budget rule: a reply later than the {:.0} µs budget (loop.torque_budget_us) is a miss, and {} misses in a row (faults.controller_silence_ticks) stop the loop with the controller-silence fault; it ended {}",
            json.latency.budget_us,
            json.latency.controller_silence_ticks,
            shares.join(", ")
        )
    })
}

/// The terminal's lines.
pub fn table(json: &WhatIfJson) -> Vec<String> {
    let rows = rows(json, &json.laws);
    let widths: Vec<usize> = (0..10)
        .map(|c| rows.iter().map(|r| r[c].chars().count()).max().unwrap_or(0))
        .collect();
    let mut out = vec![
        format!(
            "whatif {}: {} replicas per law, seed {}",
            json.scenario, json.replicas, json.seed
        ),
        latency_line(json),
    ];
    for r in &rows {
        let cells: Vec<String> = r
            .iter()
            .zip(&widths)
            .map(|(c, w)| format!("{c:<w$}", w = *w))
            .collect();
        out.push(cells.join("  ").trim_end().to_string());
    }
    out.extend(budget_rule(json));
    out.extend(json.pairs.iter().map(|p| p.sentence()));
    if let Some(sc) = &json.scales {
        for (s, laws) in sc.iter() {
            let line: Vec<String> = laws
                .iter()
                .map(|(law, o)| format!("{law} {}", band(&o.rms_max_rad.dist)))
                .collect();
            out.push(format!("latency ×{s}: RMS {}", line.join("; ")));
        }
    }
    out.push(format!(
        "{:.1} s for {} replicas on {} threads: {:.2}× the in-process runs' time ÷ threads",
        json.timing.wall_s,
        json.replicas as usize * json.laws.len() * json.scales.as_ref().map_or(1, |s| s.len()),
        json.timing.threads,
        json.timing.ratio
    ));
    out
}

/// `report.md`.
pub fn markdown(json: &WhatIfJson) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# What if: {}\n", json.scenario);
    let _ = writeln!(s, "`{}`\n", json.command);
    let _ = writeln!(
        s,
        "Each of {} replicas per law draws a latency for every tick from the records below, runs the \
         scenario in-process with each reply acting at its drawn arrival (a reply later than the \
         {:.0} µs torque budget is a miss: the drives hold), and records the metrics a run \
         records. The draws are seeded ({}); every law meets the same draws. Sensor noise keeps the \
         scenario's own seed.\n",
        json.replicas, json.latency.budget_us, json.seed
    );
    let _ = writeln!(s, "## Latency\n\n{}\n", latency_line(json));
    for src in &json.latency.sources {
        let _ = writeln!(s, "- `{}` ({}, {} ticks)", src.path, src.kind, src.ticks);
    }
    let _ = writeln!(s, "\n## Tracking\n");
    let _ = writeln!(
        s,
        "Distributions over the replicas that ran every tick; \"ideal\" is the same scenario with every \
         reply at once. The band is the replicas' 2.5–97.5 % range: where a run on the measured \
         target would fall. The CI is that of the mean.\n"
    );
    md_table(&mut s, &rows(json, &json.laws));
    if let Some(rule) = budget_rule(json) {
        let _ = writeln!(s, "\nThe faulted replicas: {rule}.");
    }
    if !json.pairs.is_empty() {
        let _ = writeln!(
            s,
            "\n## Law against law\n\nReplica r meets the same latencies in every law, so two laws \
             are compared replica by replica: the share of the replicas where one's max-joint RMS is \
             below the other's (a diverged or faulted replica ranks worst), and the median of their \
             ratio with its 95 % bootstrap interval (`pairs` in whatif.json; each replica's values \
             are `laws.<law>.<metric>.values`).\n"
        );
        for p in &json.pairs {
            let _ = writeln!(s, "- {}", p.sentence());
        }
    }
    if let Some(sc) = &json.scales {
        let _ = writeln!(s, "\n## Latency scaled\n");
        let _ = writeln!(
            s,
            "Every drawn latency multiplied by the factor (a target that fast or that slow).\n"
        );
        let laws: Vec<&String> = json.laws.iter().map(|(k, _)| k).collect();
        let mut t = vec![
            std::iter::once("scale".to_string())
                .chain(laws.iter().map(|l| format!("{l}: RMS p50 [band], rad")))
                .collect::<Vec<_>>(),
        ];
        for (k, by) in sc.iter() {
            t.push(
                std::iter::once(format!("×{k}"))
                    .chain(laws.iter().map(|l| {
                        by.get(l).map_or("—".into(), |o| {
                            format!(
                                "{}{}",
                                band(&o.rms_max_rad.dist),
                                if o.diverged_share + o.faulted_share > 0.0 {
                                    format!(
                                        " ({} diverged/faulted)",
                                        pct(o.diverged_share + o.faulted_share)
                                    )
                                } else {
                                    String::new()
                                }
                            )
                        })
                    }))
                    .collect(),
            );
        }
        md_table(&mut s, &t);
    }
    let _ = writeln!(s, "\n![latency and RMS distributions](whatif.png)\n");
    let _ = writeln!(
        s,
        "## What the model leaves out\n\n\
         The plant is always on time (its own stalls, which `stretch` pauses in a realtime run, are \
         not drawn); the controller's compute time does not depend on the state; the latencies of \
         consecutive ticks are as correlated as the draw model keeps them (blocks of the record, \
         or none), and nothing couples them to the robot's motion.\n"
    );
    let _ = writeln!(
        s,
        "## Speed\n\n{:.2} s for the replicas on {} threads; one in-process run of each law took {} s: \
         {:.2}× the ideal parallel time.",
        json.timing.wall_s,
        json.timing.threads,
        json.timing
            .one_run_s
            .iter()
            .map(|(l, t)| format!("{l} {t:.4}"))
            .collect::<Vec<_>>()
            .join(", "),
        json.timing.ratio
    );
    s
}

fn md_table<R: AsRef<[String]>>(s: &mut String, rows: &[R]) {
    for (i, r) in rows.iter().enumerate() {
        let _ = writeln!(s, "| {} |", r.as_ref().join(" | "));
        if i == 0 {
            let _ = writeln!(s, "|{}", "---|".repeat(r.as_ref().len()));
        }
    }
}

/// `<stem>.png` and `.svg`: the latency distribution drawn from (by percentile), each law's RMS
/// distribution over the replicas (as a cumulative share), and with `--scale` the RMS band
/// against the scale.
pub fn figure(
    stem: &Path,
    json: &WhatIfJson,
    pool: &Pool,
    samples: &[Sample],
    laws: &[Law],
    scales: &[f64],
) -> Result<()> {
    let mut panels = vec![
        latency_panel(json, pool),
        rms_panel(samples, json, laws, scales),
    ];
    if let Some(sc) = &json.scales {
        panels.push(scale_panel(sc, laws));
    }
    let cols = panels.len().min(3);
    plot::figure(stem, &format!("What if: {}", json.scenario), &panels, cols)
}

fn latency_panel(json: &WhatIfJson, pool: &Pool) -> Panel {
    let total: u64 = pool.distribution().map(|(_, c)| c).sum();
    // Replies by percentile: x = 1/(1 − p) (the HdrHistogram view), y = latency.
    let mut points = Vec::new();
    let mut seen = 0u64;
    for (t, c) in pool.distribution() {
        if let ReplyOutcome::Applied(l) = t {
            seen += c;
            let p = seen as f64 / (total + 1) as f64;
            points.push((1.0 / (1.0 - p), l as f64 / 1e3));
        }
    }
    // At most ~600 points: keep each one whose x has moved on by 1 %.
    let mut kept: Vec<(f64, f64)> = Vec::new();
    for p in points {
        if kept.last().is_none_or(|k| p.0 > k.0 * 1.01) {
            kept.push(p);
        } else if let Some(k) = kept.last_mut() {
            k.1 = k.1.max(p.1);
        }
    }
    let x_max = kept.last().map_or(10.0, |k| k.0);
    Panel {
        title: format!("latency drawn from ({} ticks)", json.latency.ticks),
        x_label: "1/(1 − percentile)".into(),
        y_label: "latency (µs)".into(),
        log_x: true,
        log_y: true,
        series: vec![
            Series {
                dashed: false,
                name: "pooled replies".into(),
                color: plot::RGBColor(40, 80, 160),
                points: kept,
                bars: vec![],
            },
            Series {
                dashed: false,
                name: format!("budget {:.0} µs", json.latency.budget_us),
                color: plot::RGBColor(200, 40, 40),
                points: vec![
                    (1.0, json.latency.budget_us),
                    (x_max, json.latency.budget_us),
                ],
                bars: vec![],
            },
        ],
    }
}

/// Each law's RMS over the replicas as a cumulative share, and its ideal (every reply at once)
/// as a dashed vertical line of its colour.
fn rms_panel(samples: &[Sample], json: &WhatIfJson, laws: &[Law], scales: &[f64]) -> Panel {
    let replicas = json.replicas as usize;
    let mut series: Vec<Series> = laws
        .iter()
        .enumerate()
        .map(|(l, &law)| {
            let mut v: Vec<f64> = of_law(samples, laws.len(), replicas, as_measured(scales), l)
                .filter(|s| s.status == RunStatus::Ok)
                .map(|s| s.rms_max_rad)
                .collect();
            v.sort_by(f64::total_cmp);
            let n = v.len() as f64;
            Series {
                dashed: false,
                name: law.to_string(),
                color: plot::law_color(law),
                points: v
                    .iter()
                    .enumerate()
                    .map(|(i, &x)| (x, (i as f64 + 0.5) / n))
                    .collect(),
                bars: vec![],
            }
        })
        .collect();
    series.extend(laws.iter().filter_map(|&law| {
        let ideal = *json.ideal_rms_max_rad.get(&law.to_string())?;
        Some(Series {
            dashed: true,
            name: format!("{law} ideal (no latency)"),
            color: plot::law_color(law),
            points: vec![(ideal, 0.0), (ideal, 1.0)],
            bars: vec![],
        })
    }));
    Panel {
        title: "RMS over the replicas".into(),
        x_label: "RMS joint error, max over joints (rad)".into(),
        y_label: "share of replicas at or below".into(),
        log_x: true,
        log_y: false,
        series,
    }
}

fn scale_panel(sc: &ByName<ByName<LawOut>>, laws: &[Law]) -> Panel {
    let mut by_scale: Vec<(f64, &ByName<LawOut>)> = sc
        .iter()
        .filter_map(|(k, v)| Some((k.parse::<f64>().ok()?, v)))
        .collect();
    by_scale.sort_by(|a, b| a.0.total_cmp(&b.0));
    let series = laws
        .iter()
        .map(|&law| {
            let key = law.to_string();
            let at: Vec<(f64, &Dist)> = by_scale
                .iter()
                .filter_map(|(s, v)| Some((*s, v.get(&key)?.rms_max_rad.dist.as_ref()?)))
                .collect();
            Series {
                dashed: false,
                name: key.clone(),
                color: plot::law_color(law),
                points: at.iter().map(|(s, d)| (*s, d.p50)).collect(),
                bars: at.iter().map(|(s, d)| (*s, d.p2_5, d.p97_5)).collect(),
            }
        })
        .collect();
    Panel {
        title: "RMS against latency scale (p50, 2.5–97.5 %)".into(),
        x_label: "latency × (scale)".into(),
        y_label: "RMS joint error, max over joints (rad)".into(),
        log_x: true,
        log_y: true,
        series,
    }
}
