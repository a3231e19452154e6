//! Where `whatif`'s latencies come from: a realtime run folder (each tick's fate and
//! `arrival_ns`), an HdrHistogram file (`.hgrm` percentile text or `.hlog` interval log), or a
//! text file of round-trip latencies in µs, one per line. A latency means what `arrival_ns`
//! means: the reply's arrival after the tick's state was published, on the plant's clock, less
//! the configured transport delay (which the scenario adds back).

use anyhow::{Context, Result, anyhow, bail};
use deltaloop_config::{Law, LoopMode, RunConfig, files};
use deltaloop_plant_tick::ReplyOutcome;
use deltaloop_runner::replay;
use std::path::{Path, PathBuf};

deltaloop_names::text_enum! {
    "lowercase", "latency unit";
    /// The unit of a file's latencies (`--latency-unit`).
    pub enum Unit {
        Ns,
        Us,
        Ms,
        S,
    }
}

impl Unit {
    /// Nanoseconds in one of this unit.
    pub fn ns(self) -> f64 {
        match self {
            Unit::Ns => 1.0,
            Unit::Us => 1e3,
            Unit::Ms => 1e6,
            Unit::S => 1e9,
        }
    }

    /// The unit's symbol in messages (`µs`).
    fn symbol(self) -> &'static str {
        match self {
            Unit::Ns => "ns",
            Unit::Us => "µs",
            Unit::Ms => "ms",
            Unit::S => "s",
        }
    }

    /// The unit a comment line names ("values in microseconds", "values in ns"), if any.
    fn named_in(comment: &str) -> Option<Self> {
        let c = comment.to_ascii_lowercase();
        let at = c.find("values in ")? + "values in ".len();
        let word: String = c[at..]
            .chars()
            .take_while(|ch| ch.is_alphanumeric() || *ch == 'µ')
            .collect();
        match word.as_str() {
            "ns" | "nanoseconds" => Some(Unit::Ns),
            "us" | "µs" | "microseconds" => Some(Unit::Us),
            "ms" | "milliseconds" => Some(Unit::Ms),
            "s" | "seconds" => Some(Unit::S),
            _ => None,
        }
    }
}

/// One source's latencies.
#[derive(Clone, Debug, PartialEq)]
pub enum Latencies {
    /// Recorded in order, one per tick (a run folder: one sequence per law; a text file: one).
    Sequences(Vec<Vec<ReplyOutcome>>),
    /// A distribution without order: (latency ns, count), ascending.
    Histogram(Vec<(u64, u64)>),
}

/// What kind of file or folder a source is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    RunFolder,
    Hgrm,
    Hlog,
    Text,
}

impl Kind {
    pub fn name(self) -> &'static str {
        match self {
            Kind::RunFolder => "run folder",
            Kind::Hgrm => "hgrm",
            Kind::Hlog => "hlog",
            Kind::Text => "text",
        }
    }
}

/// A loaded `--latency` source.
#[derive(Clone, Debug, PartialEq)]
pub struct Source {
    pub path: PathBuf,
    pub kind: Kind,
    pub latencies: Latencies,
    /// A run folder's sequences by law, in the file's order (for `--as-recorded`).
    pub laws: Vec<Law>,
    /// How many latencies (ticks, or a histogram's count) it held when loaded.
    pub ticks: u64,
    /// A run folder's `config.toml` (checked against the what-if's scenario).
    pub recorded: Option<Box<RunConfig>>,
}

/// The most ticks a text record may span once its lines are spread over their period
/// (`--record-period-us`): 16 M ticks (80 minutes at 3.3 kHz, 256 MB of outcomes).
pub const MAX_PERIOD_TICKS: u64 = 1 << 24;

/// `--record-period-us P`: each text record's lines, one every `period_us`, put on the
/// scenario's ticks of `ts_us`: tick k takes line ⌊k·Ts/P⌋, for the record's whole duration
/// (⌊lines·P/Ts⌋ ticks). A burst keeps its duration in time: a 3 ms burst logged at 1 kHz is 10
/// ticks at 3.3 kHz, not 3. Err (one line) for a P out of range, a record that would span more
/// than [`MAX_PERIOD_TICKS`], or no text source among `sources`.
pub fn at_period(sources: &mut [Source], period_us: f64, ts_us: f64) -> Result<()> {
    if !(period_us.is_finite() && period_us > 0.0 && period_us <= 1e6) {
        bail!(
            "--record-period-us {period_us}: allowed 0 < P <= 1000000 (µs between a text record's lines)"
        );
    }
    if !sources.iter().any(|s| s.kind == Kind::Text) {
        bail!(
            "--record-period-us {period_us}: no text source among --latency (run folders carry their own ticks, and histograms have no order)"
        );
    }
    for s in sources.iter_mut().filter(|s| s.kind == Kind::Text) {
        let Latencies::Sequences(seqs) = &mut s.latencies else {
            continue;
        };
        for seq in seqs.iter_mut() {
            let span = (seq.len() as f64 * period_us / ts_us).floor();
            if span > MAX_PERIOD_TICKS as f64 {
                bail!(
                    "--latency {}: {} lines one every {period_us} µs span {span:.0} ticks of {ts_us} µs, more than the {MAX_PERIOD_TICKS} allowed: use a shorter record",
                    s.path.display(),
                    seq.len()
                );
            }
            *seq = spread(seq, period_us, ts_us);
        }
        s.ticks = seqs.iter().map(|q| q.len() as u64).sum();
        if s.ticks == 0 {
            bail!(
                "--latency {}: its lines, one every {period_us} µs, last less than one tick of {ts_us} µs",
                s.path.display()
            );
        }
    }
    Ok(())
}

/// `seq`'s lines, one every `period_us`, on ticks of `ts_us`.
fn spread(seq: &[ReplyOutcome], period_us: f64, ts_us: f64) -> Vec<ReplyOutcome> {
    let span = (seq.len() as f64 * period_us / ts_us).floor() as usize;
    (0..span)
        .map(|k| seq[((k as f64 * ts_us / period_us).floor() as usize).min(seq.len() - 1)])
        .collect()
}

/// The largest latency file read (text, `.hgrm`, `.hlog`), bytes: 100 M lines of text.
const MAX_FILE_BYTES: u64 = 1 << 30;

impl Source {
    /// Loads `path`: a directory is a run folder; a file by its extension (`.hgrm`, `.hlog`,
    /// anything else text). `unit` is the unit of an HdrHistogram file that does not say its own.
    pub fn load(path: &Path, unit: Option<Unit>) -> Result<Self> {
        let meta = std::fs::metadata(path)
            .map_err(|e| anyhow!("--latency {}: cannot read it: {e}", path.display()))?;
        let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("");
        let mut recorded = None;
        let (kind, latencies, laws) = if meta.is_dir() {
            let (seqs, laws, config) = run_folder(path)?;
            recorded = Some(Box::new(config));
            (Kind::RunFolder, Latencies::Sequences(seqs), laws)
        } else if ext == "hgrm" {
            (Kind::Hgrm, Latencies::Histogram(hgrm(path, unit)?), vec![])
        } else if ext == "hlog" {
            (Kind::Hlog, Latencies::Histogram(hlog(path, unit)?), vec![])
        } else {
            (
                Kind::Text,
                Latencies::Sequences(vec![text(path, unit)?]),
                vec![],
            )
        };
        let ticks = match &latencies {
            Latencies::Sequences(s) => s.iter().map(|s| s.len() as u64).sum(),
            Latencies::Histogram(h) => total(path, h.iter().map(|&(_, c)| c))?,
        };
        let s = Self {
            path: path.to_path_buf(),
            kind,
            latencies,
            laws,
            ticks,
            recorded,
        };
        if s.ticks == 0 {
            bail!(
                "--latency {}: holds no latency (a {} with nothing in it)",
                path.display(),
                kind.name()
            );
        }
        Ok(s)
    }

    /// A run folder's recorded sequence of `law` (empty if it has none).
    pub fn sequence_of(&self, law: Law) -> &[ReplyOutcome] {
        match (&self.latencies, self.laws.iter().position(|&l| l == law)) {
            (Latencies::Sequences(s), Some(i)) => &s[i],
            _ => &[],
        }
    }
}

/// Latency counts added up, checked (regression: an `.hgrm`'s counts wrapped u64 and gave a
/// share of misses of 1.8e20 %).
pub fn total(path: &Path, counts: impl IntoIterator<Item = u64>) -> Result<u64> {
    counts
        .into_iter()
        .try_fold(0u64, u64::checked_add)
        .ok_or_else(|| {
            anyhow!(
                "--latency {}: its counts add up past 2^64 latencies: not a record of a run",
                path.display()
            )
        })
}

/// A realtime run folder: per law, each tick's outcome as the replay takes it (an applied reply
/// at its `arrival_ns` less the run's transport delay; the row a run diverged on, applied without
/// an arrival, at 0 ns: the divergence rule ends the run on it before it acts), and the run's
/// config. The trace is checked as `replay` checks it ([`replay::read_recorded`]), and against
/// the run's `summary.json`: a lockstep or in-process run is refused (it records no arrival:
/// every reply acts at its tick), and so is a trace cut short.
fn run_folder(dir: &Path) -> Result<(Vec<Vec<ReplyOutcome>>, Vec<Law>, RunConfig)> {
    let at = || format!("--latency {}", dir.display());
    let summary = Finished::read(dir).with_context(at)?;
    let mut seqs: Vec<Vec<ReplyOutcome>> = Vec::new();
    let mut laws = Vec::new();
    let study = replay::read_recorded(dir, |law, outcome| {
        if laws.last() != Some(&law) {
            laws.push(law);
            seqs.push(Vec::new());
        }
        if let Some(s) = seqs.last_mut() {
            s.push(outcome);
        }
    })
    .with_context(at)?;
    summary
        .check(dir, &laws, &seqs, study.reference.n as u64)
        .with_context(at)?;
    Ok((seqs, laws, study.config))
}

/// What a run folder's `summary.json` says of its trace.
struct Finished {
    /// The laws that ran every tick 0..=N.
    completed: Vec<Law>,
}

/// The largest `summary.json` read, bytes.
const MAX_SUMMARY_BYTES: u64 = 16 << 20;

impl Finished {
    /// Reads `summary.json`; Err for a folder without one, or of a mode without arrivals.
    fn read(dir: &Path) -> Result<Self> {
        let p = dir.join("summary.json");
        let bytes = files::read_regular(&p, MAX_SUMMARY_BYTES, "a run's summary").map_err(|e| {
            anyhow!(
                "cannot read {}: {e} (whatif reads the folder of a finished realtime run)",
                p.display()
            )
        })?;
        let v: serde_json::Value = serde_json::from_slice(&bytes)
            .map_err(|e| anyhow!("{}: not a run's summary ({e})", p.display()))?;
        let mode = v["mode"].as_str().unwrap_or_default();
        match LoopMode::parse(mode) {
            Ok(LoopMode::Realtime) => {}
            Ok(m) => bail!(
                "a {} run records no arrival (its replies act at their tick, so every latency would read 0): give a realtime run folder, or a file of latencies",
                m.name()
            ),
            Err(e) => bail!("{}: column mode: {e}", p.display()),
        }
        let completed = v["laws"]
            .as_object()
            .into_iter()
            .flatten()
            .filter(|(_, m)| m["completed"].as_bool() == Some(true))
            .filter_map(|(l, _)| Law::parse(l).ok())
            .collect();
        Ok(Self { completed })
    }

    /// A law that completed must have its rows up to N, and the trace must end with its last
    /// row's line end: else the record was cut.
    fn check(&self, dir: &Path, laws: &[Law], seqs: &[Vec<ReplyOutcome>], n: u64) -> Result<()> {
        let trace = dir.join("trace.csv");
        if !ends_with_line_end(&trace)? {
            bail!(
                "{}: the last row has no line end: the record is cut",
                trace.display()
            );
        }
        for (law, seq) in laws.iter().zip(seqs) {
            if self.completed.contains(law) && seq.len() as u64 != n + 1 {
                bail!(
                    "{}: law `{law}` has ticks 0..={} but its run completed ticks 0..={n} (summary.json): the record is cut",
                    trace.display(),
                    seq.len().saturating_sub(1)
                );
            }
        }
        Ok(())
    }
}

/// Whether the file's last byte is `\n` (an empty file: true).
fn ends_with_line_end(p: &Path) -> Result<bool> {
    use std::io::{Read, Seek, SeekFrom};
    let mut f = std::fs::File::open(p).with_context(|| format!("cannot read {}", p.display()))?;
    let len = f.metadata()?.len();
    if len == 0 {
        return Ok(true);
    }
    let mut last = [0u8];
    f.seek(SeekFrom::Start(len - 1))
        .and_then(|_| f.read_exact(&mut last))
        .with_context(|| format!("cannot read {}", p.display()))?;
    Ok(last[0] == b'\n')
}

/// A text file of latencies, one per line, in `unit` (µs if None); blank lines and `#` comments
/// are skipped. A line that is not UTF-8 is named.
fn text(path: &Path, unit: Option<Unit>) -> Result<Vec<ReplyOutcome>> {
    use std::io::BufRead;
    let unit = unit.unwrap_or(Unit::Us);
    let file = files::open_regular(path, MAX_FILE_BYTES, "a latency file")
        .map_err(|e| anyhow!("--latency {}: cannot read it: {e}", path.display()))?;
    let mut out = Vec::new();
    for (i, line) in std::io::BufReader::new(file).split(b'\n').enumerate() {
        let at = || format!("--latency {} line {}", path.display(), i + 1);
        let line = line.with_context(at)?;
        let line = std::str::from_utf8(&line).map_err(|e| {
            anyhow!(
                "{}: byte {} is not UTF-8 text: expected a number of {} ≥ 0, one per line",
                at(),
                e.valid_up_to() + 1,
                unit.symbol()
            )
        })?;
        let v = line.trim();
        if v.is_empty() || v.starts_with('#') {
            continue;
        }
        out.push(ReplyOutcome::Applied(latency_ns(v, unit.ns()).ok_or_else(
            || {
                anyhow!(
                    "{}: {} is not a latency: expected a number of {} ≥ 0, one per line",
                    at(),
                    deltaloop_config::show_str(v),
                    unit.symbol()
                )
            },
        )?));
    }
    Ok(out)
}

/// `v` (a number in a unit of `scale` ns) in ns; None if it is not a finite number ≥ 0 below an
/// hour.
fn latency_ns(v: &str, scale: f64) -> Option<u64> {
    let x: f64 = v.parse().ok()?;
    let ns = x * scale;
    (x.is_finite() && x >= 0.0 && ns < 3.6e12).then(|| ns.round() as u64)
}

/// The unit a file states in its comment lines, the one given, or an error naming both.
fn unit_of(path: &Path, comments: &[&str], given: Option<Unit>) -> Result<Unit> {
    let stated = comments.iter().find_map(|c| Unit::named_in(c));
    match (stated, given) {
        (Some(s), Some(g)) if s != g => bail!(
            "--latency {}: the file says its values are in {} but --latency-unit is {}",
            path.display(),
            s.name(),
            g.name()
        ),
        (Some(u), _) | (None, Some(u)) => Ok(u),
        (None, None) => bail!(
            "--latency {}: the file does not say the unit of its values: give --latency-unit ns, us, ms or s",
            path.display()
        ),
    }
}

/// An HdrHistogram percentile-distribution file (`outputPercentileDistribution`: Value,
/// Percentile, TotalCount, 1/(1-Percentile)): each row's value with the count it adds. Files whose
/// TotalCount column is cumulative (Java's) and those that count per row (deltaloop's) read alike
/// (the `Total count` footer tells them apart).
fn hgrm(path: &Path, unit: Option<Unit>) -> Result<Vec<(u64, u64)>> {
    let text = files::read_regular(path, MAX_FILE_BYTES, "a percentile file")
        .map_err(|e| anyhow!("--latency {}: cannot read it: {e}", path.display()))?;
    let text = String::from_utf8_lossy(&text);
    let comments: Vec<&str> = text.lines().filter(|l| l.starts_with('#')).collect();
    let scale = unit_of(path, &comments, unit)?.ns();
    let mut rows: Vec<(u64, f64, u64)> = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let cols: Vec<&str> = line.split_whitespace().collect();
        if line.starts_with('#') || cols.is_empty() || cols[0] == "Value" {
            continue;
        }
        let at = || format!("--latency {} line {}", path.display(), i + 1);
        let (Some(v), Some(p), Some(c)) = (
            cols.first().and_then(|v| latency_ns(v, scale)),
            cols.get(1).and_then(|p| p.parse::<f64>().ok()),
            cols.get(2).and_then(|c| c.parse::<u64>().ok()),
        ) else {
            bail!(
                "{}: {} is not a percentile row: expected Value Percentile TotalCount 1/(1-Percentile)",
                at(),
                deltaloop_config::show_str(line.trim())
            );
        };
        if !(0.0..=1.0).contains(&p) || rows.last().is_some_and(|r| p < r.1 || v < r.0) {
            bail!(
                "{}: percentile {p} at value {v} ns: rows must rise in value and percentile (0..=1)",
                at()
            );
        }
        rows.push((v, p, c));
    }
    let footer = comments.iter().find_map(|c| {
        let at = c.find("Total count")?;
        c[at..]
            .split('=')
            .nth(1)?
            .trim()
            .trim_end_matches(']')
            .split(|ch: char| ch == ',' || ch.is_whitespace())
            .next()?
            .parse::<u64>()
            .ok()
    });
    // Java's TotalCount is cumulative; deltaloop's own files count each row. A column that adds
    // up to the footer's total counts rows (a cumulative one can only do so when every row but
    // the last is 0, where both readings agree); else it must rise to the total.
    let sum = total(path, rows.iter().map(|r| r.2))?;
    let rising = rows.windows(2).all(|w| w[0].2 <= w[1].2);
    let last = rows.last().map_or(0, |r| r.2);
    let per_row = match footer {
        Some(t) if t == sum => true,
        Some(t) if rising && t == last => false,
        None => !rising,
        Some(t) => bail!(
            "--latency {}: the TotalCount column neither adds up nor rises to the footer's total count {t}",
            path.display()
        ),
    };
    let mut out: Vec<(u64, u64)> = Vec::new();
    let mut before = 0u64;
    for &(v, _, c) in &rows {
        let n = if per_row { c } else { c.saturating_sub(before) };
        before = c;
        if n > 0 {
            out.push((v, n));
        }
    }
    merge_equal(&mut out);
    Ok(out)
}

/// An HdrHistogram interval log: every interval added up, one interval in memory at a time.
fn hlog(path: &Path, unit: Option<Unit>) -> Result<Vec<(u64, u64)>> {
    let scale = {
        let head = files::read_regular(path, MAX_FILE_BYTES, "an interval log")
            .map_err(|e| anyhow!("--latency {}: cannot read it: {e}", path.display()))?;
        let head = String::from_utf8_lossy(&head);
        let comments: Vec<&str> = head.lines().take_while(|l| l.starts_with('#')).collect();
        unit_of(path, &comments, unit)?.ns()
    };
    let mut counts: std::collections::BTreeMap<u64, u64> = Default::default();
    deltaloop_timing::hlog::each_interval(path, |i| {
        for v in i.hist.iter_recorded() {
            let ns = (v.value_iterated_to() as f64 * scale).round() as u64;
            let c = counts.entry(ns).or_default();
            *c = total(path, [*c, v.count_at_value()])?;
        }
        Ok(())
    })
    .with_context(|| format!("--latency {}", path.display()))?;
    Ok(counts.into_iter().collect())
}

/// Adds up the counts of equal values (sorted input).
fn merge_equal(v: &mut Vec<(u64, u64)>) {
    v.dedup_by(|b, a| {
        if a.0 == b.0 {
            a.1 += b.1;
            true
        } else {
            false
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    fn file(dir: &tempfile::TempDir, name: &str, text: &str) -> PathBuf {
        let p = dir.path().join(name);
        std::fs::write(&p, text).unwrap();
        p
    }

    #[test]
    fn a_record_at_another_period_keeps_its_bursts_duration() {
        let line = |us: u64| ReplyOutcome::Applied(us * 1000);
        // Lines every 900 µs on ticks of 300 µs: each line holds three ticks.
        let seq = [line(40), line(900), line(40)];
        let got = spread(&seq, 900.0, 300.0);
        assert_eq!(
            got,
            [
                line(40),
                line(40),
                line(40),
                line(900),
                line(900),
                line(900),
                line(40),
                line(40),
                line(40)
            ]
        );
        // Every 100 µs: every third line, for the record's 0.6 ms.
        let fast: Vec<_> = (0..6).map(line).collect();
        assert_eq!(spread(&fast, 100.0, 300.0), [line(0), line(3)]);
        // 1 kHz onto 3.3 kHz: a 3 ms burst (3 lines) is 10 ticks.
        let mut khz = vec![line(40); 10];
        khz.extend([line(900); 3]);
        khz.extend(vec![line(40); 10]);
        let t = spread(&khz, 1000.0, 300.0);
        assert_eq!(t.iter().filter(|&&o| o == line(900)).count(), 10);
        assert_eq!(t.len(), 76);
    }

    #[test]
    fn a_text_file_is_a_sequence_in_us_and_bad_lines_are_named() {
        let d = tempfile::tempdir().unwrap();
        let p = file(&d, "rtt.txt", "# ping\n12.5\n\n30\n0\n");
        let s = Source::load(&p, None).unwrap();
        assert_eq!(
            s.latencies,
            Latencies::Sequences(vec![vec![
                ReplyOutcome::Applied(12_500),
                ReplyOutcome::Applied(30_000),
                ReplyOutcome::Applied(0)
            ]])
        );
        for bad in ["-1", "nan", "12 us", "inf"] {
            let p = file(&d, "bad.txt", &format!("10\n{bad}\n"));
            let e = Source::load(&p, None).unwrap_err().to_string();
            assert!(e.contains("line 2") && e.contains("µs ≥ 0"), "{e}");
        }
        let p = file(&d, "empty.txt", "# nothing\n");
        let e = Source::load(&p, None).unwrap_err().to_string();
        assert!(e.contains("holds no latency"), "{e}");
    }

    /// deltaloop's own `.hgrm` (counts per row, unit in its comment) and Java's (cumulative
    /// TotalCount, no unit) read to the same distribution.
    #[test]
    fn hgrm_files_of_either_count_convention_read_alike() {
        let mut h = deltaloop_study::latency_histogram();
        for (v, n) in [(10_000u64, 50u64), (20_000, 30), (90_000, 20)] {
            h.record_n(v, n).unwrap();
        }
        let d = tempfile::tempdir().unwrap();
        let own = file(&d, "a.hgrm", &deltaloop_timing::hgrm(&h, "round trip"));
        let ours = Source::load(&own, None).unwrap();
        let Latencies::Histogram(got) = &ours.latencies else {
            panic!("{ours:?}")
        };
        assert_eq!(got.iter().map(|c| c.1).sum::<u64>(), 100);
        let near = |ns: u64, want: u64| ns.abs_diff(want) * 100 <= want;
        let at = |want: u64| {
            got.iter()
                .filter(|(v, _)| near(*v, want))
                .map(|c| c.1)
                .sum::<u64>()
        };
        assert_eq!(
            (at(10_000), at(20_000), at(90_000)),
            (50, 30, 20),
            "{got:?}"
        );

        let java = "       Value     Percentile TotalCount 1/(1-Percentile)\n\n\
                    10.000 0.500000000000 50 2.00\n\
                    20.000 0.800000000000 80 5.00\n\
                    90.000 1.000000000000 100 inf\n\
                    #[Mean    =       29.000, StdDeviation   =       30.000]\n\
                    #[Max     =       90.000, Total count    =          100]\n";
        let j = file(&d, "j.hgrm", java);
        let e = Source::load(&j, None).unwrap_err().to_string();
        assert!(e.contains("--latency-unit"), "{e}");
        let j = Source::load(&j, Some(Unit::Us)).unwrap();
        assert_eq!(
            j.latencies,
            Latencies::Histogram(vec![(10_000, 50), (20_000, 30), (90_000, 20)])
        );
        let e = Source::load(&own, Some(Unit::Ns)).unwrap_err().to_string();
        assert!(e.contains("says its values are in us"), "{e}");
    }

    #[test]
    fn hgrm_rows_that_fall_are_refused_with_their_line() {
        let d = tempfile::tempdir().unwrap();
        let p = file(&d, "x.hgrm", "# values in ns\n20 0.5 5 2\n10 0.9 9 10\n");
        let e = Source::load(&p, None).unwrap_err().to_string();
        assert!(e.contains("line 3") && e.contains("must rise"), "{e}");
        let p = file(&d, "y.hgrm", "# values in ns\nabc\n");
        let e = Source::load(&p, None).unwrap_err().to_string();
        assert!(
            e.contains("line 2") && e.contains("not a percentile row"),
            "{e}"
        );
    }

    /// Regression: the counts of an `.hgrm` were added in u64 without a check: 10 µs × 2^63 and
    /// 20 µs × 2^63 wrapped to a total of 0 and printed 1.8e20 % misses with exit 0 (in a release
    /// build). Counts that add up past 2^64 are refused, in one file or pooled over several.
    #[test]
    fn regression_hgrm_counts_that_wrap_u64_are_refused() {
        let d = tempfile::tempdir().unwrap();
        let big = 1u64 << 63;
        let p = file(
            &d,
            "w.hgrm",
            &format!("# values in us\n10 0.5 {big} 2\n20 1.0 {big} inf\n"),
        );
        let e = format!("{:#}", Source::load(&p, None).unwrap_err());
        assert!(e.contains("w.hgrm") && e.contains("2^64"), "{e}");
        let half = file(&d, "h.hgrm", &format!("# values in us\n10 1.0 {big} inf\n"));
        let mut two = [
            Source::load(&half, None).unwrap(),
            Source::load(&half, None).unwrap(),
        ];
        let e = super::super::draw::Pool::new(&mut two, super::super::draw::Model::Independent)
            .err()
            .map(|e| format!("{e:#}"))
            .unwrap_or_default();
        assert!(e.contains("2^64"), "pooled: {e}");
    }

    /// Regression: `--latency-unit ns` was ignored for a text file (read in µs all the same),
    /// and a text file with a byte that is not UTF-8 failed without its line.
    #[test]
    fn regression_text_files_take_the_latency_unit_and_name_a_non_utf8_line() {
        let d = tempfile::tempdir().unwrap();
        let p = file(&d, "ns.txt", "1500\n");
        let s = Source::load(&p, Some(Unit::Ns)).unwrap();
        assert_eq!(
            s.latencies,
            Latencies::Sequences(vec![vec![ReplyOutcome::Applied(1500)]])
        );
        let p = d.path().join("bad.txt");
        std::fs::write(&p, b"10\n20\n3\xff0\n").unwrap();
        let e = format!("{:#}", Source::load(&p, None).unwrap_err());
        assert!(e.contains("bad.txt line 3") && e.contains("UTF-8"), "{e}");
    }

    #[test]
    fn an_hlog_adds_up_its_intervals_in_its_stated_unit() {
        use deltaloop_timing::hlog::HlogWriter;
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("x.hlog");
        let t = deltaloop_study::latency_histogram();
        let base =
            std::time::SystemTime::UNIX_EPOCH + std::time::Duration::from_secs(1_700_000_000);
        let mut w = HlogWriter::create(
            &p,
            "test; values in ns",
            base,
            std::time::Duration::from_secs(1),
            &t,
        )
        .unwrap();
        w.record(100_000_000, 15_000).unwrap();
        w.record(200_000_000, 15_000).unwrap();
        w.record(1_500_000_000, 40_000).unwrap();
        w.finish(2_000_000_000).unwrap();
        let s = Source::load(&p, None).unwrap();
        let Latencies::Histogram(h) = &s.latencies else {
            panic!()
        };
        assert_eq!(h.iter().map(|c| c.1).sum::<u64>(), 3);
        assert!(h[0].1 == 2 && h[0].0.abs_diff(15_000) < 20, "{h:?}");
    }
}
