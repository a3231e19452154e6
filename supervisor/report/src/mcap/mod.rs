//! Runs in MCAP, for Foxglove, PlotJuggler and `ros2 bag` (docs/guide/run-folder.md):
//! `deltaloop export RUN_DIR --mcap` writes a finished run as one file ([`export`]), and
//! `run … --mcap` writes `<law>.mcap` while the law records ([`Live`], a sink of the recorder: a
//! run killed outright leaves every chunk it closed). Every law's channels, stamped on the
//! simulated clock (t = k·Ts):
//!
//! - `/<law>/joint_states`: `sensor_msgs/msg/JointState` (CDR): q (rad), q̇ (rad/s) and the
//!   applied torque τᵃ (N m) of each joint, the numbers of `trace.csv` bit for bit;
//! - `/<law>/control`: JSON, the rest of the trace row (reference, error, command, s, N̂, N, the
//!   reply's fate, the drives, the arrival), every number as the shortest text that reads back
//!   as the same double;
//! - `/<law>/timing`: JSON, the row of `<law>.timing.csv` (process modes) and its round trip;
//! - `/<law>/events`: `foxglove.Log`: missed, late and skipped replies, held and rejected
//!   commands, and how the run ended;
//! - `/<law>/scene`: `foxglove.SceneUpdate`, the robot drawn from the plant's kinematics;
//!   `/reference_path` once;
//!
//! and (in an export) the run's `config.toml` and `summary.json` as attachments. The file is
//! written a chunk at a time (LZ4), a row at a time: memory does not grow with the run.

#[cfg(feature = "foxglove")]
pub mod server;
mod tick;

use crate::trace;
use anyhow::{Context, Result, bail};
use deltaloop_config::files;
use deltaloop_config::{Law, RunConfig};
use deltaloop_mcap::cdr;
use deltaloop_mcap::file::McapFile;
use deltaloop_mcap::scene::{self, Painter};
use deltaloop_model::Vec3;
use deltaloop_study::Study;
use deltaloop_study::record::TickRecord;
use deltaloop_study::reference::RefRow;
use deltaloop_timing::TIMING_COLUMNS;
use mcap::records::Metadata;
use serde::Serialize;
use serde_json::{Value, json};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use tick::{Columns, Row, write_timing};

/// What to export, and where (default `RUN_DIR/run.mcap`).
pub struct ExportRequest<'a> {
    pub run_dir: &'a Path,
    pub out: Option<PathBuf>,
    /// Replace an existing output file (never one of the run's files, never through a link).
    pub force: bool,
}

/// The name of the default output in the run folder.
pub const EXPORT_NAME: &str = "run.mcap";

/// Largest `summary.json` an export reads, bytes (4 MiB): a run's is tens of kB.
pub const MAX_SUMMARY_BYTES: u64 = 4 << 20;

/// What an export wrote.
pub struct Exported {
    pub path: PathBuf,
    /// Messages per channel topic.
    pub messages: BTreeMap<String, u64>,
    pub bytes: u64,
}

/// A JSON schema that says only "an object" (the channel's fields are named in the guide).
const OBJECT_SCHEMA: &str = r#"{"type":"object"}"#;

/// The JSON schema of `foxglove.Log`.
const LOG_SCHEMA: &str = r#"{"title":"foxglove.Log","type":"object","properties":{"timestamp":{"type":"object","properties":{"sec":{"type":"integer"},"nsec":{"type":"integer"}}},"level":{"type":"integer"},"message":{"type":"string"},"name":{"type":"string"},"file":{"type":"string"},"line":{"type":"integer"}}}"#;

/// `foxglove.Log` levels.
pub const INFO: u8 = 2;
pub const WARNING: u8 = 3;
pub const ERROR: u8 = 4;

/// Where the messages go: an MCAP file ([`Out`]) or, with the `foxglove` feature, the live
/// server of `top --foxglove`. Channel and schema ids are the sink's own.
pub trait Bus {
    /// The id of the schema `name` (registered on first use).
    fn schema(&mut self, name: &'static str, encoding: &str, data: &str) -> Result<u16>;
    /// A new channel on `topic` with messages in `encoding`.
    fn channel(&mut self, schema: u16, topic: &str, encoding: &str) -> Result<u16>;
    /// One message at `t_ns` on the simulated clock (ns).
    fn write(&mut self, channel: u16, t_ns: u64, data: &[u8]) -> Result<()>;
    /// Whether anyone reads the messages now (a live server without clients skips the work of
    /// rendering them; a file always reads).
    fn active(&self) -> bool {
        true
    }

    fn json(&mut self, channel: u16, t_ns: u64, v: &impl Serialize) -> Result<()> {
        // One allocation: a tick's control and timing messages are a few hundred bytes.
        let mut buf = Vec::with_capacity(1024);
        serde_json::to_writer(&mut buf, v)?;
        self.write(channel, t_ns, &buf)
    }

    /// A `foxglove.Log` line of `law` at `t_ns`.
    fn log(
        &mut self,
        channel: u16,
        t_ns: u64,
        level: u8,
        law: &str,
        message: String,
    ) -> Result<()> {
        let v = json!({
            "timestamp": {"sec": t_ns / 1_000_000_000, "nsec": t_ns % 1_000_000_000},
            "level": level, "message": message, "name": law, "file": "", "line": 0,
        });
        self.json(channel, t_ns, &v)
    }
}

/// The file being written: its channels, and a message counter per channel.
pub struct Out {
    w: McapFile,
    /// The file's name in errors (an export's output, not its temporary name).
    path: PathBuf,
    counts: BTreeMap<u16, (String, u32)>,
    schemas: BTreeMap<&'static str, u16>,
}

/// The writer's name in the file.
const LIBRARY: &str = concat!("deltaloop ", env!("CARGO_PKG_VERSION"));

impl Out {
    /// A new file at `path`, chunked and LZ4-compressed.
    fn create(path: &Path) -> Result<Self> {
        let w = McapFile::create(path, LIBRARY)
            .with_context(|| format!("cannot create {}", path.display()))?;
        Ok(Self::over(w, path))
    }

    /// The file `w`, named `path` in errors.
    fn over(w: McapFile, path: &Path) -> Self {
        Out {
            w,
            path: path.to_path_buf(),
            counts: BTreeMap::new(),
            schemas: BTreeMap::new(),
        }
    }

    /// What a failed write says (a full disk names the file).
    fn cannot(&self) -> String {
        format!("cannot write {}", self.path.display())
    }
}

impl Bus for Out {
    fn schema(&mut self, name: &'static str, encoding: &str, data: &str) -> Result<u16> {
        if let Some(&id) = self.schemas.get(name) {
            return Ok(id);
        }
        let id = self
            .w
            .add_schema(name, encoding, data.as_bytes())
            .with_context(|| self.cannot())?;
        self.schemas.insert(name, id);
        Ok(id)
    }

    fn channel(&mut self, schema: u16, topic: &str, encoding: &str) -> Result<u16> {
        let id = self
            .w
            .add_channel(schema, topic, encoding)
            .with_context(|| self.cannot())?;
        self.counts.insert(id, (topic.to_string(), 0));
        Ok(id)
    }

    fn write(&mut self, channel: u16, t_ns: u64, data: &[u8]) -> Result<()> {
        let seq = self.counts.get_mut(&channel).map_or(0, |c| {
            c.1 += 1;
            c.1
        });
        self.w
            .write(channel, seq, t_ns, data)
            .with_context(|| self.cannot())
    }
}

/// One law's channels.
struct Channels {
    joints: u16,
    control: u16,
    timing: u16,
    events: u16,
    scene: u16,
}

/// What an export reads of a run folder, read and checked before anything is written.
struct RunInput {
    cfg: RunConfig,
    /// `config.toml` as read (the attachment is what was parsed).
    config_text: String,
    summary_text: String,
    summary: Value,
    study: Study,
    trace_path: PathBuf,
}

impl RunInput {
    /// Reads `dir`'s config and summary (regular files, capped: see [`files`]) and finds its
    /// trace.
    fn read(dir: &Path) -> Result<Self> {
        let not_run = || format!("{} is not a run folder", dir.display());
        let cfg_path = dir.join("config.toml");
        let config_text = files::read_text_file(&cfg_path)
            .map_err(|e| anyhow::anyhow!("cannot read {}: {e}", cfg_path.display()))
            .with_context(not_run)?;
        let cfg = RunConfig::from_toml_str(&config_text, Some(&cfg_path)).with_context(not_run)?;
        let summary_path = dir.join("summary.json");
        let summary_text = files::read_text(&summary_path, MAX_SUMMARY_BYTES, "a summary.json")
            .map_err(|e| anyhow::anyhow!("cannot read {}: {e}", summary_path.display()))?;
        let summary: Value = serde_json::from_str(&summary_text)
            .with_context(|| format!("{}: not JSON", summary_path.display()))?;
        let trace_path = dir.join("trace.csv");
        if std::fs::symlink_metadata(&trace_path).is_err() {
            bail!(
                "{} has no trace.csv (a run with [record] trace = false cannot be exported)",
                dir.display()
            );
        }
        let study = Study::new(cfg.clone()).context("the run's reference")?;
        Ok(Self {
            cfg,
            config_text,
            summary_text,
            summary,
            study,
            trace_path,
        })
    }
}

/// Writes the run in `req.run_dir` as one MCAP file: into a temporary file beside the output,
/// synced, then renamed to it. A failed export leaves the output as it was (a previous export
/// included) and no temporary file.
pub fn export(req: &ExportRequest<'_>) -> Result<Exported> {
    let dir = req.run_dir;
    let input = RunInput::read(dir)?;
    let path = req.out.clone().unwrap_or_else(|| dir.join(EXPORT_NAME));
    check_out(dir, &input.cfg, &path, req.force, req.out.is_some())?;
    let named = || format!("cannot write {}", path.display());
    let tmp = crate::temp_beside(&path).with_context(named)?;
    let file = tmp.as_file().try_clone().with_context(named)?;
    let mut out = Out::over(McapFile::over(file, LIBRARY).with_context(named)?, &path);
    write_export(&mut out, dir, &input)?;
    let Out { w, counts, .. } = out;
    w.close()
        .map_err(anyhow::Error::from)
        .and_then(|f| Ok(f.sync_all()?))
        .with_context(named)?;
    let bytes = tmp.as_file().metadata().map_or(0, |m| m.len());
    // Without --force, a file that appeared at the output meanwhile is not replaced either.
    if req.force {
        tmp.persist(&path).map_err(|e| e.error)
    } else {
        tmp.persist_noclobber(&path).map_err(|e| e.error)
    }
    .with_context(named)?;
    crate::sync_parent(&path);
    let messages = counts
        .into_values()
        .map(|(topic, n)| (topic, u64::from(n)))
        .collect();
    Ok(Exported {
        path,
        messages,
        bytes,
    })
}

/// Refuses an output that would destroy the run (always) or replace a file unasked (without
/// `force`), and any output that is not a regular file or is a symbolic link.
fn check_out(dir: &Path, cfg: &RunConfig, out: &Path, force: bool, given: bool) -> Result<()> {
    let shown = out.display();
    if let Some(what) = run_file(dir, cfg, out) {
        bail!(
            "--out {shown} {what}: writing there would destroy the run; choose another --out (--force does not change this)"
        );
    }
    let meta = match std::fs::symlink_metadata(out) {
        Ok(m) => m,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => bail!("cannot check --out {shown}: {e}"),
    };
    if meta.file_type().is_symlink() {
        let to = std::fs::read_link(out)
            .map(|t| format!(" (to {})", t.display()))
            .unwrap_or_default();
        bail!(
            "--out {shown} is a symbolic link{to}: deltaloop never writes through a link; give a real file as --out"
        );
    }
    if !meta.is_file() {
        bail!(
            "--out {shown} is {}, not a regular file: choose another --out",
            files::kind_of(meta.file_type())
        );
    }
    if !force {
        if !given {
            bail!(
                "{shown} exists (an earlier export): pass --force to replace it, or write elsewhere with --out FILE"
            );
        }
        bail!("--out {shown} exists: choose another --out, or pass --force to replace it");
    }
    Ok(())
}

/// How `out` is one of the run's files ("is the run's trace.csv", "is a hard link to …"), or
/// None. The run's files are every file in `dir` but an earlier export's (`run.mcap`, or another
/// `.mcap` not named after one of the run's laws), compared resolved (links, `..`) and by inode.
fn run_file(dir: &Path, cfg: &RunConfig, out: &Path) -> Option<String> {
    use std::os::unix::fs::MetadataExt;
    let here = crate::resolved(out);
    let inode = std::fs::metadata(out).ok().map(|m| (m.dev(), m.ino()));
    let laws: Vec<String> = cfg
        .controller
        .laws
        .iter()
        .map(|l| format!("{l}.mcap"))
        .collect();
    let exported = |name: &str| {
        name == EXPORT_NAME || (name.ends_with(".mcap") && !laws.iter().any(|l| l == name))
    };
    let entries = std::fs::read_dir(dir).ok()?;
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let Ok(meta) = std::fs::symlink_metadata(entry.path()) else {
            continue;
        };
        if meta.is_dir() || exported(&name) {
            continue;
        }
        if crate::resolved(&entry.path()) == here {
            return Some(format!("is the run's {name}"));
        }
        if inode == Some((meta.dev(), meta.ino())) {
            return Some(format!("is a hard link to the run's {name}"));
        }
    }
    None
}

/// A CSV file of the run, opened by the input rule (a regular file of at most `max_bytes`;
/// `what` names it in that rule's errors), and its header row. Errors name the file.
fn capped_csv(
    path: &Path,
    max_bytes: u64,
    what: &str,
) -> Result<(csv::Reader<files::Capped>, csv::StringRecord)> {
    let file = files::open_regular(path, max_bytes, what)
        .map_err(|e| anyhow::anyhow!("cannot read {}: {e}", path.display()))?;
    let mut rows = csv::Reader::from_reader(file);
    let header = rows
        .headers()
        .with_context(|| format!("cannot read {}", path.display()))?
        .clone();
    Ok((rows, header))
}

/// The messages, attachments and metadata of the run `input` of `dir`, onto `out`.
fn write_export(out: &mut Out, dir: &Path, input: &RunInput) -> Result<()> {
    let (cfg, study, summary) = (&input.cfg, &input.study, &input.summary);
    reference_path(out, study)?;
    let ts_ns = cfg.ts_ns();
    let mut painter = painter(study);
    let trace_path = &input.trace_path;
    let (mut rows, header) = capped_csv(trace_path, trace::max_bytes(study), "this run's trace")?;
    let col = |name: &str| {
        trace::column_at(&header, name).with_context(|| format!("{} line 1", trace_path.display()))
    };
    // Every column of the format, each once, wherever the header puts it.
    for name in trace::header() {
        col(&name)?;
    }
    let cols = Columns::find(&col)?;
    let mut current: Option<(Law, Channels)> = None;
    let mut order = trace::RowOrder::default();
    let arrivals = trace::arrivals(study);
    for (i, row) in rows.records().enumerate() {
        let line = i + 2;
        let at = || format!("{} line {line}", trace_path.display());
        let row = row.with_context(at)?;
        let cell = |i| row.get(i).unwrap_or("");
        let law = trace::law_cell(cell(cols.law)).with_context(at)?;
        let r = Row::parse(&cell, &cols, &arrivals).with_context(at)?;
        order.next(law, r.k).with_context(at)?;
        if current.as_ref().is_none_or(|(l, _)| *l != law) {
            if let Some((done, ch)) = current.take() {
                finish_law(out, dir, study, summary, done.name(), &ch)?;
            }
            current = Some((law, law_channels(out, law.name())?));
        }
        let Some((_, ch)) = current.as_ref() else {
            continue;
        };
        r.write(out, ch, law.name(), &cols, ts_ns, Some((&mut painter, 1)))?;
    }
    if let Some((done, ch)) = current.take() {
        finish_law(out, dir, study, summary, done.name(), &ch)?;
    }
    for (name, media, data) in [
        ("config.toml", "application/toml", &input.config_text),
        ("summary.json", "application/json", &input.summary_text),
    ] {
        out.w
            .writer()
            .attach(&mcap::Attachment {
                log_time: 0,
                create_time: 0,
                name: name.into(),
                media_type: media.into(),
                data: data.as_bytes().into(),
            })
            .with_context(|| out.cannot())?;
    }
    let metadata = Metadata {
        name: "deltaloop".into(),
        metadata: BTreeMap::from([
            ("scenario".into(), cfg.name.clone()),
            ("ts_s".into(), format!("{:e}", cfg.loop_.ts_s)),
            (
                "mode".into(),
                summary["mode"].as_str().unwrap_or("").to_string(),
            ),
            (
                "command".into(),
                summary["command"].as_str().unwrap_or("").to_string(),
            ),
        ]),
    };
    out.w
        .writer()
        .write_metadata(&metadata)
        .with_context(|| out.cannot())?;
    Ok(())
}

/// The reference path's channel, and the path (task space, every tick up to 2000 points) drawn
/// on it at t = 0.
fn reference_path(out: &mut impl Bus, study: &Study) -> Result<u16> {
    let s = out.schema(
        "foxglove.SceneUpdate",
        "jsonschema",
        scene::SCENE_UPDATE_SCHEMA,
    )?;
    let ch = out.channel(s, "/reference_path", "json")?;
    draw_reference(out, ch, study)?;
    Ok(ch)
}

/// The reference path's message on channel `ch`.
fn draw_reference(out: &mut impl Bus, ch: u16, study: &Study) -> Result<()> {
    let n = study.reference.row_count();
    let stride = n.div_ceil(2000).max(1);
    let points: Vec<Vec3> = (0..n)
        .step_by(stride)
        .map(|k| study.reference.row(k).task.x)
        .collect();
    out.write(ch, 0, &scene::path(&points)?)
}

/// The robot's painter for `study` (its payload step included).
fn painter(study: &Study) -> Painter {
    let cfg = &study.config;
    let payload = cfg
        .payload_step_tick()
        .map(|k| (k, cfg.plant.payload_step_kg));
    Painter::new(study.robot.clone(), payload)
}

fn law_channels(out: &mut impl Bus, law: &str) -> Result<Channels> {
    let js = out.schema(
        "sensor_msgs/msg/JointState",
        "ros2msg",
        cdr::JOINT_STATE_MSGDEF,
    )?;
    let obj = out.schema("deltaloop.Tick", "jsonschema", OBJECT_SCHEMA)?;
    let log = out.schema("foxglove.Log", "jsonschema", LOG_SCHEMA)?;
    let sc = out.schema(
        "foxglove.SceneUpdate",
        "jsonschema",
        scene::SCENE_UPDATE_SCHEMA,
    )?;
    Ok(Channels {
        joints: out.channel(js, &format!("/{law}/joint_states"), "cdr")?,
        control: out.channel(obj, &format!("/{law}/control"), "json")?,
        timing: out.channel(obj, &format!("/{law}/timing"), "json")?,
        events: out.channel(log, &format!("/{law}/events"), "json")?,
        scene: out.channel(sc, &format!("/{law}/scene"), "json")?,
    })
}

/// After a law's rows: its timing rows (`<law>.timing.csv`, a regular file of at most the
/// size the run's rows can have) and how it ended.
fn finish_law(
    out: &mut impl Bus,
    dir: &Path,
    study: &Study,
    summary: &Value,
    law: &str,
    ch: &Channels,
) -> Result<()> {
    let ts_ns = study.config.ts_ns();
    let timing = dir.join(format!("{law}.timing.csv"));
    if std::fs::symlink_metadata(&timing).is_ok() {
        let (mut rows, header) = capped_csv(&timing, timing_max_bytes(study), "a timing.csv")?;
        // Read by name: every column of the format, each once.
        let at: Vec<usize> = TIMING_COLUMNS
            .iter()
            .map(|name| {
                trace::column_at(&header, name)
                    .with_context(|| format!("{} line 1", timing.display()))
            })
            .collect::<Result<_>>()?;
        let order = tick::timing_order(TIMING_COLUMNS.into_iter());
        for (i, row) in rows.records().enumerate() {
            let line = || format!("{} line {}", timing.display(), i + 2);
            let row = row.with_context(line)?;
            let cells = timing_row(&row, &at).with_context(line)?;
            write_timing(out, ch, ts_ns, &cells, &order)?;
        }
    }
    ending(out, ch, law, &summary["laws"][law], ts_ns)
}

/// What a timing cell holds.
const TIMING_CELL: &str = "a whole number (ns, a tick, or a 0/1 flag), or empty";

/// A timing row's cells by name ([`TIMING_COLUMNS`], at columns `at`): ns, counts or flags, each
/// a whole number or empty; the tick `k` is always there.
fn timing_row<'a>(row: &csv::StringRecord, at: &[usize]) -> Result<[(&'a str, Option<u64>); 13]> {
    let mut cells = [("", None); 13];
    for (i, (name, &col)) in TIMING_COLUMNS.iter().zip(at).enumerate() {
        let v = row.get(col).unwrap_or("");
        let n = match v {
            "" => None,
            v => Some(
                v.parse()
                    .map_err(|_| trace::bad_cell(name, v, TIMING_CELL))?,
            ),
        };
        cells[i] = (*name, n);
    }
    if cells[0].1.is_none() {
        return Err(trace::bad_cell("k", "", "a tick number (0, 1, 2, …)"));
    }
    Ok(cells)
}

/// The longest `<law>.timing.csv` row, bytes: 13 numbers of at most 20 digits make under 300.
const MAX_TIMING_ROW_BYTES: u64 = 512;

/// The largest `<law>.timing.csv` a run of `study` can have, bytes: a header and a row per tick
/// 0..=N + 1 and per tick of a safe stop after it (`faults.safe_stop_ms`).
fn timing_max_bytes(study: &Study) -> u64 {
    let cfg = &study.config;
    let brake = (f64::from(cfg.faults.safe_stop_ms) * 1e-3 / cfg.loop_.ts_s).ceil() as u64;
    let rows = (study.reference.n as u64)
        .saturating_add(brake)
        .saturating_add(3);
    rows.saturating_mul(MAX_TIMING_ROW_BYTES)
}

/// The last event of a law: how it ended, from its metrics (`summary.json`'s entry).
fn ending(out: &mut impl Bus, ch: &Channels, law: &str, m: &Value, ts_ns: u64) -> Result<()> {
    let status = m["status"].as_str().unwrap_or("unknown");
    let (tick, level, why) = if let Some(t) = m["fault_at_tick"].as_u64() {
        (t, ERROR, m["fault"].as_str().unwrap_or(""))
    } else if let Some(t) = m["diverged_at_tick"].as_u64() {
        (t, ERROR, m["diverged_reason"].as_str().unwrap_or(""))
    } else if let Some(t) = m["interrupted_at_tick"].as_u64() {
        (t, WARNING, "stopped on request")
    } else {
        (m["ticks"].as_u64().unwrap_or(0), INFO, "")
    };
    let line = if why.is_empty() {
        format!("run {status}")
    } else {
        format!("run {status} at tick {tick}: {why}")
    };
    out.log(ch.events, tick * ts_ns, level, law, line)
}

/// `<law>.mcap` written while the law records: a sink of the recorder, one row at a time (the
/// trace's own rendering of the row, so both say the same numbers). A run killed outright
/// leaves every chunk this closed (readers open the file up to its last chunk).
pub struct Live<B: Bus = Out> {
    out: B,
    ch: Channels,
    cols: Columns,
    law: Law,
    ts_ns: u64,
    painter: Painter,
    fields: Vec<String>,
    /// The order of the timing message's keys.
    timing_order: Vec<usize>,
    /// The robot is drawn every this many ticks.
    scene_every: u64,
    /// The reference path's channel.
    reference: u16,
}

impl Live {
    /// Starts `path` for `law` of `study`.
    pub fn create(path: &Path, study: &Study, law: Law) -> Result<Self> {
        Live::over(Out::create(path)?, study, law, 1)
    }

    /// Ends the file with how the law ended (its metrics, as `summary.json` has them).
    pub fn finish(mut self, metrics: &Value) -> Result<()> {
        ending(
            &mut self.out,
            &self.ch,
            self.law.name(),
            metrics,
            self.ts_ns,
        )?;
        // Closed, not dropped: a write the disk refuses is an error, not a silent loss.
        let cannot = self.out.cannot();
        self.out.w.close().context(cannot)?;
        Ok(())
    }
}

impl<B: Bus> Live<B> {
    /// `law` of `study` on `out`, the robot drawn every `scene_every` ticks (≥ 1).
    pub fn over(mut out: B, study: &Study, law: Law, scene_every: u64) -> Result<Self> {
        let reference = reference_path(&mut out, study)?;
        let ch = law_channels(&mut out, law.name())?;
        let header = trace::header();
        let cols = Columns::find(&|name: &str| {
            header
                .iter()
                .position(|h| h == name)
                .with_context(|| format!("no trace column {name}"))
        })?;
        let cfg = &study.config;
        Ok(Self {
            out,
            ch,
            cols,
            law,
            ts_ns: cfg.ts_ns(),
            painter: painter(study),
            fields: vec![String::new(); header.len()],
            timing_order: tick::timing_order(TIMING_COLUMNS.into_iter()),
            scene_every: scene_every.max(1),
            reference,
        })
    }

    /// Draws the reference path again (a client that joined a live stream late has not seen it).
    pub fn reference_again(&mut self, study: &Study) -> Result<()> {
        draw_reference(&mut self.out, self.reference, study)
    }

    /// The bus the messages go to.
    pub fn bus(&self) -> &B {
        &self.out
    }

    /// The bus, once the law is done.
    pub fn into_bus(self) -> B {
        self.out
    }

    /// A line on the law's events channel at tick k.
    pub fn event(&mut self, k: u64, level: u8, message: String) -> Result<()> {
        let t = k * self.ts_ns;
        self.out
            .log(self.ch.events, t, level, self.law.name(), message)
    }

    /// Writes tick k's messages; an error is returned (the caller keeps the first).
    pub fn take(&mut self, r: &TickRecord, row: &RefRow, n_true: Option<Vec3>) -> Result<()> {
        if !self.out.active() {
            return Ok(());
        }
        trace::render(self.law, r, row, n_true, &mut self.fields);
        let fields = &self.fields;
        let cell = |i| fields.get(i).map_or("", String::as_str);
        // The recorder's own row: any arrival it measured.
        let row = Row::parse(&cell, &self.cols, &(0..=u64::MAX))?;
        row.write(
            &mut self.out,
            &self.ch,
            self.law.name(),
            &self.cols,
            self.ts_ns,
            Some((&mut self.painter, self.scene_every)),
        )
    }

    /// Writes tick k's timing row (process modes: what `<law>.timing.csv` gets).
    pub fn timing(&mut self, cells: &[Option<u64>; 13]) -> Result<()> {
        if !self.out.active() {
            return Ok(());
        }
        let cells: [(&str, Option<u64>); 13] =
            std::array::from_fn(|i| (TIMING_COLUMNS[i], cells[i]));
        write_timing(
            &mut self.out,
            &self.ch,
            self.ts_ns,
            &cells,
            &self.timing_order,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use deltaloop_law::Output;
    use deltaloop_model::PlantSample;
    use deltaloop_study::record::ReplyFate;

    /// A bus that drops every message.
    struct Discard;

    impl Bus for Discard {
        fn schema(&mut self, _: &'static str, _: &str, _: &str) -> Result<u16> {
            Ok(0)
        }
        fn channel(&mut self, _: u16, _: &str, _: &str) -> Result<u16> {
            Ok(0)
        }
        fn write(&mut self, _: u16, _: u64, _: &[u8]) -> Result<()> {
            Ok(())
        }
    }

    /// Regression: a 10-minute realtime soak with `--mcap` in a test build ended `lost_data`
    /// (664 079 ticks lost from the supervisor's queues): each tick's messages were built as trees
    /// of JSON values, the robot's scene alone hundreds of allocations, and the supervisor fell
    /// behind the 3.3 kHz loop. A tick's joint state, control, timing and scene messages now take
    /// a handful of allocations (the parsed row's, one buffer per message but the scene's).
    #[test]
    fn regression_mcap_soak_lost_ticks_a_tick_allocates_a_handful() {
        let cfg =
            RunConfig::from_toml_str("name = \"t\"\n[scenario]\npath = \"s1\"\n", None).unwrap();
        let study = Study::new(cfg).unwrap();
        let mut live = Live::over(Discard, &study, Law::Tdc, 1).unwrap();
        let mut tick = |k: u64| {
            let row = study.reference.row(k as usize);
            let q = row.joint.q;
            let out = Output {
                tau: Vec3::new(0.1, -0.2, 0.3),
                s: Vec3::zeros(),
                n_hat: Vec3::zeros(),
                u: Vec3::zeros(),
            };
            let r = TickRecord {
                sample: PlantSample {
                    k,
                    q,
                    qd: row.joint.qd,
                    tau_applied: out.tau,
                },
                q_true: q,
                qd_true: row.joint.qd,
                out: Some(out),
                tau: out.tau,
                fate: ReplyFate::Applied,
                clamped: false,
                held: false,
                rejected: false,
                arrival_ns: Some(41_000),
                telemetry: true,
                m_hat: None,
            };
            live.take(&r, &row, None).unwrap();
            let t = k * 300_000;
            live.timing(&std::array::from_fn(|i| Some(t + i as u64)))
                .unwrap();
        };
        // The first ticks size the reused buffers.
        (0..10).for_each(&mut tick);
        let before = crate::alloc_count::allocations();
        (10..110).for_each(&mut tick);
        let per_tick = (crate::alloc_count::allocations() - before) as f64 / 100.0;
        assert!(per_tick <= 12.0, "{per_tick} allocations a tick");
    }

    /// A run folder whose trace.csv is missing is refused in one line naming it.
    #[test]
    fn a_folder_without_a_trace_is_refused_in_one_line() {
        let d = tempfile::tempdir().unwrap();
        let cfg =
            RunConfig::from_toml_str("name = \"t\"\n[scenario]\npath = \"s1\"\n", None).unwrap();
        std::fs::write(d.path().join("config.toml"), cfg.to_toml_string()).unwrap();
        std::fs::write(d.path().join("summary.json"), "{}").unwrap();
        let e = export(&ExportRequest {
            run_dir: d.path(),
            out: None,
            force: false,
        })
        .err()
        .unwrap()
        .to_string();
        assert!(e.contains("has no trace.csv") && !e.contains('\n'), "{e}");
    }
}
