//! The sweep's `report.md`: one table per axis, the latency budget of each law.

use super::plots::on_grid;
use super::point::{Metric, Row};
use super::schema::SweepFile;
use crate::record::RunStatus;
use deltaloop_config::config::PathKind;
use deltaloop_config::{Law, LoopMode, Preset};
use std::fmt::Write as _;
use std::path::Path;

/// The largest sub-tick transport delay (µs) on the grid up to which a law's tracking RMS stays
/// within 2× its value at D = 0 (every delay up to it included), and the RMS there; None without
/// a D = 0 result.
pub(super) fn latency_budget(
    sw: &SweepFile,
    rows: &[Row],
    scenario: PathKind,
    preset: Preset,
    law: Law,
) -> Option<(f64, f64, f64)> {
    let (l0, d0) = (sw.tde_delay_samples[0], sw.transport_delay_samples[0]);
    let at = |us: f64| {
        rows.iter().find(|r| {
            r.mode != LoopMode::Realtime
                && r.scenario == scenario
                && r.preset == preset
                && r.law == law
                && r.tde_delay_samples == l0
                && r.transport_delay_samples == d0
                && r.transport_delay_us == us
        })
    };
    let zero = at(0.0).filter(|r| r.status == RunStatus::Ok)?.rms_rad;
    let mut grid: Vec<f64> = sw.transport_delay_us.clone();
    grid.retain(|&us| us > 0.0);
    grid.sort_by(f64::total_cmp);
    let mut best = (0.0, zero);
    for us in grid {
        match at(us) {
            Some(r) if r.status == RunStatus::Ok && r.rms_rad <= 2.0 * zero => {
                best = (us, r.rms_rad)
            }
            _ => break,
        }
    }
    Some((zero, best.0, best.1))
}

pub(super) fn cell(r: Option<&Row>, get: Metric) -> String {
    match r {
        None => "–".into(),
        Some(r) => match r.status {
            RunStatus::Ok => format!("{:.2e}", get(r)),
            RunStatus::Diverged => format!("div@{}", r.diverged_at_tick.unwrap_or(0)),
            RunStatus::Interrupted => "–".into(),
            other => other.name().into(),
        },
    }
}

/// One markdown table: a row per law, a column per value of one delay axis.
pub(super) fn axis_table<'a>(
    s: &mut String,
    caption: &str,
    sym: &str,
    values: &[u32],
    laws: &[Law],
    find: impl Fn(Law, u32) -> Option<&'a Row>,
    get: Metric,
) {
    let _ = writeln!(s, "{caption}:\n");
    let _ = write!(s, "| law |");
    for v in values {
        let _ = write!(s, " {sym}={v} |");
    }
    let _ = writeln!(s, "\n|---|{}", "---|".repeat(values.len()));
    for &law in laws {
        let _ = write!(s, "| `{law}` |");
        for &v in values {
            let _ = write!(s, " {} |", cell(find(law, v), get));
        }
        let _ = writeln!(s);
    }
    let _ = writeln!(s);
}

pub(super) fn report(
    sw: &SweepFile,
    rows: &[Row],
    figures: &[(String, String)],
    path: &Path,
) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# Sweep `{}`\n\n{}\n\nProduced by: `deltaloop sweep {}`. {} runs; deterministic axes in `{}` mode.\n",
        sw.name,
        sw.description,
        path.display(),
        rows.iter().filter(|r| r.is_result()).count(),
        sw.mode
    );
    let count = |st: RunStatus| rows.iter().filter(|r| r.status == st).count();
    let (div, stopped, lost, err) = (
        count(RunStatus::Diverged),
        count(RunStatus::Fault) + count(RunStatus::Stopped),
        count(RunStatus::LostData),
        count(RunStatus::Error),
    );
    // These counts only when there are some: a normal sweep's report stays as it was.
    let stopped_count = [
        (stopped, "stopped on a loop fault"),
        (lost, "lost data (the supervisor fell behind)"),
    ]
    .iter()
    .filter(|(n, _)| *n > 0)
    .map(|(n, what)| format!("; {what}: {n}"))
    .collect::<String>();
    let _ = writeln!(
        s,
        "Diverged: {div}{stopped_count}; errors: {err}. A run diverges at the first tick with |e| > 0.5 rad, a non-finite value, or the robot leaving its workspace; it is recorded there (`div@tick`), never crashes the sweep.\n"
    );
    if stopped > 0 {
        let _ = writeln!(
            s,
            "A stopped run ended on a loop fault, not by diverging: e.g. a controller that missed its torque budget `faults.controller_silence_ticks` times in a row, after which the plant braked to a safe stop. The fault is the row's `reason` in `sweep.csv`.\n"
        );
    }
    grid_tables(&mut s, sw, rows);
    if !sw.compute_delay_us.is_empty() {
        let _ = writeln!(
            s,
            "## Controller compute delay (realtime)\n\n| scenario | preset | law | compute delay (µs) | status | RMS (rad) | misses | round trip p99.9 (µs) | reason |\n|---|---|---|---|---|---|---|---|---|"
        );
        for r in rows
            .iter()
            .filter(|r| r.mode == LoopMode::Realtime && r.is_result())
        {
            let _ = writeln!(
                s,
                "| {} | {} | `{}` | {} | {} | {:.2e} | {} | {} | {} |",
                r.scenario,
                r.preset,
                r.law,
                r.compute_delay_us,
                r.status,
                r.rms_rad,
                r.deadline_misses.map_or("–".into(), |m| m.to_string()),
                r.round_trip_p999_us
                    .map_or("–".into(), |p| format!("{p:.1}")),
                r.reason.replace('|', "\\|").replace('\n', " ")
            );
        }
        let _ = writeln!(s);
    }
    if !sw.transport_delay_us.is_empty() {
        budget_table(&mut s, sw, rows);
    }
    let _ = writeln!(s, "## Figures\n");
    for (stem, title) in figures {
        let _ = writeln!(s, "### {title}\n\n![{title}]({stem}.png)\n");
    }
    s
}

/// The grid's tables: per scenario and preset, each metric against ℓ and against d.
fn grid_tables(s: &mut String, sw: &SweepFile, rows: &[Row]) {
    let tables: [(&str, Metric); 2] = [
        ("RMS joint error, max over joints (rad)", |r| r.rms_rad),
        ("TDE error RMS, max over joints (rad/s²)", |r| {
            r.tde_err_rms
        }),
    ];
    for &sc in &sw.scenarios {
        let scn = sc.name();
        for &pr in &sw.presets {
            for (title, get) in tables {
                let _ = writeln!(
                    s,
                    "## {} — preset `{}`: {title}\n",
                    scn.to_uppercase(),
                    pr.name()
                );
                let (l0, d0) = (sw.tde_delay_samples[0], sw.transport_delay_samples[0]);
                let base = |r: &&Row| on_grid(r) && r.scenario == sc && r.preset == pr;
                let by_ell = |law: Law, l: u32| {
                    rows.iter().filter(base).find(|r| {
                        r.law == law && r.tde_delay_samples == l && r.transport_delay_samples == d0
                    })
                };
                let by_d = |law: Law, d: u32| {
                    rows.iter().filter(base).find(|r| {
                        r.law == law && r.tde_delay_samples == l0 && r.transport_delay_samples == d
                    })
                };
                axis_table(
                    s,
                    &format!("Against the TDE delay ℓ (transport delay d = {d0})"),
                    "ℓ",
                    &sw.tde_delay_samples,
                    &sw.laws,
                    by_ell,
                    get,
                );
                axis_table(
                    s,
                    &format!("Against the transport delay d (ℓ = {l0})"),
                    "d",
                    &sw.transport_delay_samples,
                    &sw.laws,
                    by_d,
                    get,
                );
                let _ = writeln!(s);
            }
        }
    }
}

/// The latency budget of each law on the sub-tick transport-delay axis.
fn budget_table(s: &mut String, sw: &SweepFile, rows: &[Row]) {
    let _ = writeln!(
        s,
        "## Latency budget\n\nThe largest transport delay D on the grid (at ℓ = {}, d = {}) up to which each law's tracking RMS stays within 2× its value at D = 0. Delays are sub-tick: a command takes effect at t_k + D, cutting the interval (docs/delta-robot.md §5.2).\n\n| scenario | preset | law | RMS at D = 0 (rad) | latency budget (µs) | RMS there (rad) |\n|---|---|---|---|---|---|",
        sw.tde_delay_samples[0], sw.transport_delay_samples[0]
    );
    for &sc in &sw.scenarios {
        for &pr in &sw.presets {
            for &law in &sw.laws {
                if let Some((zero, us, rms)) = latency_budget(sw, rows, sc, pr, law) {
                    let _ = writeln!(
                        s,
                        "| {} | {} | `{law}` | {zero:.3e} | {us} | {rms:.3e} |",
                        sc.name(),
                        pr.name()
                    );
                }
            }
        }
    }
    let _ = writeln!(s);
}
