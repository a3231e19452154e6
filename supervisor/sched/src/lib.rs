//! Why a tick was late: the kernel's scheduling record of the loop's CPUs beside the loop's own
//! stamps (`--explain`, docs/guide/misses.md).
//!
//! - [`record`]: the kernel's events (`sched_switch`, `sched_waking`, `irq_handler_entry/exit`,
//!   `softirq_entry/exit`) of the loop's CPUs, recorded by a tracefs instance of its own into a
//!   file while the loop runs, read by a thread off the loop's CPUs;
//! - [`event`]: that file's lines as events (pure);
//! - [`attribute`]: each missed or late tick's window folded into one cause (pure, streaming);
//! - [`timeline`]: which thread ran on which CPU around one tick, for its figure (pure);
//! - [`analyse`]: a recorded file and the run's windows into `<law>.misses.csv` and counts.

pub mod attribute;
pub mod event;
pub mod record;
pub mod timeline;

pub use attribute::{Cause, MissKind, Verdict, Window};
pub use event::{Event, Kind, Thread};
pub use record::{Counts, Recorder, steal_jiffies};

use anyhow::Context as _;
use serde::Serialize;
use std::collections::BTreeMap;
use std::io::BufRead;
use std::path::Path;

/// The header of `<law>.misses.csv`.
pub const MISSES_COLUMNS: [&str; 7] = ["k", "kind", "cause", "culprit", "pid", "cpu", "lost_us"];

/// What the kernel's record says of a law's run, for `summary.json`.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Explained {
    /// Missed ticks by cause (every cause, zeros included).
    pub miss_causes: BTreeMap<&'static str, u64>,
    /// Missed ticks by the command name of the thread that held the loop's CPU.
    pub miss_culprits: BTreeMap<String, u64>,
    /// Late ticks (the plant woke more than a quarter period late) by cause.
    pub late_causes: BTreeMap<&'static str, u64>,
    /// The kernel's events read, and per second of the recording.
    pub sched_events: u64,
    pub sched_events_per_s: f64,
    /// The record's size, bytes (a file in the run folder while the law runs, removed after).
    pub sched_bytes: u64,
    /// The missed tick that lost the most, if any.
    #[serde(skip)]
    pub worst: Option<Verdict>,
}

impl Explained {
    fn new(counts: Counts) -> Self {
        let zeros = || Cause::ALL.iter().map(|c| (c.name(), 0)).collect();
        Self {
            miss_causes: zeros(),
            late_causes: zeros(),
            sched_events: counts.lines,
            sched_events_per_s: counts.per_second(),
            sched_bytes: counts.bytes,
            ..Self::default()
        }
    }

    /// `preempted 80 (culprits: burner 80), irq 2`: the causes of missed ticks that occurred,
    /// most first, and the top culprits; None without a missed tick.
    pub fn words(&self) -> Option<String> {
        let mut s = by_cause(&self.miss_causes)?;
        let top = self.culprit_words(3, |c, n| format!("{c} {n}"));
        if !top.is_empty() {
            s.push_str(&format!(" (culprits: {})", top.join(", ")));
        }
        Some(s)
    }

    /// The late ticks' causes as [`Explained::words`] says the missed ones'.
    pub fn late_words(&self) -> Option<String> {
        by_cause(&self.late_causes)
    }

    /// The first `n` culprits, most missed ticks first, each as `say(name, ticks)`.
    pub fn culprit_words(&self, n: usize, say: impl Fn(&str, u64) -> String) -> Vec<String> {
        self.top_culprits()
            .iter()
            .take(n)
            .map(|(c, k)| say(c, *k))
            .collect()
    }

    /// The culprits, most missed ticks first (ties by name).
    pub fn top_culprits(&self) -> Vec<(&str, u64)> {
        let mut v: Vec<_> = self
            .miss_culprits
            .iter()
            .map(|(n, c)| (n.as_str(), *c))
            .collect();
        v.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(b.0)));
        v
    }
}

/// `preempted 80, irq 2`: the causes that occurred, most first (ties by name); None if none.
fn by_cause(m: &BTreeMap<&'static str, u64>) -> Option<String> {
    let mut causes: Vec<_> = m.iter().filter(|(_, n)| **n > 0).collect();
    causes.sort_by(|a, b| b.1.cmp(a.1).then(a.0.cmp(b.0)));
    (!causes.is_empty()).then(|| {
        causes
            .iter()
            .map(|(c, n)| format!("{c} {n}"))
            .collect::<Vec<_>>()
            .join(", ")
    })
}

/// The events of a recorded file, in the file's order (lines of other shapes skipped).
pub fn events(file: &Path) -> std::io::Result<impl Iterator<Item = Event>> {
    let r = std::io::BufReader::new(std::fs::File::open(file)?);
    Ok(r.lines()
        .map_while(Result::ok)
        .filter_map(|l| event::parse(&l)))
}

/// Explains `windows` (in start order) from the record `file` made by a [`Recorder`] that
/// counted `counts`: writes `<misses>` (one row per window, [`MISSES_COLUMNS`]) and returns the
/// counts by cause. `pids`: the loop threads.
pub fn analyse(
    file: &Path,
    counts: Counts,
    pids: &[i32],
    windows: impl IntoIterator<Item = Window>,
    misses: &Path,
) -> anyhow::Result<Explained> {
    let named = |f: &Path| format!("cannot write {}", f.display());
    let mut w = csv::Writer::from_path(misses).with_context(|| named(misses))?;
    w.write_record(MISSES_COLUMNS)
        .with_context(|| named(misses))?;
    let mut x = Explained::new(counts);
    let mut failed = None;
    attribute::explain(
        pids,
        windows,
        events(file).with_context(|| format!("cannot read {}", file.display()))?,
        |v| {
            let culprit = v
                .culprit
                .as_ref()
                .map(|c| c.comm.clone())
                .or(v.source.clone())
                .unwrap_or_default();
            let pid = v.culprit.as_ref().map(|c| c.pid.to_string());
            let row = [
                v.k.to_string(),
                v.kind.name().to_string(),
                v.cause.name().to_string(),
                culprit,
                pid.unwrap_or_default(),
                v.cpu.to_string(),
                format!("{:.1}", v.lost_us),
            ];
            if let Err(e) = w.write_record(&row) {
                failed.get_or_insert(e);
            }
            let by_cause = match v.kind {
                MissKind::Missed => &mut x.miss_causes,
                MissKind::Late => &mut x.late_causes,
            };
            *by_cause.entry(v.cause.name()).or_default() += 1;
            if v.kind == MissKind::Missed {
                if let Some(c) = &v.culprit {
                    *x.miss_culprits.entry(c.comm.clone()).or_default() += 1;
                }
                if x.worst.as_ref().is_none_or(|w| v.lost_us > w.lost_us) {
                    x.worst = Some(v);
                }
            }
        },
    );
    if let Some(e) = failed {
        return Err(e).with_context(|| named(misses));
    }
    w.flush().with_context(|| named(misses))?;
    Ok(x)
}
