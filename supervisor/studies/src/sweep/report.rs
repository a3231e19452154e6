//! The sweep's `report.md`: one table per axis, the latency budget of each law.

use super::point::{LINK_MAX_MISS_SHARE, Metric, Row};
use super::schema::{SweepFile, variants};
use deltaloop_config::PathKind;
use deltaloop_config::{LawVariant, LoopMode, Preset};
use deltaloop_study::record::RunStatus;
use deltaloop_study::record::{sensitivity, stats};
use std::fmt::Write as _;
use std::path::Path;

/// The largest sub-tick transport delay (µs) on the grid up to which a law's tracking RMS stays
/// within 2× its value at D = 0 (every delay up to it included), and the RMS there; None without
/// a D = 0 result. The rows of D = 0 and of the budget come with it (their round-off spreads cut
/// the printed digits).
fn latency_budget<'a>(
    sw: &SweepFile,
    rows: &'a [Row],
    scenario: PathKind,
    preset: Preset,
    law: LawVariant,
) -> Option<(&'a Row, f64, &'a Row)> {
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
    let zero = at(0.0).filter(|r| r.status == RunStatus::Ok)?;
    let mut grid: Vec<f64> = sw.transport_delay_us.clone();
    grid.retain(|&us| us > 0.0);
    grid.sort_by(f64::total_cmp);
    let mut best = (0.0, zero);
    for us in grid {
        match at(us) {
            Some(r) if r.status == RunStatus::Ok && r.rms_rad <= 2.0 * zero.rms_rad => {
                best = (us, r)
            }
            _ => break,
        }
    }
    Some((zero, best.0, best.1))
}

/// A metric as the sweep's tables show it: its value (with the CI's half-width when the row
/// has repeats), the round-off spread of its twin (NaN: none) and the interval.
#[derive(Clone, Copy)]
struct Shown {
    pub value: Metric,
    pub roundoff: Metric,
    pub ci: fn(&Row) -> (f64, f64),
    /// A ratio: its interval is asymmetric (log space) and printed as `[lo, hi]`.
    pub ratio: bool,
}

/// RMS joint error, max over joints.
const RMS: Shown = Shown {
    value: |r| r.rms_rad,
    roundoff: |r| r.rms_rad_roundoff,
    ci: |r| (r.rms_rad_ci95_lo, r.rms_rad_ci95_hi),
    ratio: false,
};

/// TDE error RMS, max over joints.
const TDE: Shown = Shown {
    value: |r| r.tde_err_rms,
    roundoff: |r| r.tde_err_rms_roundoff,
    ci: |r| (r.tde_err_rms_ci95_lo, r.tde_err_rms_ci95_hi),
    ratio: false,
};

/// A value with 3 significant digits, or fewer when its round-off twin moved it by more than a
/// unit of the third (`†` marks those), then `±x %`: the half-width of its 95 % CI over the repeats.
fn value_text(r: &Row, m: Shown) -> String {
    let x = (m.value)(r);
    let rel = (m.roundoff)(r);
    let mut t = if rel.is_finite() && sensitivity::digits(x, rel) < 3 {
        format!("{}†", sensitivity::sci(x, rel))
    } else {
        format!("{x:.2e}")
    };
    let (lo, hi) = (m.ci)(r);
    if lo.is_finite() && hi.is_finite() && x != 0.0 {
        if m.ratio {
            let _ = write!(t, " [{lo:.3}, {hi:.3}]");
        } else {
            let _ = write!(t, " ±{}", pct((hi - lo) / 2.0 / x.abs()));
        }
    }
    if r.repeats_ok < r.repeats {
        let _ = write!(t, " ({}/{} not ok)", r.repeats - r.repeats_ok, r.repeats);
    }
    t
}

/// A relative half-width in percent, with the digits it deserves.
fn pct(x: f64) -> String {
    if x < 0.001 {
        "<0.1 %".into()
    } else if x < 0.1 {
        format!("{:.1} %", x * 100.0)
    } else {
        format!("{:.0} %", x * 100.0)
    }
}

fn cell(r: Option<&Row>, m: Shown) -> String {
    match r {
        None => "–".into(),
        Some(r) => match r.status {
            RunStatus::Ok => value_text(r, m),
            RunStatus::Diverged => format!("div@{}", r.diverged_at_tick.unwrap_or(0)),
            RunStatus::Interrupted => "–".into(),
            other => other.name().into(),
        },
    }
}

/// One markdown table: a row per law, a column per value of one delay axis.
fn axis_table<'a>(
    s: &mut String,
    caption: &str,
    sym: &str,
    values: &[u32],
    laws: &[LawVariant],
    find: impl Fn(LawVariant, u32) -> Option<&'a Row>,
    get: Shown,
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
        "# Sweep `{}`\n\n{}\n\nProduced by: `deltaloop sweep {}`. {} points; deterministic axes in `{}` mode.\n",
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
    reading_note(&mut s, sw, rows);
    grid_tables(&mut s, sw, rows);
    if !sw.compute_delay_us.is_empty() {
        let _ = writeln!(
            s,
            "## Controller compute delay (realtime)\n\nLatency cost: the RMS over that of the same config with ideal timing (in-process, same seed).\n\n| scenario | preset | law | compute delay (µs) | status | RMS (rad) | latency cost | misses | round trip p99.9 (µs) | reason |\n|---|---|---|---|---|---|---|---|---|---|"
        );
        for r in rows
            .iter()
            .filter(|r| r.mode == LoopMode::Realtime && r.link_delay_us.is_none() && r.is_result())
        {
            let _ = writeln!(
                s,
                "| {} | {} | `{}` | {} | {} | {} | {} | {} | {} | {} |",
                r.scenario,
                r.preset,
                r.law,
                r.compute_delay_us,
                r.status,
                value_text(r, RMS),
                value_text(r, COST),
                r.deadline_misses.map_or("–".into(), |m| m.to_string()),
                r.round_trip_p999_us
                    .map_or("–".into(), |p| format!("{p:.1}")),
                r.reason.replace('|', "\\|").replace('\n', " ")
            );
        }
        let _ = writeln!(s);
    }
    if !sw.link_delay_us.is_empty() {
        link_table(&mut s, sw, rows);
    }
    if super::compensation::compares(sw) {
        super::compensation::table(&mut s, sw, rows);
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

/// The latency cost of a realtime point (no round-off twin in realtime).
const COST: Shown = Shown {
    value: |r| r.latency_cost,
    roundoff: |_| f64::NAN,
    ci: |r| (r.latency_cost_ci95_lo, r.latency_cost_ci95_hi),
    ratio: true,
};

/// How to read the cells: repeats and their interval, round-off marks.
fn reading_note(s: &mut String, sw: &SweepFile, rows: &[Row]) {
    if sw.repeats > 1 {
        let first = rows.first().map_or(0, |r| r.seed);
        let _ = writeln!(
            s,
            "Each point ran {} times, with sensor-noise seeds {} to {}; a cell is the mean over the runs that ended `ok` (`(k/N not ok)`: the others, left out), ± the half-width of its {} (relative to the mean); a latency cost, a ratio, is a geometric mean with its interval in brackets ({}). `sweep.csv` has the standard deviations and both ends of each interval.\n",
            sw.repeats,
            first,
            first.saturating_add(u64::from(sw.repeats) - 1),
            stats::CI_METHOD,
            stats::RATIO_CI_METHOD
        );
        let spread = rows
            .iter()
            .filter(|r| r.mode != LoopMode::Realtime && r.repeats_ok > 1)
            .any(|r| r.rms_rad_std > 0.0);
        let deterministic = rows
            .iter()
            .any(|r| r.mode != LoopMode::Realtime && r.repeats_ok > 1);
        if deterministic && !spread {
            let _ = writeln!(
                s,
                "**The seeds changed nothing**: every in-process point gave the same result for every seed. The base config has no sensor noise (`[sensor]`), so these repeats are one run, N times.\n"
            );
        }
    }
    if sw.sensitivity {
        let marked = rows
            .iter()
            .filter(|r| {
                r.rms_rad_roundoff.is_finite()
                    && sensitivity::digits(r.rms_rad, r.rms_rad_roundoff) < 3
            })
            .count();
        let _ = writeln!(
            s,
            "Round-off: every deterministic point also ran its twin with {}; a value its twin moved by a unit of its third digit or more is marked † and keeps only the digits that survive ({marked} points on the RMS; the spreads are the `*_roundoff` columns of `sweep.csv`). A difference between two † values smaller than their spread is not a result.\n",
            sensitivity::PERTURBATION
        );
    }
}

/// The grid's tables: per scenario and preset, each metric against ℓ and against d.
fn grid_tables(s: &mut String, sw: &SweepFile, rows: &[Row]) {
    let tables: [(&str, Shown); 2] = [
        ("RMS joint error, max over joints (rad)", RMS),
        ("TDE error RMS, max over joints (rad/s²)", TDE),
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
                let base = |r: &&Row| r.on_grid() && r.scenario == sc && r.preset == pr;
                let by_ell = |law: LawVariant, l: u32| {
                    rows.iter().filter(base).find(|r| {
                        r.law == law && r.tde_delay_samples == l && r.transport_delay_samples == d0
                    })
                };
                let by_d = |law: LawVariant, d: u32| {
                    rows.iter().filter(base).find(|r| {
                        r.law == law && r.tde_delay_samples == l0 && r.transport_delay_samples == d
                    })
                };
                axis_table(
                    s,
                    &format!("Against the TDE delay ℓ (transport delay d = {d0})"),
                    "ℓ",
                    &sw.tde_delay_samples,
                    &variants(sw),
                    by_ell,
                    get,
                );
                axis_table(
                    s,
                    &format!("Against the transport delay d (ℓ = {l0})"),
                    "d",
                    &sw.transport_delay_samples,
                    &variants(sw),
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
            for law in variants(sw) {
                if let Some((zero, us, there)) = latency_budget(sw, rows, sc, pr, law) {
                    let _ = writeln!(
                        s,
                        "| {} | {} | `{law}` | {} | {us} | {} |",
                        sc.name(),
                        pr.name(),
                        value_text(zero, RMS),
                        value_text(there, RMS)
                    );
                }
            }
        }
    }
    let _ = writeln!(s);
}

/// How far a link point's RMS may be from that of the same delay injected in-process
/// (`transport_delay_us` = its median arrival), relative, for the two to be said to match, when
/// the realtime run was not disturbed ([`Row::link_disturbed`]): the realtime run's arrival
/// varies from tick to tick around its median and a miss holds the torque a tick longer, where
/// the injected delay is one constant (docs/guide/delay-study.md has the measured spread).
pub const LINK_MATCH_TOLERANCE: f64 = 0.10;

/// The relative difference of a link point's RMS from that of its injected twin (None: no twin).
pub fn link_match(r: &Row) -> Option<f64> {
    r.injected_rms_rad
        .filter(|&i| i > 0.0 && r.status == RunStatus::Ok)
        .map(|i| r.rms_rad / i - 1.0)
}

/// The relative difference of a link point's replay RMS from that of its injected twin: the
/// model's question (does one constant delay explain the link's measured arrivals?) without the
/// machine's (the replay is deterministic, whatever disturbed the realtime run).
pub fn replay_match(r: &Row) -> Option<f64> {
    r.injected_rms_rad
        .zip(r.replay_rms_rad)
        .filter(|&(i, _)| i > 0.0)
        .map(|(i, p)| p / i - 1.0)
}

/// `yes` / `no` for [`replay_match`] within [`LINK_MATCH_TOLERANCE`], `–` without both runs.
pub fn replay_verdict(r: &Row) -> &'static str {
    match replay_match(r) {
        None => "–",
        Some(d) if d.abs() <= LINK_MATCH_TOLERANCE => "yes",
        Some(_) => "no",
    }
}

/// A link point's verdict: `yes` / `no` (within [`LINK_MATCH_TOLERANCE`] or not), or why the
/// point says nothing (`disturbed: …`, `–` without a twin).
pub fn link_verdict(r: &Row) -> String {
    match (link_match(r), &r.link_disturbed) {
        (None, _) => "–".into(),
        (Some(_), Some(why)) => format!("disturbed: {why}"),
        (Some(d), None) if d.abs() <= LINK_MATCH_TOLERANCE => "yes".into(),
        (Some(_), None) => "no".into(),
    }
}

/// The link axis: each point in realtime across the bridge, next to the same delay injected.
fn link_table(s: &mut String, sw: &SweepFile, rows: &[Row]) {
    let _ = writeln!(
        s,
        "## Emulated network delay (realtime, across the bridge)\n\nEach point ran in realtime with the controller behind `deltaloop-bridge` over this host's loopback (the far side with its own iceoryx2 root), the bridges delaying every datagram by the link delay each way{}. Link round trip: the round trip less the far host's residence (p50). Injected: the same config in-process with `transport_delay_us` = the run's median arrival A_k − t_k, same seed. They match when the RMS differs by at most {:.0} %: realtime is not bit-identical (the arrival varies per tick around its median, a miss holds the torque), the injected delay is one constant. A run with more than {:.0} % of its ticks missed, a burst of 5 or more, or whose plant paused its clock or once woke a tick late, was disturbed by the machine and says nothing either way; one that was not can still miss the tolerance when a burst of misses falls on a sensitive moment of the motion (the longest burst is in brackets after the misses). Replay: the realtime run re-run in-process with each reply acting at its own recorded arrival (`deltaloop replay`), deterministic; against the injected run it says whether one constant delay explains the link's measured arrivals, also when the realtime run was disturbed (the same tolerance).\n\n| scenario | preset | law | link delay (µs) | status | link round trip p50 (µs) | median arrival (µs) | RMS realtime (rad) | RMS injected (rad) | difference | match | RMS replay (rad) | replay vs injected | a constant delay explains it | misses (longest burst) | reason |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
        match (sw.link_jitter_us, sw.link_loss) {
            (j, l) if j == 0.0 && l == 0.0 => String::new(),
            (j, l) => format!(" (plus a uniform jitter in [0, {j}] µs; loss {l})"),
        },
        LINK_MATCH_TOLERANCE * 100.0,
        LINK_MAX_MISS_SHARE * 100.0
    );
    let opt = |v: Option<f64>, digits: usize| v.map_or("–".into(), |v| format!("{v:.digits$}"));
    for r in rows
        .iter()
        .filter(|r| r.link_delay_us.is_some() && r.is_result())
    {
        let diff = link_match(r);
        let _ = writeln!(
            s,
            "| {} | {} | `{}` | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            r.scenario,
            r.preset,
            r.law,
            r.link_delay_us.unwrap_or(0.0),
            r.status,
            opt(r.link_rtt_p50_us, 1),
            opt(r.median_arrival_us, 1),
            value_text(r, RMS),
            // Three significant digits, as a value without its own twin (value_text).
            r.injected_rms_rad
                .map_or("–".into(), |v| format!("{v:.2e}")),
            diff.map_or("–".into(), |d| format!("{:+.1} %", d * 100.0)),
            link_verdict(r),
            r.replay_rms_rad.map_or("–".into(), |v| format!("{v:.2e}")),
            replay_match(r).map_or("–".into(), |d| format!("{:+.1} %", d * 100.0)),
            replay_verdict(r),
            r.deadline_misses.map_or("–".into(), |m| format!(
                "{m} ({})",
                r.max_consecutive_misses.unwrap_or(0)
            )),
            r.reason.replace('|', "\\|").replace('\n', " ")
        );
    }
    let _ = writeln!(s);
}
