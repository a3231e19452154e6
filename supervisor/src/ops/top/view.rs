//! What `deltaloop top` shows, as text: the screen's lines and the one-line `--plain` form
//! (`key=value`, for scripts). No terminal I/O here.

use super::find::RunInfo;
use deltaloop_timing::Percentiles;
use deltaloop_timing::live::Snapshot;

/// Where the run is.
#[derive(Clone, Debug, PartialEq)]
pub enum Status {
    /// Before the first telemetry (handshake, or a run that has not started yet).
    Waiting,
    Running,
    /// The plant published its final state after tick N.
    Completed {
        tick: u64,
    },
    /// The loop stopped early; why (a FAULT, DIVERGED or STOP on the control channel, or the
    /// processes vanished).
    Stopped {
        why: String,
    },
}

impl Status {
    /// Whether the run is over.
    pub fn ended(&self) -> bool {
        matches!(self, Status::Completed { .. } | Status::Stopped { .. })
    }

    fn text(&self) -> String {
        match self {
            Status::Waiting => "waiting for the loop to start".into(),
            Status::Running => "running".into(),
            Status::Completed { tick } => format!("completed (final state at tick {tick})"),
            Status::Stopped { why } => format!("stopped: {why}"),
        }
    }
}

/// µs with a precision that suits the value.
fn us(v: f64) -> String {
    if v >= 1000.0 {
        format!("{v:.0}")
    } else {
        format!("{v:.1}")
    }
}

fn pct_row(name: &str, p: &Percentiles) -> String {
    if p.count == 0 {
        return format!("{name:<15} {:>9}", "-");
    }
    format!(
        "{name:<15} {:>9} {:>9} {:>9} {:>9}  ({} ticks)",
        us(p.p50_us),
        us(p.p99_us),
        us(p.p999_us),
        us(p.max_us),
        p.count
    )
}

/// Per joint, rad, as the run's own table prints them.
fn rad(e: &[f64; 3]) -> String {
    format!("{:>10.3e} {:>10.3e} {:>10.3e}", e[0], e[1], e[2])
}

/// The screen: a few lines of text.
pub fn lines(info: &RunInfo, total: Option<u64>, s: &Snapshot, status: &Status) -> Vec<String> {
    let law = info.law.map_or("?".into(), |l| l.to_string());
    let mode = info.mode.map_or("?", |m| m.name());
    let progress = match total {
        Some(t) if t > 0 => format!(
            "{} / {t} ({:.1} %)",
            s.ticks,
            100.0 * s.ticks.min(t) as f64 / t as f64
        ),
        _ => s.ticks.to_string(),
    };
    let since = s.since_tick.map_or("-".into(), |k| k.to_string());
    let mut l = vec![
        format!("run {}   law {law}   mode {mode}", info.run_id),
        format!(
            "config   {}",
            info.config
                .as_ref()
                .map_or("? (not found)".into(), |c| c.display().to_string())
        ),
        format!("status   {}", status.text()),
        format!("ticks    {progress}"),
        format!(
            "misses   {} (ratio {:.2e})   observer missed {} ticks",
            s.misses, s.miss_ratio, s.observer_gaps
        ),
        match (s.realtime_factor, s.longest_pause) {
            (Some(f), Some((ms, k))) => format!(
                "sim time real-time factor {f:.4}: the plant paused {} time(s), {:.1} ms (longest {ms:.1} ms at tick {k})",
                s.pauses, s.paused_ms
            ),
            (Some(f), None) => {
                format!("sim time real-time factor {f:.4}: no pause of the plant's clock")
            }
            (None, _) => "sim time real-time factor -".into(),
        },
        String::new(),
        format!(
            "{:<15} {:>9} {:>9} {:>9} {:>9}  µs, since tick {since}",
            "", "p50", "p99", "p99.9", "max"
        ),
        pct_row("round trip", &s.round_trip),
        match &s.wake_lateness {
            Some(w) => pct_row("wake lateness", w),
            None => format!(
                "{:<15} {:>9}  (no deadline in {mode} mode)",
                "wake lateness", "-"
            ),
        },
        String::new(),
    ];
    match (&s.err_now, &s.err_rms) {
        (Some((k, now)), Some(rms)) => {
            l.push(format!(
                "{:<26} {:>10} {:>10} {:>10}",
                "tracking error q_d - q, rad", "joint 1", "joint 2", "joint 3"
            ));
            l.push(format!("{:<26} {}", format!("  now (tick {k})"), rad(now)));
            l.push(format!(
                "{:<26} {}",
                format!("  RMS since tick {since}"),
                rad(rms)
            ));
        }
        _ => l.push(match &info.config {
            Some(_) => "tracking error: no state seen yet".into(),
            None => "tracking error: unknown (the run's config was not found)".into(),
        }),
    }
    l
}

/// One `key=value` line for `--plain`.
pub fn plain(info: &RunInfo, s: &Snapshot, status: &Status) -> String {
    let p = |name: &str, p: &Percentiles| {
        format!(
            " {name}_p50_us={:.2} {name}_p99_us={:.2} {name}_p999_us={:.2} {name}_max_us={:.2}",
            p.p50_us, p.p99_us, p.p999_us, p.max_us
        )
    };
    let mut line = format!(
        "run={} law={} mode={} status={} ticks={} misses={} miss_ratio={:.3e} observer_missed={}",
        info.run_id,
        info.law.map_or("?".into(), |l| l.to_string()),
        info.mode.map_or("?", |m| m.name()),
        match status {
            Status::Waiting => "waiting",
            Status::Running => "running",
            Status::Completed { .. } => "completed",
            Status::Stopped { .. } => "stopped",
        },
        s.ticks,
        s.misses,
        s.miss_ratio,
        s.observer_gaps
    );
    if let Some(f) = s.realtime_factor {
        line.push_str(&format!(
            " rtf={f:.4} pauses={} paused_ms={:.1}",
            s.pauses, s.paused_ms
        ));
    }
    line.push_str(&p("rt", &s.round_trip));
    if let Some(w) = &s.wake_lateness {
        line.push_str(&p("wake", w));
    }
    if let (Some((_, now)), Some(rms)) = (&s.err_now, &s.err_rms) {
        // The largest joint's.
        let max = |e: &[f64; 3]| e.iter().fold(0.0f64, |a, x| a.max(x.abs()));
        line.push_str(&format!(
            " err_now_rad={:.3e} err_rms_rad={:.3e}",
            max(now),
            max(rms)
        ));
    }
    line
}
