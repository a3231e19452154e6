//! `trace.csv`: one row per tick per law. Its columns are one table, [`COLUMNS`]: the writer, the
//! replay reader and the docs' column list (checked by a test) all follow it, so a column is
//! added in one place.
//!
//! Every float is written in shortest round-trip exponent form (e.g. `-7.776579935558914e-10`):
//! a reader gets the recorded double back bit for bit.

use anyhow::{Context, Result};
use deltaloop_law::Law;
use deltaloop_model::Vec3;
use deltaloop_study::Study;
use deltaloop_study::record::{ReplyFate, TickRecord};
use deltaloop_study::reference::RefRow;
use std::fmt::Arguments;
use std::path::{Path, PathBuf};

/// What one row is written from.
pub struct Row<'a> {
    pub law: Law,
    pub rec: &'a TickRecord,
    pub reference: &'a RefRow,
    /// N_k, the true lumped dynamics (None where the next state is unknown), rad/s².
    pub n_true: Option<Vec3>,
}

/// Puts one field of a row (the writer's sink; no allocation).
type Put<'p> = dyn FnMut(Arguments<'_>) + 'p;

/// One column of `trace.csv`, or one per joint (`name_1`, `name_2`, `name_3`).
pub struct Column {
    pub name: &'static str,
    pub per_joint: bool,
    /// The unit ("" for words and counts).
    pub unit: &'static str,
    /// What it holds, and when it is empty.
    pub what: &'static str,
    /// Puts the column's one or three fields.
    write: fn(&Row<'_>, &mut Put<'_>),
}

/// Puts a vector's three components, or three empty fields.
fn joints(v: Option<Vec3>, put: &mut Put<'_>) {
    match v {
        Some(v) => v.iter().for_each(|x| put(format_args!("{x:e}"))),
        None => (0..3).for_each(|_| put(format_args!(""))),
    }
}

pub const LAW: Column = Column {
    name: "law",
    per_joint: false,
    unit: "",
    what: "the law's name",
    write: |r, put| put(format_args!("{}", r.law.name())),
};
pub const K: Column = Column {
    name: "k",
    per_joint: false,
    unit: "",
    what: "the tick",
    write: |r, put| put(format_args!("{}", r.rec.sample.k)),
};
pub const T: Column = Column {
    name: "t_s",
    per_joint: false,
    unit: "s",
    what: "t_k = k·Ts",
    write: |r, put| put(format_args!("{:e}", r.reference.t)),
};
pub const Q_DES: Column = Column {
    name: "q_des",
    per_joint: true,
    unit: "rad",
    what: "the reference q_d,k",
    write: |r, put| joints(Some(r.reference.joint.q), put),
};
pub const Q: Column = Column {
    name: "q",
    per_joint: true,
    unit: "rad",
    what: "the true joint angle q_k",
    write: |r, put| joints(Some(r.rec.q_true), put),
};
pub const QDOT: Column = Column {
    name: "qdot",
    per_joint: true,
    unit: "rad/s",
    what: "the true joint rate q̇_k",
    write: |r, put| joints(Some(r.rec.qd_true), put),
};
pub const E: Column = Column {
    name: "e",
    per_joint: true,
    unit: "rad",
    what: "the tracking error e_k = q_des − q",
    write: |r, put| joints(Some(r.reference.joint.q - r.rec.q_true), put),
};
pub const TAU: Column = Column {
    name: "tau",
    per_joint: true,
    unit: "N m",
    what: "the commanded torque τ_k (empty: the controller never answered)",
    write: |r, put| joints(r.rec.out.as_ref().map(|o| o.tau), put),
};
pub const TAU_APPLIED: Column = Column {
    name: "tau_applied",
    per_joint: true,
    unit: "N m",
    what: "τᵃ_k, the torque the drives applied over [t_{k−1}, t_k)",
    write: |r, put| joints(Some(r.rec.sample.tau_applied), put),
};
pub const S: Column = Column {
    name: "s",
    per_joint: true,
    unit: "rad/s",
    what: "the sliding variable s_k (empty: never answered)",
    write: |r, put| joints(r.rec.out.as_ref().map(|o| o.s), put),
};
pub const N_HAT: Column = Column {
    name: "n_hat",
    per_joint: true,
    unit: "rad/s²",
    what: "the TDE N̂_k (empty: never answered)",
    write: |r, put| joints(r.rec.out.as_ref().map(|o| o.n_hat), put),
};
pub const N_TRUE: Column = Column {
    name: "n_true",
    per_joint: true,
    unit: "rad/s²",
    what: "the true N_k (empty where the next state is unknown)",
    write: |r, put| joints(r.n_true, put),
};
pub const REPLY: Column = Column {
    name: "reply",
    per_joint: false,
    unit: "",
    what: "what became of the controller's reply to tick k: applied, late, skipped, missed \
           (unknown: the plant's telemetry of the tick never reached the supervisor)",
    write: |r, put| put(format_args!("{}", fate_and_drives(r.rec).0)),
};
pub const DRIVES: Column = Column {
    name: "drives",
    per_joint: false,
    unit: "",
    what: "what the drives did over [t_k, t_{k+1}): commanded, clamped, held, rejected (or unknown)",
    write: |r, put| put(format_args!("{}", fate_and_drives(r.rec).1)),
};
pub const ARRIVAL: Column = Column {
    name: "arrival_ns",
    per_joint: false,
    unit: "ns",
    what: "A_k − t_k, when tick k's command reached the drives: the transport delay plus, in \
           realtime, its measured latency (empty: no command was applied)",
    write: |r, put| match r.rec.arrival_ns {
        Some(a) => put(format_args!("{a}")),
        None => put(format_args!("")),
    },
};

/// After [`COLUMNS`], in the traces of compensated runs only (every other trace is as it was).
pub const M_HAT: Column = Column {
    name: "m_hat",
    per_joint: true,
    unit: "kg m²",
    what: "a compensated law's learned inertia M̂ after tick k (docs/controllers.md; only in a \
           run with `compensate = \"predict\"`; empty for `pid`, and from a reply the supervisor \
           did not see on)",
    write: |r, put| joints(r.rec.m_hat, put),
};

/// The columns of `trace.csv`, in order.
pub const COLUMNS: [Column; 15] = [
    LAW,
    K,
    T,
    Q_DES,
    Q,
    QDOT,
    E,
    TAU,
    TAU_APPLIED,
    S,
    N_HAT,
    N_TRUE,
    REPLY,
    DRIVES,
    ARRIVAL,
];

/// What `drives` may say (see [`DRIVES`]).
pub const DRIVES_WORDS: [&str; 5] = ["commanded", "clamped", "held", "rejected", UNKNOWN];

/// `reply` and `drives` of a tick recorded without the plant's telemetry.
pub const UNKNOWN: &str = "unknown";

/// What a number column holds.
const A_NUMBER: &str = "a number, or empty";

/// What a column of ns holds.
pub const A_NS: &str = "a whole number of ns, or empty";

/// A cell of a run's file that is not what its column holds, in one line: `column reply =
/// "maybe": expected applied, …` (the reader puts the file and line before it).
pub fn bad_cell(column: &str, value: &str, allowed: &str) -> anyhow::Error {
    anyhow::anyhow!(
        "column {column} = {}: expected {allowed}",
        deltaloop_config::show_str(value)
    )
}

/// The position of column `name` in a header read by name: there once, else an error naming it.
pub fn column_at(header: &csv::StringRecord, name: &str) -> Result<usize> {
    let mut at = header.iter().enumerate().filter(|(_, c)| *c == name);
    match (at.next(), at.next()) {
        (Some((i, _)), None) => Ok(i),
        (None, _) => anyhow::bail!("no column `{name}`"),
        (Some(_), Some(_)) => anyhow::bail!("column `{name}` appears twice"),
    }
}

/// The `law` cell.
pub fn law_cell(v: &str) -> Result<Law> {
    Law::parse(v).map_err(|_| bad_cell(LAW.name, v, &deltaloop_names::one_of::<Law>()))
}

/// The `k` cell.
pub fn tick_cell(v: &str) -> Result<u64> {
    v.parse()
        .map_err(|_| bad_cell(K.name, v, "a tick number (0, 1, 2, …)"))
}

/// The `reply` cell: what became of the reply, None if `unknown`.
pub fn reply_cell(v: &str) -> Result<Option<ReplyFate>> {
    if v == UNKNOWN {
        return Ok(None);
    }
    ReplyFate::parse(v).map(Some).map_err(|_| {
        let words = deltaloop_names::allowed::<ReplyFate>();
        bad_cell(REPLY.name, v, &format!("{words} or {UNKNOWN}"))
    })
}

/// The `drives` cell, one of [`DRIVES_WORDS`].
pub fn drives_cell(v: &str) -> Result<()> {
    if DRIVES_WORDS.contains(&v) {
        return Ok(());
    }
    let (last, rest) = DRIVES_WORDS.split_last().unwrap_or((&"", &[]));
    Err(bad_cell(
        DRIVES.name,
        v,
        &format!("{} or {last}", rest.join(", ")),
    ))
}

/// A number cell of `column` (per joint: `name`, joint j = 1..=3), None if empty.
pub fn number_cell(name: &str, j: Option<usize>, v: &str) -> Result<Option<f64>> {
    if v.is_empty() {
        return Ok(None);
    }
    v.parse().map(Some).map_err(|_| match j {
        Some(j) => bad_cell(&format!("{name}_{j}"), v, A_NUMBER),
        None => bad_cell(name, v, A_NUMBER),
    })
}

/// A cell of ns (`arrival_ns`, a timing column), None if empty.
pub fn ns_cell(column: &str, v: &str) -> Result<Option<u64>> {
    if v.is_empty() {
        return Ok(None);
    }
    v.parse().map(Some).map_err(|_| bad_cell(column, v, A_NS))
}

/// What `arrival_ns` (A_k − t_k) of an applied reply may be in a run of `study`, ns: at least the
/// transport delay D (the plant adds a latency ≥ 0 to it), and at most D plus the run's span
/// (N + 1)·Ts. A command arriving after the run's end could not have acted in it, and the bound
/// keeps every time the drives add up far from overflow (regression: `u64::MAX` was taken, and
/// wrapped around inside the drives).
pub fn arrivals(study: &Study) -> std::ops::RangeInclusive<u64> {
    let d = study.config.transport_delay_ns();
    let span_ns = (study.reference.n as f64 + 1.0) * study.config.loop_.ts_s * 1e9;
    // `as` saturates: a span beyond u64 (not a valid config) cannot wrap.
    d..=d.saturating_add(span_ns.round() as u64)
}

/// The `arrival_ns` cell of a row whose reply is `fate`, checked against `range`
/// ([`arrivals`]) when the reply was applied.
pub fn arrival_cell(
    v: &str,
    fate: Option<ReplyFate>,
    range: &std::ops::RangeInclusive<u64>,
) -> Result<Option<u64>> {
    let ns = ns_cell(ARRIVAL.name, v)?;
    match ns {
        Some(a) if fate == Some(ReplyFate::Applied) && !range.contains(&a) => Err(bad_cell(
            ARRIVAL.name,
            v,
            &format!(
                "{}..={} ns for an applied reply (the transport delay, plus at most the run's span)",
                range.start(),
                range.end()
            ),
        )),
        _ => Ok(ns),
    }
}

/// The order of a trace's rows as the recorder writes them: each law's rows together, their
/// ticks increasing, each once.
#[derive(Default)]
pub struct RowOrder {
    current: Option<(Law, u64)>,
    done: Vec<Law>,
}

impl RowOrder {
    /// Checks the next row, of `law` at tick `k`.
    pub fn next(&mut self, law: Law, k: u64) -> Result<()> {
        match self.current {
            Some((l, last)) if l == law => {
                if k <= last {
                    return Err(bad_cell(
                        K.name,
                        &k.to_string(),
                        &format!("a tick after tick {last} (each tick once, in order)"),
                    ));
                }
            }
            _ => {
                self.done.extend(self.current.map(|(l, _)| l));
                if self.done.contains(&law) {
                    return Err(bad_cell(
                        LAW.name,
                        law.name(),
                        "each law's rows together (its rows ended above)",
                    ));
                }
            }
        }
        self.current = Some((law, k));
        Ok(())
    }
}

/// The reply's fate and what the drives did; both `unknown` without the plant's telemetry
/// (nothing then says what it did with the reply).
fn fate_and_drives(r: &TickRecord) -> (&'static str, &'static str) {
    if !r.telemetry {
        return (UNKNOWN, UNKNOWN);
    }
    let drives = match (r.rejected, r.held, r.clamped) {
        (true, _, _) => DRIVES_WORDS[3],
        (_, true, _) => DRIVES_WORDS[2],
        (_, _, true) => DRIVES_WORDS[1],
        _ => DRIVES_WORDS[0],
    };
    (r.fate.name(), drives)
}

/// The header line's fields ([`COLUMNS`]: every trace has them).
pub fn header() -> Vec<String> {
    header_of(false)
}

/// The header line's fields of a run's trace: [`COLUMNS`], then [`M_HAT`] if `compensated`.
pub fn header_of(compensated: bool) -> Vec<String> {
    COLUMNS
        .iter()
        .chain(compensated.then_some(&M_HAT))
        .flat_map(|c| {
            if c.per_joint {
                (1..=3).map(|j| format!("{}_{j}", c.name)).collect()
            } else {
                vec![c.name.to_string()]
            }
        })
        .collect()
}

/// Renders tick k's row of `law` into `fields` (one per header field, reused: no allocation once
/// they have grown); fields past the [`header_of`] they were made for are not written.
pub fn render(
    law: Law,
    rec: &TickRecord,
    reference: &RefRow,
    n_true: Option<Vec3>,
    fields: &mut [String],
) {
    use std::fmt::Write as _;
    let row = Row {
        law,
        rec,
        reference,
        n_true,
    };
    let mut f = fields.iter_mut();
    let mut put = |v: Arguments<'_>| {
        if let Some(s) = f.next() {
            s.clear();
            let _ = s.write_fmt(v);
        }
    };
    for c in COLUMNS.iter().chain([&M_HAT]) {
        (c.write)(&row, &mut put);
    }
}

/// `trace.csv` rows of one law ([`COLUMNS`]), written as the ticks are recorded (the file's
/// part for that law; [`join_trace`] puts the parts behind the header).
///
/// Rows are encoded into a buffer of about [`WRITE_BYTES`] and handed to the kernel whole: the
/// file always ends at the end of a row. A write error (a full disk) cuts the file back to its
/// last whole row and is kept (the first one, naming the file): [`TraceWriter::failed`] says so
/// at once, [`TraceWriter::finish`] returns it, and later rows are not written.
pub struct TraceWriter {
    path: PathBuf,
    law: Law,
    rows: csv::Writer<Rows>,
    file: std::fs::File,
    /// Bytes of the file, all of them whole rows.
    whole: u64,
    fields: Vec<String>,
    error: Option<anyhow::Error>,
}

/// The rows a [`TraceWriter`] holds before it writes them, bytes (about a hundred rows).
pub const WRITE_BYTES: usize = 64 * 1024;

/// Encoded rows not yet written (the cell lets the writer empty them behind the encoder).
struct Rows(std::cell::RefCell<Vec<u8>>);

impl std::io::Write for Rows {
    fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
        self.0.get_mut().extend_from_slice(b);
        Ok(b.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl TraceWriter {
    /// Creates the part file `path` for `law`'s rows, starting with the header (a part is a valid
    /// CSV on its own: what a killed run leaves is readable); a `compensated` run's rows end with
    /// [`M_HAT`].
    pub fn create(path: &Path, law: Law, compensated: bool) -> Result<Self> {
        let file = std::fs::File::create(path)
            .with_context(|| format!("cannot create {}", path.display()))?;
        let header = header_of(compensated);
        let mut w = Self {
            path: path.to_path_buf(),
            law,
            rows: csv::WriterBuilder::new()
                .has_headers(false)
                .from_writer(Rows(std::cell::RefCell::new(Vec::with_capacity(
                    WRITE_BYTES + MAX_ROW_BYTES as usize,
                )))),
            file,
            whole: 0,
            fields: vec![String::new(); header.len()],
            error: None,
        };
        w.encode(&header);
        w.write_rows();
        match w.error.take() {
            Some(e) => Err(e),
            None => Ok(w),
        }
    }

    /// Writes tick k's row (into the fields and buffer allocated at creation: no allocation per
    /// row).
    pub fn write(&mut self, rec: &TickRecord, reference: &RefRow, n_true: Option<Vec3>) {
        if self.error.is_some() {
            return;
        }
        render(self.law, rec, reference, n_true, &mut self.fields);
        let fields = std::mem::take(&mut self.fields);
        self.encode(&fields);
        self.fields = fields;
        if self.rows.get_ref().0.borrow().len() >= WRITE_BYTES {
            self.write_rows();
        }
    }

    /// Encodes one row into the buffer (memory only).
    fn encode<T: AsRef<[u8]>>(&mut self, fields: &[T]) {
        // Into a Vec: neither can fail but for memory.
        let _ = self.rows.write_record(fields);
        let _ = self.rows.flush();
    }

    /// Writes the buffered rows; on failure cuts the file back to its last whole row.
    fn write_rows(&mut self) {
        use std::io::Write as _;
        let mut buf = self.rows.get_ref().0.borrow_mut();
        if self.error.is_some() || buf.is_empty() {
            return;
        }
        match self.file.write_all(&buf) {
            Ok(()) => self.whole += buf.len() as u64,
            Err(e) => {
                let _ = self.file.set_len(self.whole);
                self.error = Some(
                    anyhow::Error::new(e).context(format!("cannot write {}", self.path.display())),
                );
            }
        }
        buf.clear();
    }

    /// Whether a write has failed (the rows stop there).
    pub fn failed(&self) -> bool {
        self.error.is_some()
    }

    /// Hands every row so far to the kernel (a killed run keeps them). A failure is kept, as a
    /// row's: [`TraceWriter::failed`] says so, [`TraceWriter::finish`] returns it.
    pub fn flush(&mut self) {
        self.write_rows();
    }

    /// Writes what is left; the first write error, if any.
    pub fn finish(mut self) -> Result<()> {
        self.write_rows();
        match self.error.take() {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }
}

/// The part file of `law`'s rows in run folder `dir`.
pub fn trace_part(dir: &Path, law: Law) -> PathBuf {
    dir.join(format!("trace.{law}.part"))
}

/// The longest `trace.csv` row, bytes: 30 numbers of at most 24 characters and three words make
/// under 1 KiB.
const MAX_ROW_BYTES: u64 = 4096;

/// The largest `trace.csv` a run of `study` can have, bytes: a header and a row per law and tick
/// 0..=N + 1. Its readers (replay, export) stop there, whatever the file.
pub fn max_bytes(study: &Study) -> u64 {
    let laws = study.config.controller.laws.len() as u64;
    let rows = laws.saturating_mul(study.reference.n as u64 + 2);
    rows.saturating_add(1).saturating_mul(MAX_ROW_BYTES)
}

/// Where `law`'s rows are kept when its part could not be joined into `trace.csv` (a full
/// disk): a CSV with the same header.
pub fn trace_of(dir: &Path, law: Law) -> PathBuf {
    dir.join(format!("trace.{law}.csv"))
}

/// Keeps the rows of a law that could not finish (its trace failed: a full disk) apart from
/// `trace.csv`, as [`trace_of`] that law (whole rows up to the failed write).
pub fn keep_apart(dir: &Path, law: Law) {
    let part = trace_part(dir, law);
    if part.is_file() {
        let _ = std::fs::rename(&part, trace_of(dir, law));
    }
}

/// Writes `trace.csv` in `dir` from the part files of `laws`, in order: the first part becomes the
/// file (renamed, not copied: an hour-long trace is gigabytes, and a rename needs no free space),
/// the others are appended without their header lines, and each part is removed once it is in.
/// A missing part (the law never ran) adds no rows; with no part at all the file is the header
/// alone.
///
/// A part that cannot be appended (a full disk) is cut off `trace.csv` again, so the file keeps
/// the laws before it whole, and is renamed [`trace_of`] its law; the error names `trace.csv`
/// and where those rows are.
pub fn join_trace(dir: &Path, laws: &[Law]) -> Result<()> {
    let path = dir.join("trace.csv");
    let parts: Vec<(Law, PathBuf)> = laws
        .iter()
        .map(|&l| (l, trace_part(dir, l)))
        .filter(|(_, p)| p.is_file())
        .collect();
    let Some(((_, first), rest)) = parts.split_first() else {
        let mut line = header().join(",");
        line.push('\n');
        return super::write_text(&path, &line);
    };
    std::fs::rename(first, &path).with_context(|| format!("cannot write {}", path.display()))?;
    let mut out = std::fs::OpenOptions::new()
        .append(true)
        .open(&path)
        .with_context(|| format!("cannot write {}", path.display()))?;
    let mut failed = Vec::new();
    for (law, part) in rest {
        if let Err(e) = append_part(&mut out, part) {
            let kept = trace_of(dir, *law);
            let at = match std::fs::rename(part, &kept) {
                Ok(()) => kept,
                Err(_) => part.clone(),
            };
            failed.push(format!(
                "cannot append the rows of `{law}` to {} ({e:#}): they are in {}",
                path.display(),
                at.display()
            ));
        }
    }
    out.sync_all()
        .with_context(|| format!("cannot write {}", path.display()))?;
    if failed.is_empty() {
        return Ok(());
    }
    anyhow::bail!("{}", failed.join("; "))
}

/// Appends the rows of `part` (its header line skipped) to `out`, syncs them, and removes
/// `part`; on failure `out` is cut back to its length before, and `part` is left as it was.
fn append_part(out: &mut std::fs::File, part: &Path) -> Result<()> {
    use std::io::{BufRead, Seek};
    let before = out.seek(std::io::SeekFrom::End(0))?;
    let mut r = std::io::BufReader::new(
        std::fs::File::open(part).with_context(|| format!("cannot read {}", part.display()))?,
    );
    let mut head = String::new();
    let copied = r
        .read_line(&mut head)
        .with_context(|| format!("cannot read {}", part.display()))
        .and_then(|_| {
            // On disk before the part is removed: a write error that only the sync reports
            // (NFS, EIO) must leave the part in place.
            std::io::copy(&mut r, out)
                .and_then(|_| out.sync_data())
                .map_err(anyhow::Error::from)
        });
    if let Err(e) = copied {
        // Cutting frees what was written: the rows before stay whole, nothing is half there.
        let _ = out.set_len(before);
        return Err(e);
    }
    let _ = std::fs::remove_file(part);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// docs/guide/run-folder.md names every column, in the table's order, with its unit.
    #[test]
    fn the_docs_list_every_trace_column_in_order_with_its_unit() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/guide/run-folder.md");
        let doc = std::fs::read_to_string(&path).unwrap();
        let start = doc.find("- `trace.csv`").expect("the trace.csv entry");
        let entry = &doc[start..start + doc[start..].find("\n- ").unwrap()];
        let mut at = 0;
        for c in COLUMNS.iter().chain([&M_HAT]) {
            let token = if c.per_joint {
                format!("`{}_j", c.name)
            } else {
                format!("`{}`", c.name)
            };
            let found = entry[at..]
                .find(&token)
                .unwrap_or_else(|| panic!("run-folder.md does not list {token} after byte {at}"));
            at += found + token.len();
            if c.per_joint {
                at += entry[at..].find('`').map_or(0, |n| n + 1); // past the closing backtick
            }
            if !c.unit.is_empty() {
                let next = entry[at..].find('`').map_or(entry.len(), |n| at + n);
                assert!(
                    entry[at..next].contains(c.unit),
                    "run-folder.md: no unit {} by {token}",
                    c.unit
                );
            }
        }
    }

    #[test]
    fn the_header_has_one_field_per_column_and_joint() {
        let h = header();
        assert_eq!(h.len(), 3 + 9 * 3 + 3);
        assert_eq!(&h[..4], ["law", "k", "t_s", "q_des_1"]);
        assert_eq!(h.last().map(String::as_str), Some("arrival_ns"));
    }

    /// A trace's rows in the recorder's order: each law's together, ticks increasing; a header
    /// names each column once. Each refusal names the column, the value and what is allowed.
    #[test]
    fn rows_out_of_order_and_columns_twice_are_named() {
        let mut o = RowOrder::default();
        for (law, k) in [(Law::Tdc, 0), (Law::Tdc, 1), (Law::Tdc, 3), (Law::Pid, 0)] {
            o.next(law, k).unwrap();
        }
        assert_eq!(
            o.next(Law::Pid, 0).unwrap_err().to_string(),
            "column k = \"0\": expected a tick after tick 0 (each tick once, in order)"
        );
        assert_eq!(
            o.next(Law::Tdc, 4).unwrap_err().to_string(),
            "column law = \"tdc\": expected each law's rows together (its rows ended above)"
        );
        let h = csv::StringRecord::from(vec!["k", "reply", "k"]);
        assert_eq!(column_at(&h, "reply").unwrap(), 1);
        assert_eq!(
            column_at(&h, "k").unwrap_err().to_string(),
            "column `k` appears twice"
        );
        assert_eq!(
            column_at(&h, "law").unwrap_err().to_string(),
            "no column `law`"
        );
        assert!(drives_cell("held").is_ok());
        assert_eq!(
            drives_cell("braked").unwrap_err().to_string(),
            "column drives = \"braked\": expected commanded, clamped, held, rejected or unknown"
        );
        assert_eq!(reply_cell("unknown").unwrap(), None);
        let r = 100..=200;
        let applied = Some(ReplyFate::Applied);
        assert_eq!(arrival_cell("150", applied, &r).unwrap(), Some(150));
        assert_eq!(arrival_cell("", applied, &r).unwrap(), None);
        assert_eq!(
            arrival_cell("999", Some(ReplyFate::Late), &r).unwrap(),
            Some(999)
        );
        assert_eq!(
            arrival_cell("999", applied, &r).unwrap_err().to_string(),
            "column arrival_ns = \"999\": expected 100..=200 ns for an applied reply (the transport delay, plus at most the run's span)"
        );
        assert_eq!(
            number_cell("s", Some(1), "x").unwrap_err().to_string(),
            "column s_1 = \"x\": expected a number, or empty"
        );
    }
}
