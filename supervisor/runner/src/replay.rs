//! `deltaloop replay RUN_DIR`: re-runs a finished run in-process from what its folder recorded and
//! checks that it reproduces its `trace.csv` byte for byte.
//!
//! A process run differs from the in-process loop only in what the transport did, and the trace
//! records all of it per tick: which states the controller answered (`reply`: applied, late,
//! skipped, missed) and when each applied command reached the drives (`arrival_ns`). The plant and
//! the controller are deterministic given those and `config.toml` (sensor noise has its seed), so
//! the replay steps the same two ticks with the same inputs, and must write the same bytes. It
//! reads the trace as it goes: memory does not grow with the run.

use crate::inproc::{self, Schedule};
use crate::lawrun::{self, Keep, LawRun};
use anyhow::{Context, Result, bail};
use deltaloop_config::files;
use deltaloop_config::{Law, RunConfig};
use deltaloop_plant_tick::ReplyOutcome;
use deltaloop_report as output;
use deltaloop_study::Study;
use deltaloop_study::record::ReplyFate;
use std::path::{Path, PathBuf};

/// What one tick of the recorded trace says about the transport.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Recorded {
    pub law: Law,
    /// The tick k.
    pub k: u64,
    /// What became of the controller's reply to it.
    pub fate: ReplyFate,
    /// A_k − t_k, ns, for an applied command (None on the row a run diverged on).
    pub arrival_ns: Option<u64>,
}

/// The recorded ticks of a trace, read one row at a time.
struct TraceRows {
    path: PathBuf,
    rows: csv::StringRecordsIntoIter<files::Capped>,
    line: u64,
    cols: [usize; 4],
    /// What `arrival_ns` of an applied reply may be, ns (see [`output::trace::arrivals`]).
    arrival: std::ops::RangeInclusive<u64>,
    peeked: Option<Recorded>,
}

impl TraceRows {
    fn open(path: &Path, study: &Study) -> Result<Self> {
        let file = files::open_regular(path, output::trace::max_bytes(study), "this run's trace")
            .map_err(|e| anyhow::anyhow!("cannot read {}: {e}", path.display()))?;
        let mut r = csv::ReaderBuilder::new().flexible(false).from_reader(file);
        let h = r
            .headers()
            .with_context(|| format!("{}: no header line", path.display()))?
            .clone();
        let col = |name: &str| {
            h.iter().position(|c| c == name).with_context(|| {
                format!(
                    "{} line 1: no column `{name}` (a trace written before deltaloop recorded arrivals cannot be replayed)",
                    path.display()
                )
            })
        };
        use deltaloop_report::trace::{ARRIVAL, K, LAW, REPLY};
        let cols = [
            col(LAW.name)?,
            col(K.name)?,
            col(REPLY.name)?,
            col(ARRIVAL.name)?,
        ];
        Ok(Self {
            path: path.to_path_buf(),
            rows: r.into_records(),
            line: 1,
            cols,
            arrival: output::trace::arrivals(study),
            peeked: None,
        })
    }

    /// The next row, parsed; None at the end of the file.
    fn next(&mut self) -> Result<Option<Recorded>> {
        if let Some(r) = self.peeked.take() {
            return Ok(Some(r));
        }
        let Some(row) = self.rows.next() else {
            return Ok(None);
        };
        self.line += 1;
        let at = || format!("{} line {}", self.path.display(), self.line);
        let row = row.with_context(at)?;
        let [law, k, reply, arrival] = self.cols.map(|c| row.get(c).unwrap_or(""));
        let law = output::trace::law_cell(law).with_context(at)?;
        let k = output::trace::tick_cell(k).with_context(at)?;
        let fate = match ReplyFate::parse(reply).ok() {
            Some(fate) => fate,
            // The supervisor recorded the tick without knowing what the plant did with it (its
            // telemetry never came, or its reply was lost on the link): the run cannot be re-run
            // from it. Name the whole stretch.
            None if reply == "unknown" => {
                let (first, mut last) = (k, k);
                while let Some(Ok(row)) = self.rows.next() {
                    let [_, k, reply, _] = self.cols.map(|c| row.get(c).unwrap_or(""));
                    match k.parse::<u64>() {
                        Ok(k) if reply == "unknown" && k == last + 1 => last = k,
                        _ => break,
                    }
                }
                bail!(
                    "{}: the run lost ticks {first}..{last} (their `reply` is unknown: the plant's telemetry of those ticks never reached the supervisor, or the replies of a controller on another host were lost on the link); only a run with every tick can be replayed",
                    at()
                )
            }
            None => {
                let allowed = deltaloop_names::one_of::<ReplyFate>();
                let e = output::trace::bad_cell(output::trace::REPLY.name, reply, &allowed);
                bail!("{}: {e}", at())
            }
        };
        let arrival_ns = match (fate, arrival) {
            // The row the divergence rule ended the run on: recorded before the drives took its
            // reply, so it has none (checked in `step`: only a law's last row may be so).
            (ReplyFate::Applied, "") => None,
            (ReplyFate::Applied, a) => {
                let ns: u64 = a.parse().map_err(|_| {
                    anyhow::anyhow!(
                        "{}: column arrival_ns = {}: an applied reply needs its arrival in ns",
                        at(),
                        deltaloop_config::show_str(a)
                    )
                })?;
                if !self.arrival.contains(&ns) {
                    bail!(
                        "{} (tick {k}): column arrival_ns = {ns} is out of range: an applied reply arrives {}..={} ns after its tick (the transport delay, plus at most the run's span)",
                        at(),
                        self.arrival.start(),
                        self.arrival.end()
                    );
                }
                Some(ns)
            }
            _ => None,
        };
        Ok(Some(Recorded {
            law,
            k,
            fate,
            arrival_ns,
        }))
    }

    /// The next row if it belongs to `law`.
    fn next_of(&mut self, law: Law) -> Result<Option<Recorded>> {
        match self.next()? {
            Some(r) if r.law == law => Ok(Some(r)),
            other => {
                self.peeked = other;
                Ok(None)
            }
        }
    }
}

/// Replay's check of a law's rows: its ticks count 0, 1, 2, … with none lost or repeated; Err
/// names the row (`line` of `path`) whose tick `k` is not the tick `due`.
fn tick_due(path: &Path, line: u64, k: u64, due: u64) -> Result<()> {
    if k == due {
        return Ok(());
    }
    let why = if k > due {
        format!(
            "the run lost ticks {due}..{} (or the file was edited)",
            k - 1
        )
    } else {
        "the file was edited (ticks out of order)".into()
    };
    bail!(
        "{} line {line}: tick {k} where tick {due} was due: {why}; only a run with every tick can be replayed",
        path.display()
    )
}

/// The error for an applied reply without its arrival on `line`, which is not its law's last.
fn no_arrival(path: &Path, line: u64) -> anyhow::Error {
    anyhow::anyhow!(
        "{} line {line}: column arrival_ns is empty: an applied reply needs its arrival in ns (only the row a run diverged on has none)",
        path.display()
    )
}

/// The error for a law whose rows start again on `line`.
fn law_twice(path: &Path, line: u64, law: Law) -> anyhow::Error {
    anyhow::anyhow!("{} line {line}: law `{law}` appears twice", path.display())
}

/// The recorded rows of one law as an arrival schedule for the in-process loop.
struct Replayed<'r> {
    rows: &'r mut TraceRows,
    law: Law,
    /// The transport delay D, ns: `arrival_ns` counts from t_k, the plant from t_k + D.
    delay_ns: u64,
}

impl Schedule for Replayed<'_> {
    fn outcome(&mut self, k: u64) -> Result<Option<ReplyOutcome>> {
        let Some(r) = self.rows.next_of(self.law)? else {
            return Ok(None);
        };
        tick_due(&self.rows.path, self.rows.line, r.k, k)?;
        // Regression: every run that diverged by the tracking rule was refused. Its last row (an
        // applied reply without its arrival) is replayed as recorded; the rule ends the replay on
        // it before any arrival counts.
        if r.fate == ReplyFate::Applied && r.arrival_ns.is_none() {
            let line = self.rows.line;
            if self.rows.next_of(self.law)?.is_some() {
                return Err(no_arrival(&self.rows.path, line));
            }
        }
        Ok(Some(r.fate.recorded(r.arrival_ns, self.delay_ns)))
    }

    /// A replay runs to its end: Ctrl-C does not cut it into a trace that differs.
    fn interruptible(&self) -> bool {
        false
    }
}

/// Replays `law` from the recorded rows, writing its trace rows to `keep`.
fn replay_law(study: &Study, law: Law, rows: &mut TraceRows, keep: &Keep) -> Result<LawRun> {
    let rec = lawrun::recorder(study, law, keep)?;
    let plant = study
        .plant_side()
        .context("the recorded initial configuration")?;
    let mut schedule = Replayed {
        rows,
        law,
        delay_ns: study.config.transport_delay_ns(),
    };
    inproc::run_schedule(study, law, rec, plant, &mut schedule)
}

/// How a replay compared.
#[derive(Debug, PartialEq)]
pub enum Verdict {
    /// The replayed trace equals the recorded one, byte for byte (`ticks` rows), but for the
    /// columns `unknown` names: the law's internals a ROS 2 node does not report (its command
    /// carries only τ), which the replay's law computes.
    Identical { ticks: u64, unknown: Vec<String> },
    /// They first differ on this line of `trace.csv` (the header: no tick).
    Differs {
        line: u64,
        tick: Option<String>,
        column: String,
        recorded: String,
        replayed: String,
    },
}

/// Reads the transport's part of a finished run's trace, row by row in the file's order, checked
/// as a replay checks it (each row's cells; each law's rows in one stretch, its ticks 0, 1, 2, …
/// with none lost or repeated; an applied reply without its arrival only on a law's last row),
/// into `each`: each tick's law and its reply's outcome as the plant took it (the recorded
/// arrival less the run's transport delay, [`ReplyFate::recorded`], as the replay takes it);
/// returns the run's study. Memory does not grow with the run.
pub fn read_recorded(run_dir: &Path, mut each: impl FnMut(Law, ReplyOutcome)) -> Result<Study> {
    let cfg = RunConfig::from_file(&run_dir.join("config.toml"))?;
    if !cfg.record.trace {
        bail!(
            "{} has no trace.csv: the run was recorded with record.trace = false (its config.toml)",
            run_dir.display()
        );
    }
    let study = Study::new(cfg).context("the recorded scenario")?;
    let mut rows = TraceRows::open(&run_dir.join("trace.csv"), &study)?;
    let delay_ns = study.config.transport_delay_ns();
    let mut laws: Vec<Law> = Vec::new();
    let (mut due, mut no_arrival_on) = (0u64, None);
    while let Some(r) = rows.next()? {
        if laws.last() != Some(&r.law) {
            if laws.contains(&r.law) {
                return Err(law_twice(&rows.path, rows.line, r.law));
            }
            laws.push(r.law);
            due = 0;
        } else if let Some(line) = no_arrival_on {
            return Err(no_arrival(&rows.path, line));
        }
        tick_due(&rows.path, rows.line, r.k, due)?;
        due += 1;
        no_arrival_on =
            (r.fate == ReplyFate::Applied && r.arrival_ns.is_none()).then_some(rows.line);
        each(r.law, r.fate.recorded(r.arrival_ns, delay_ns));
    }
    Ok(study)
}

/// Replays the run in `run_dir` into `out` (its `trace.csv` and nothing else) and compares.
pub fn replay(run_dir: &Path, out: &Path) -> Result<(Verdict, Vec<LawRun>)> {
    let cfg = RunConfig::from_file(&run_dir.join("config.toml"))?;
    if !cfg.record.trace {
        bail!(
            "{} has no trace.csv to replay: the run was recorded with record.trace = false (its config.toml)",
            run_dir.display()
        );
    }
    let study = Study::new(cfg).context("the recorded scenario")?;
    let recorded = run_dir.join("trace.csv");
    let mut rows = TraceRows::open(&recorded, &study)?;
    // Regression: a header alone was "reproduced byte for byte (0 rows)".
    rows.peeked = rows.next()?;
    if rows.peeked.is_none() {
        bail!(
            "{} has no ticks (a header and no rows): there is nothing to replay",
            recorded.display()
        );
    }
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let mut laws = Vec::new();
    let mut runs = Vec::new();
    while let Some(first) = rows.next()? {
        if laws.contains(&first.law) {
            return Err(law_twice(&recorded, rows.line, first.law));
        }
        rows.peeked = Some(first);
        let keep = Keep {
            trace: Some(output::trace_part(out, first.law)),
            ..Keep::default()
        };
        runs.push(replay_law(&study, first.law, &mut rows, &keep)?);
        laws.push(first.law);
        // A law whose replay ended before its recorded rows did: skip the rest, the comparison
        // names the first difference.
        while rows.next_of(first.law)?.is_some() {}
    }
    output::join_trace(out, &laws)?;
    let cap = output::trace::max_bytes(&study);
    // A ROS 2 node's replies (`--controller ros2`) carried τ only: the recorded internals are
    // zeros the replay's law does not reproduce.
    let unknown = if crate::procs::ros2_robot_answers(&study.config) {
        UNKNOWN_INTERNALS
    } else {
        &[]
    };
    Ok((
        compare(&recorded, &out.join("trace.csv"), cap, unknown)?,
        runs,
    ))
}

/// The trace columns of the law's internals (s, N̂), per joint.
const UNKNOWN_INTERNALS: &[&str] = &["s_1", "s_2", "s_3", "n_hat_1", "n_hat_2", "n_hat_3"];

/// Compares two trace files byte for byte (header and line ends included), and names the line
/// and column of the first difference. Lines are read one at a time (at most `cap` bytes of the
/// recorded file): memory does not grow with the run.
fn compare(recorded: &Path, replayed: &Path, cap: u64, unknown: &[&str]) -> Result<Verdict> {
    use std::io::BufRead;
    let open = |p: &Path| -> Result<std::io::BufReader<files::Capped>> {
        Ok(std::io::BufReader::new(
            files::open_regular(p, cap, "this run's trace")
                .map_err(|e| anyhow::anyhow!("cannot read {}: {e}", p.display()))?,
        ))
    };
    let (mut a, mut b) = (open(recorded)?, open(replayed)?);
    let (mut x, mut y) = (Vec::new(), Vec::new());
    let mut header = Vec::new();
    let mut line = 0u64;
    loop {
        x.clear();
        y.clear();
        let read = |r: &mut std::io::BufReader<files::Capped>, buf: &mut Vec<u8>, p: &Path| {
            r.read_until(b'\n', buf)
                .with_context(|| format!("cannot read {}", p.display()))
        };
        let (nx, ny) = (
            read(&mut a, &mut x, recorded)?,
            read(&mut b, &mut y, replayed)?,
        );
        line += 1;
        if line == 1 {
            header = fields(&x);
        }
        let same_known = || {
            let (fx, fy) = (fields(&x), fields(&y));
            split_end(&x).1 == split_end(&y).1
                && fx.len() == fy.len()
                && (0..fx.len()).all(|i| {
                    fx[i] == fy[i] || header.get(i).is_some_and(|h| unknown.contains(&h.as_str()))
                })
        };
        if x == y || (line > 1 && !unknown.is_empty() && nx > 0 && ny > 0 && same_known()) {
            if nx == 0 {
                return Ok(Verdict::Identical {
                    ticks: line.saturating_sub(2),
                    unknown: unknown.iter().map(|c| c.to_string()).collect(),
                });
            }
            continue;
        }
        return Ok(first_difference(
            line,
            &header,
            (nx > 0).then_some(&x),
            (ny > 0).then_some(&y),
        ));
    }
}

/// The fields of a line, its line end cut.
fn fields(line: &[u8]) -> Vec<String> {
    let (body, _) = split_end(line);
    String::from_utf8_lossy(body)
        .split(',')
        .map(str::to_string)
        .collect()
}

/// A line and its end (`\n`, `\r\n`, or none at the end of a file).
fn split_end(line: &[u8]) -> (&[u8], &[u8]) {
    let body = line.strip_suffix(b"\n").unwrap_or(line);
    let body = body.strip_suffix(b"\r").unwrap_or(body);
    line.split_at(body.len())
}

/// Where two different lines (None: the file has ended) first differ.
fn first_difference(
    line: u64,
    header: &[String],
    x: Option<&Vec<u8>>,
    y: Option<&Vec<u8>>,
) -> Verdict {
    use deltaloop_config::show_str;
    let (xs, ys) = (
        x.map_or_else(Vec::new, |x| fields(x)),
        y.map_or_else(Vec::new, |y| fields(y)),
    );
    let tick = (line > 1).then(|| xs.get(1).or(ys.get(1)).cloned().unwrap_or_default());
    let shown = |f: Option<&String>| f.map_or_else(|| "(no row)".to_string(), |f| show_str(f));
    if let (Some(x), Some(y), true) = (x, y, xs == ys) {
        // Same fields: the line ends differ.
        let end = |l: &[u8]| match split_end(l).1 {
            b"" => "none (the file ends)".to_string(),
            e => show_str(&String::from_utf8_lossy(e)),
        };
        return Verdict::Differs {
            line,
            tick,
            column: "line end".into(),
            recorded: end(x),
            replayed: end(y),
        };
    }
    let col = (0..xs.len().max(ys.len()))
        .find(|&i| xs.get(i) != ys.get(i))
        .unwrap_or(0);
    Verdict::Differs {
        line,
        tick,
        column: header.get(col).cloned().unwrap_or_else(|| col.to_string()),
        recorded: shown(xs.get(col)),
        replayed: shown(ys.get(col)),
    }
}

/// One line for the terminal.
pub fn describe(v: &Verdict, run_dir: &Path) -> String {
    match v {
        Verdict::Identical { ticks, unknown } if unknown.is_empty() => format!(
            "replay of {}: trace.csv reproduced byte for byte ({ticks} rows)",
            run_dir.display()
        ),
        Verdict::Identical { ticks, unknown } => format!(
            "replay of {}: trace.csv reproduced byte for byte ({ticks} rows) but for columns {} (the law's internals: the ROS 2 node's commands carry only τ)",
            run_dir.display(),
            unknown.join(", ")
        ),
        Verdict::Differs {
            line,
            tick,
            column,
            recorded,
            replayed,
        } => format!(
            "replay of {}: trace.csv differs first at line {line} ({}), column {column}: recorded {recorded}, replayed {replayed}",
            run_dir.display(),
            tick.as_ref()
                .map_or_else(|| "the header".to_string(), |t| format!("tick {t}"))
        ),
    }
}

/// The max-joint RMS tracking error with ideal timing (in-process: no latency beyond the
/// configured transport delay, no misses), rad, of each measured law over the same ticks its
/// metrics cover (0..=`ticks`): a run that diverged, faulted or stopped early is compared with
/// the ideal run over its own span, not over the whole scenario (regression: a realtime soak that
/// diverged 49 s into its hour spent two minutes simulating the ideal hour, and compared 49 s
/// with 60 minutes).
pub fn ideal_rms(
    study: &Study,
    measured: &[&deltaloop_study::record::metrics::LawMetrics],
) -> Result<Vec<(Law, f64)>> {
    measured
        .iter()
        .map(|m| {
            let run = crate::inproc::run_law_through(study, m.law, &Keep::default(), m.ticks)?;
            Ok((m.law, max_rms(&run.metrics)))
        })
        .collect()
}

/// The largest per-joint RMS tracking error, rad.
pub fn max_rms(m: &deltaloop_study::record::metrics::LawMetrics) -> f64 {
    m.rms_rad.into_iter().fold(0.0, f64::max)
}

/// "measured latency cost" lines: each law's RMS against the same ticks with ideal timing.
pub fn latency_cost(
    measured: &[&deltaloop_study::record::metrics::LawMetrics],
    ideal: &[(Law, f64)],
) -> Vec<String> {
    measured
        .iter()
        .filter_map(|m| {
            let law = m.law;
            let &(_, best) = ideal.iter().find(|(l, _)| *l == law)?;
            let rms = max_rms(m);
            Some(format!(
                "`{law}`: measured latency cost: RMS ×{:.3} vs the same run with ideal timing ({rms:.4e} vs {best:.4e} rad, ticks 0..={})",
                rms / best,
                m.ticks
            ))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn differs(a: &str, b: &str) -> Verdict {
        let header = fields(b"law,k,t_s\n");
        first_difference(
            3,
            &header,
            (!a.is_empty()).then(|| a.as_bytes().to_vec()).as_ref(),
            (!b.is_empty()).then(|| b.as_bytes().to_vec()).as_ref(),
        )
    }

    /// Regression: line ends were not compared (a CRLF trace was "byte for byte"). The first
    /// difference is named: a field by its column, else the line end.
    #[test]
    fn regression_line_ends_count_and_the_first_difference_is_named() {
        let d = |tick: &str, column: &str, recorded: &str, replayed: &str| Verdict::Differs {
            line: 3,
            tick: Some(tick.into()),
            column: column.into(),
            recorded: recorded.into(),
            replayed: replayed.into(),
        };
        for (recorded, replayed, want) in [
            (
                "tdc,1,3e-4\r\n",
                "tdc,1,3e-4\n",
                d("1", "line end", "\"\\r\\n\"", "\"\\n\""),
            ),
            (
                "tdc,1,3e-4",
                "tdc,1,3e-4\n",
                d("1", "line end", "none (the file ends)", "\"\\n\""),
            ),
            (
                "tdc,1,3e-4\n",
                "tdc,1,4e-4\n",
                d("1", "t_s", "\"3e-4\"", "\"4e-4\""),
            ),
            ("tdc,1,3e-4\n", "", d("1", "law", "\"tdc\"", "(no row)")),
        ] {
            assert_eq!(
                differs(recorded, replayed),
                want,
                "{recorded:?} vs {replayed:?}"
            );
        }
    }
}
