//! `deltaloop replay RUN_DIR`: re-runs a finished run in-process from what its folder recorded and
//! checks that it reproduces its `trace.csv` byte for byte.
//!
//! A process run differs from the in-process loop only in what the transport did, and the trace
//! records all of it per tick: which states the controller answered (`reply`: applied, late,
//! skipped, missed) and when each applied command reached the drives (`arrival_ns`). The plant and
//! the controller are deterministic given those and `config.toml` (sensor noise has its seed), so
//! the replay steps the same two ticks with the same inputs, and must write the same bytes. It
//! reads the trace as it goes: memory does not grow with the run.

use crate::lawrun::{self, Keep, LawRun};
use crate::output;
use crate::study::Study;
use anyhow::{Context, Result, bail};
use deltaloop_config::{Law, RunConfig};
use deltaloop_plant::Arrival;
use std::path::{Path, PathBuf};

/// What one tick of the recorded trace says about the transport.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Recorded {
    law: Law,
    k: u64,
    fate: Fate,
    /// A_k − t_k, ns, for an applied command.
    arrival_ns: Option<u64>,
}

/// The `reply` column.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Fate {
    Applied,
    Late,
    Skipped,
    Missed,
}

/// The recorded ticks of a trace, read one row at a time.
struct TraceRows {
    path: PathBuf,
    rows: csv::StringRecordsIntoIter<std::fs::File>,
    line: u64,
    cols: [usize; 4],
    peeked: Option<Recorded>,
}

impl TraceRows {
    fn open(path: &Path) -> Result<Self> {
        let mut r = csv::ReaderBuilder::new()
            .flexible(false)
            .from_path(path)
            .with_context(|| format!("cannot read {}", path.display()))?;
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
        let cols = [col("law")?, col("k")?, col("reply")?, col("arrival_ns")?];
        Ok(Self {
            path: path.to_path_buf(),
            rows: r.into_records(),
            line: 1,
            cols,
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
        let law = Law::parse(law).map_err(|e| anyhow::anyhow!("{}: column law: {e}", at()))?;
        let k = k.parse().map_err(|_| {
            anyhow::anyhow!(
                "{}: column k = {} is not a tick number",
                at(),
                deltaloop_config::config::show_str(k)
            )
        })?;
        let fate = match reply {
            "applied" => Fate::Applied,
            "late" => Fate::Late,
            "skipped" => Fate::Skipped,
            "missed" => Fate::Missed,
            // The supervisor recorded the tick without the plant's telemetry: what the plant did
            // is not known, so the run cannot be re-run from it. Name the whole stretch.
            "unknown" => {
                let (first, mut last) = (k, k);
                while let Some(Ok(row)) = self.rows.next() {
                    let [_, k, reply, _] = self.cols.map(|c| row.get(c).unwrap_or(""));
                    match k.parse::<u64>() {
                        Ok(k) if reply == "unknown" && k == last + 1 => last = k,
                        _ => break,
                    }
                }
                bail!(
                    "{}: the run lost ticks {first}..{last} (the plant's telemetry of those ticks never reached the supervisor, so their `reply` is unknown); only a run with every tick can be replayed",
                    at()
                )
            }
            other => bail!(
                "{}: column reply = {}: expected applied, late, skipped or missed",
                at(),
                deltaloop_config::config::show_str(other)
            ),
        };
        let arrival_ns = match (fate, arrival) {
            (Fate::Applied, a) => Some(a.parse().map_err(|_| {
                anyhow::anyhow!(
                    "{}: column arrival_ns = {}: an applied reply needs its arrival in ns",
                    at(),
                    deltaloop_config::config::show_str(a)
                )
            })?),
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

/// Replays `law` from the recorded rows, writing its trace rows to `keep`.
fn replay_law(study: &Study, law: Law, rows: &mut TraceRows, keep: &Keep) -> Result<LawRun> {
    let mut rec = lawrun::recorder(study, law, keep)?;
    let mut plant = study
        .plant_side()
        .context("the recorded initial configuration")?;
    let mut ctrl = study.controller_side(law);
    let delay_ns = study.config.transport_delay_ns();
    let mut skipped_before = 0u64;
    let mut last = None;
    while let Some(r) = rows.next_of(law)? {
        let k = plant.tick();
        if r.k != k {
            let why = if r.k > k {
                format!(
                    "the run lost ticks {k}..{} (or the file was edited)",
                    r.k - 1
                )
            } else {
                "the file was edited (ticks out of order)".into()
            };
            bail!(
                "{} line {}: tick {} where tick {k} was due: {why}; only a run with every tick can be replayed",
                rows.path.display(),
                rows.line,
                r.k
            );
        }
        let state = plant.state();
        let reference = study.reference.row(k as usize).joint;
        let (reply, arrival) = match r.fate {
            Fate::Applied | Fate::Late => {
                let mut reply = ctrl.answer(&state, &reference);
                reply.skipped = std::mem::take(&mut skipped_before);
                let arrival = match (r.fate, r.arrival_ns) {
                    (Fate::Applied, Some(a)) => {
                        Arrival::ReplyAfter(reply, a.saturating_sub(delay_ns))
                    }
                    _ => Arrival::Missed,
                };
                (Some(reply), arrival)
            }
            Fate::Skipped => {
                skipped_before += 1;
                (None, Arrival::Missed)
            }
            Fate::Missed => {
                skipped_before = 0;
                (None, Arrival::Missed)
            }
        };
        last = Some(k);
        if !rec.tick(&state, reply.as_ref()) {
            return lawrun::finish(rec, None);
        }
        match plant.advance(arrival) {
            Ok(tel) => rec.applied(Some(&tel)),
            Err(stop) => {
                rec.plant_failed(stop.cause().to_string());
                return lawrun::finish(rec, None);
            }
        }
    }
    // A run that reached its last tick N closes with the state N + 1, as it did when recorded.
    let after = (last == Some(study.reference.n as u64)).then(|| plant.state());
    lawrun::finish(rec, after.as_ref())
}

/// How a replay compared.
#[derive(Debug, PartialEq)]
pub enum Verdict {
    /// The replayed trace equals the recorded one, byte for byte (`ticks` rows).
    Identical { ticks: u64 },
    /// They first differ on this line of `trace.csv`.
    Differs {
        line: u64,
        tick: String,
        column: String,
        recorded: String,
        replayed: String,
    },
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
    let mut rows = TraceRows::open(&recorded)?;
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let mut laws = Vec::new();
    let mut runs = Vec::new();
    while let Some(first) = rows.next()? {
        if laws.contains(&first.law) {
            bail!(
                "{} line {}: law `{}` appears twice",
                recorded.display(),
                rows.line,
                first.law
            );
        }
        rows.peeked = Some(first);
        let keep = Keep {
            trace: Some(output::trace_part(out, first.law)),
            records: false,
        };
        runs.push(replay_law(&study, first.law, &mut rows, &keep)?);
        laws.push(first.law);
        // A law whose replay ended before its recorded rows did: skip the rest, the comparison
        // names the first difference.
        while rows.next_of(first.law)?.is_some() {}
    }
    output::join_trace(out, &laws)?;
    Ok((compare(&recorded, &out.join("trace.csv"))?, runs))
}

/// Compares two trace files line by line.
fn compare(recorded: &Path, replayed: &Path) -> Result<Verdict> {
    use std::io::BufRead;
    let open = |p: &Path| -> Result<std::io::Lines<std::io::BufReader<std::fs::File>>> {
        Ok(std::io::BufReader::new(
            std::fs::File::open(p).with_context(|| format!("cannot read {}", p.display()))?,
        )
        .lines())
    };
    let (mut a, mut b) = (open(recorded)?, open(replayed)?);
    let header: Vec<String> = match a.next() {
        Some(h) => h?.split(',').map(str::to_string).collect(),
        None => Vec::new(),
    };
    let _ = b.next();
    let mut line = 1u64;
    loop {
        line += 1;
        let (x, y) = (a.next().transpose()?, b.next().transpose()?);
        if x == y {
            if x.is_none() {
                return Ok(Verdict::Identical { ticks: line - 2 });
            }
            continue;
        }
        let (x, y) = (x.unwrap_or_default(), y.unwrap_or_default());
        let (xs, ys): (Vec<&str>, Vec<&str>) = (x.split(',').collect(), y.split(',').collect());
        let col = (0..xs.len().max(ys.len()))
            .find(|&i| xs.get(i) != ys.get(i))
            .unwrap_or(0);
        return Ok(Verdict::Differs {
            line,
            tick: xs.get(1).or(ys.get(1)).unwrap_or(&"").to_string(),
            column: header.get(col).cloned().unwrap_or_else(|| col.to_string()),
            recorded: xs.get(col).unwrap_or(&"(no row)").to_string(),
            replayed: ys.get(col).unwrap_or(&"(no row)").to_string(),
        });
    }
}

/// One line for the terminal.
pub fn describe(v: &Verdict, run_dir: &Path) -> String {
    match v {
        Verdict::Identical { ticks } => format!(
            "replay of {}: trace.csv reproduced byte for byte ({ticks} rows)",
            run_dir.display()
        ),
        Verdict::Differs {
            line,
            tick,
            column,
            recorded,
            replayed,
        } => format!(
            "replay of {}: trace.csv differs first at line {line} (tick {tick}), column {column}: recorded {recorded}, replayed {replayed}",
            run_dir.display()
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
    measured: &[&crate::metrics::LawMetrics],
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
pub fn max_rms(m: &crate::metrics::LawMetrics) -> f64 {
    m.rms_rad.into_iter().fold(0.0, f64::max)
}

/// "measured latency cost" lines: each law's RMS against the same ticks with ideal timing.
pub fn latency_cost(measured: &[&crate::metrics::LawMetrics], ideal: &[(Law, f64)]) -> Vec<String> {
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
