//! The compensation study's table and figure: each law with and without delay compensation
//! (`compensate = ["none", "predict"]`) against the transport delay D, whole ticks d and
//! sub-tick µs at the first ℓ, as the ratio to the same law's uncompensated RMS at D = 0.

use super::point::Row;
use super::schema::{SweepFile, variants};
use anyhow::Result;
use deltaloop_config::{Compensation, LawVariant, LoopMode, PathKind, Preset};
use deltaloop_report::plot::{self, Panel, Series};
use deltaloop_study::record::{RunStatus, sensitivity};
use std::fmt::Write as _;
use std::path::Path;

/// Whether the sweep runs its laws both with and without compensation.
pub(super) fn compares(sw: &SweepFile) -> bool {
    [Compensation::None, Compensation::Predict]
        .iter()
        .all(|c| sw.compensate.contains(c))
}

/// The deterministic points of `law` at the first ℓ, one per transport delay (the ℓ × d grid's
/// column and the sub-tick axis; a sub-tick value of whole ticks, e.g. 300 µs, is the grid's
/// d = 1 again and left out), with D/Ts, ascending.
fn by_delay<'a>(
    sw: &SweepFile,
    rows: &'a [Row],
    scenario: PathKind,
    preset: Preset,
    law: LawVariant,
) -> Vec<(f64, &'a Row)> {
    let l0 = sw.tde_delay_samples[0];
    let mut v: Vec<(f64, &Row)> = rows
        .iter()
        .filter(|r| {
            r.mode != LoopMode::Realtime
                && r.is_result()
                && r.scenario == scenario
                && r.preset == preset
                && r.law == law
                && r.tde_delay_samples == l0
        })
        .map(|r| (r.effective_delay_ticks - f64::from(l0), r))
        .collect();
    // Stable: of two points at one delay the grid's, expanded first, stays.
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    v.dedup_by(|b, a| (b.0 - a.0).abs() < 1e-9);
    v
}

/// A column's heading: `d = 2`, or `45 µs` for a sub-tick delay.
fn heading(r: &Row) -> String {
    match r.transport_delay_us {
        us if us > 0.0 && r.transport_delay_samples == 0 => format!("{us} µs"),
        us if us > 0.0 => format!("d = {} + {us} µs", r.transport_delay_samples),
        _ => format!("d = {}", r.transport_delay_samples),
    }
}

/// `x` with three significant digits, without an exponent up to 10⁵ (`1.24`, `42.9`, `1703`).
fn three_digits(x: f64) -> String {
    match x.abs() {
        a if a >= 1e5 => format!("{x:.2e}"),
        a if a >= 100.0 => format!("{x:.0}"),
        a if a >= 10.0 => format!("{x:.1}"),
        _ => format!("{x:.2}"),
    }
}

/// `r`'s RMS over `zero`'s with the digits that survive both round-off twins, `div@k` for a
/// diverged run, the status otherwise; `‡` where the drives clamped the torque.
fn ratio_text(r: &Row, zero: &Row) -> String {
    let mut t = match r.status {
        RunStatus::Ok => {
            let x = r.rms_rad / zero.rms_rad;
            let spread = [r.rms_rad_roundoff, zero.rms_rad_roundoff]
                .into_iter()
                .filter(|s| s.is_finite())
                .map(f64::abs)
                .sum::<f64>();
            if spread > 0.0 && sensitivity::digits(x, spread) < 3 {
                format!("×{}†", sensitivity::sci(x, spread))
            } else {
                format!("×{}", three_digits(x))
            }
        }
        RunStatus::Diverged => format!("div@{}", r.diverged_at_tick.unwrap_or(0)),
        other => other.name().to_string(),
    };
    if r.clamp_count > 0 {
        t.push('‡');
    }
    t
}

/// `report.md`'s "Delay compensation": per scenario and preset, each law and its compensated
/// variant against D, relative to the uncompensated law at D = 0.
pub(super) fn table(s: &mut String, sw: &SweepFile, rows: &[Row]) {
    let _ = writeln!(
        s,
        "## Delay compensation\n\nEach law as it is and compensated (`+pred`: the law acts on the state predicted for when its torque acts, docs/controllers.md, \"Delay compensation\"), at ℓ = {}, against the transport delay D (whole ticks d, and sub-tick). A cell is the RMS joint error (max over joints) over that of the same law uncompensated at D = 0 (its value in rad in the first column); `div@k`: diverged at tick k; ‡: the drives clamped the torque at least once; †: the round-off twins moved the ratio, shown with the digits that survive.\n",
        sw.tde_delay_samples[0]
    );
    for &sc in &sw.scenarios {
        for &pr in &sw.presets {
            let laws = variants(sw);
            let Some(columns) = laws
                .iter()
                .map(|&law| by_delay(sw, rows, sc, pr, law))
                .max_by_key(Vec::len)
                .filter(|c| !c.is_empty())
            else {
                continue;
            };
            let _ = writeln!(
                s,
                "### {} — preset `{}`\n\n| law | RMS at D = 0 (rad) |{}\n|---|---|{}",
                sc.name().to_uppercase(),
                pr.name(),
                columns
                    .iter()
                    .map(|(_, r)| format!(" {} |", heading(r)))
                    .collect::<String>(),
                "---|".repeat(columns.len())
            );
            for law in laws {
                let plain = LawVariant::new(law.law, Compensation::None);
                let zero = by_delay(sw, rows, sc, pr, plain)
                    .into_iter()
                    .find(|(x, r)| *x == 0.0 && r.status == RunStatus::Ok);
                let here = by_delay(sw, rows, sc, pr, law);
                let _ = write!(
                    s,
                    "| `{law}` | {} |",
                    zero.map_or("–".into(), |(_, z)| format!("{:.2e}", z.rms_rad))
                );
                for (x, _) in &columns {
                    let cell = match (here.iter().find(|(xr, _)| xr == x), zero) {
                        (Some((_, r)), Some((_, z))) => ratio_text(r, z),
                        (Some((_, r)), None) => r.status.name().to_string(),
                        (None, _) => "–".into(),
                    };
                    let _ = write!(s, " {cell} |");
                }
                let _ = writeln!(s);
            }
            let _ = writeln!(s);
        }
    }
}

/// `rms_vs_delay_compensated`: RMS against D/Ts, each law solid and its compensated variant
/// dashed in the same colour, a panel per scenario and preset.
pub(super) fn figure(sw: &SweepFile, rows: &[Row], out: &Path) -> Result<(String, String)> {
    let mut panels = Vec::new();
    for &sc in &sw.scenarios {
        for &pr in &sw.presets {
            let series = variants(sw)
                .into_iter()
                .map(|law| Series {
                    name: law.to_string(),
                    color: plot::law_color(law.law),
                    points: by_delay(sw, rows, sc, pr, law)
                        .into_iter()
                        .filter(|(_, r)| r.status == RunStatus::Ok)
                        .map(|(x, r)| (x, r.rms_rad))
                        .collect(),
                    bars: Vec::new(),
                    dashed: law.compensate != Compensation::None,
                })
                .collect();
            panels.push(Panel {
                title: format!("{} — preset {}", sc.name().to_uppercase(), pr.name()),
                x_label: "transport delay D/Ts (ticks)".into(),
                y_label: "RMS joint error, max over joints (rad)".into(),
                log_x: false,
                log_y: true,
                series,
            });
        }
    }
    let stem = "rms_vs_delay_compensated".to_string();
    let title = "RMS joint error vs transport delay, with (dashed) and without compensation";
    plot::figure(&out.join(&stem), title, &panels, sw.presets.len())?;
    Ok((stem, title.to_string()))
}
