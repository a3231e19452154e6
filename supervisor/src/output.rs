//! The run folder: `trace.csv`, `summary.json`, `report.md` (the resolved `config.toml` is
//! written by [`crate::run::run`] before the runs).

use crate::analysis::Mismatch;
use crate::metrics::LawMetrics;
use crate::record::{LawRun, TickRecord};
use crate::reference::JointReference;
use crate::timing::TimingSummary;
use anyhow::{Context, Result};
use deltaloop_law::ControllerParams;
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// `summary.json`.
#[derive(Debug, Serialize)]
pub struct Summary<'a> {
    pub scenario: &'a str,
    pub mode: &'a str,
    pub preset: &'a str,
    pub command: &'a str,
    pub started_utc: String,
    /// Control period, s.
    pub ts_s: f64,
    /// N: ticks after tick 0 covered by the metrics.
    pub ticks: usize,
    /// Motion duration T, s.
    pub motion_duration_s: f64,
    pub friction: bool,
    pub tau_max_nm: f64,
    pub tde_delay_samples: u32,
    pub controller: ControllerParams,
    pub mismatch: &'a Mismatch,
    /// Ctrl-C / SIGTERM stopped the run: the data is partial.
    pub interrupted: bool,
    /// Metrics per law, keyed by law name.
    pub laws: BTreeMap<&'a str, &'a LawMetrics>,
    /// The iceoryx2 run id of each law's process pair (process modes only).
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub run_ids: BTreeMap<&'a str, &'a str>,
    /// Loop timing per law (process modes only), keyed by law name.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub timing: BTreeMap<&'a str, &'a TimingSummary>,
}

/// A progress bar over `len` steps on stderr, or a hidden one (`show` false: tests, pipes).
pub fn progress_bar(len: usize, show: bool) -> indicatif::ProgressBar {
    let bar = if show {
        indicatif::ProgressBar::new(len as u64)
    } else {
        indicatif::ProgressBar::hidden()
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} {msg}",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar
}

/// The default run folder: `runs/<UTC time>-<scenario name>`.
pub fn default_run_dir(name: &str) -> PathBuf {
    let stamp = chrono::Utc::now().format("%Y%m%d-%H%M%S");
    PathBuf::from("runs").join(format!("{stamp}-{name}"))
}

/// A run folder this process holds: created (or emptied with `force`), and locked for as long as
/// this value lives, so no two runs ever write into one folder.
#[derive(Debug)]
pub struct RunFolder {
    dir: PathBuf,
    _lock: std::fs::File,
}

/// The lock file in every run folder; its presence also marks a folder as deltaloop's.
const LOCK_FILE: &str = ".deltaloop-lock";

impl RunFolder {
    /// Claims `dir`: refuses a non-empty folder unless `force` (then empties it, but only if it
    /// is a deltaloop folder: one with a lock file, `config.toml`, `summary.json` or a sweep's
    /// `sweep.toml`), and refuses a
    /// folder another run holds, `force` or not.
    pub fn claim(dir: &Path, force: bool) -> Result<Self> {
        let shown = dir.display();
        let entries: Vec<PathBuf> = match std::fs::read_dir(dir) {
            Ok(rd) => rd.filter_map(|e| e.ok().map(|e| e.path())).collect(),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Vec::new(),
            Err(e) => anyhow::bail!("cannot read run folder {shown}: {e}"),
        };
        std::fs::create_dir_all(dir)
            .with_context(|| format!("cannot create run folder {shown}"))?;
        let lock = std::fs::OpenOptions::new()
            .create(true)
            .truncate(false)
            .write(true)
            .open(dir.join(LOCK_FILE))
            .with_context(|| format!("cannot create {}", dir.join(LOCK_FILE).display()))?;
        // SAFETY: flock on a descriptor we own; non-blocking, released when the file closes.
        if unsafe {
            libc::flock(
                std::os::fd::AsRawFd::as_raw_fd(&lock),
                libc::LOCK_EX | libc::LOCK_NB,
            )
        } != 0
        {
            anyhow::bail!(
                "run folder {shown} is in use by another deltaloop run: choose another --out"
            );
        }
        let theirs: Vec<&PathBuf> = entries.iter().filter(|p| !p.ends_with(LOCK_FILE)).collect();
        if !theirs.is_empty() {
            if !force {
                anyhow::bail!(
                    "run folder {shown} is not empty ({} entries): choose another --out, or pass --force to empty and reuse it",
                    theirs.len()
                );
            }
            let ours = entries.iter().any(|p| {
                ["config.toml", "summary.json", "sweep.toml", LOCK_FILE]
                    .iter()
                    .any(|f| p.ends_with(f))
            });
            if !ours {
                anyhow::bail!(
                    "run folder {shown} is not empty and does not look like a deltaloop run folder (no config.toml, summary.json or sweep.toml): refusing to empty it, even with --force"
                );
            }
            for p in theirs {
                let r = if p.is_dir() && !p.is_symlink() {
                    std::fs::remove_dir_all(p)
                } else {
                    std::fs::remove_file(p)
                };
                r.with_context(|| format!("--force: cannot remove {}", p.display()))?;
            }
        }
        Ok(Self {
            dir: dir.to_path_buf(),
            _lock: lock,
        })
    }

    /// The folder.
    pub fn path(&self) -> &Path {
        &self.dir
    }
}

/// UTC now, RFC 3339.
pub fn now_utc() -> String {
    chrono::Utc::now().to_rfc3339_opts(chrono::SecondsFormat::Secs, true)
}

fn header() -> Vec<String> {
    let mut h = vec!["law".to_string(), "k".into(), "t_s".into()];
    for name in [
        "q_des",
        "q",
        "qdot",
        "e",
        "tau",
        "tau_applied",
        "s",
        "n_hat",
        "n_true",
    ] {
        for j in 1..=3 {
            h.push(format!("{name}_{j}"));
        }
    }
    h.extend(["reply".into(), "drives".into()]);
    h
}

/// What the drives did over [t_k, t_{k+1}) (`trace.csv` column `drives`).
fn drives(r: &TickRecord) -> &'static str {
    match (r.rejected, r.held, r.clamped) {
        (true, _, _) => "rejected",
        (_, true, _) => "held",
        (_, _, true) => "clamped",
        _ => "commanded",
    }
}

/// Writes `trace.csv`: one row per tick per law, every float in shortest round-trip exponent form
/// (e.g. `-7.776579935558914e-10`). Columns: law, k, t_s, then per joint q_des (rad), q (rad,
/// true), qdot (rad/s, true), e (rad), tau (commanded τ_k, N m), tau_applied (τᵃ_k, N m), s
/// (rad/s), n_hat (rad/s²), n_true (rad/s²); then `reply` (what became of the controller's reply
/// to tick k: applied, late, skipped, missed) and `drives` (what the drives did over
/// [t_k, t_{k+1}): commanded, clamped, held, rejected). tau, s and n_hat are empty on a tick the
/// controller never answered; n_true is empty where the next state is unknown.
pub fn write_trace(
    path: &Path,
    runs: &[LawRun],
    reference: &JointReference,
    m_bar: f64,
) -> Result<()> {
    let mut w = csv::Writer::from_path(path)
        .with_context(|| format!("cannot create {}", path.display()))?;
    let named = || format!("cannot write {}", path.display());
    w.write_record(header()).with_context(named)?;
    let ts = reference.ts;
    let mut row: Vec<String> = Vec::with_capacity(30);
    for run in runs {
        for (i, r) in run.records.iter().enumerate() {
            let rf = &reference.rows[r.sample.k as usize];
            let truth = run
                .next_of(i)
                .map(|(qd1, tau1)| (qd1 - r.qd_true) / ts - tau1 / m_bar);
            row.clear();
            row.push(run.law.name().into());
            row.push(r.sample.k.to_string());
            row.push(format!("{:e}", rf.t));
            let mut push3 =
                |v: &deltaloop_model::Vec3| row.extend(v.iter().map(|x| format!("{x:e}")));
            push3(&rf.joint.q);
            push3(&r.q_true);
            push3(&r.qd_true);
            push3(&(rf.joint.q - r.q_true));
            let mut opt3 = |v: Option<&deltaloop_model::Vec3>| match v {
                Some(v) => row.extend(v.iter().map(|x| format!("{x:e}"))),
                None => row.extend(std::iter::repeat_n(String::new(), 3)),
            };
            opt3(r.out.as_ref().map(|o| &o.tau));
            opt3(Some(&r.sample.tau_applied));
            opt3(r.out.as_ref().map(|o| &o.s));
            opt3(r.out.as_ref().map(|o| &o.n_hat));
            opt3(truth.as_ref());
            row.push(r.fate.name().into());
            row.push(drives(r).into());
            w.write_record(&row).with_context(named)?;
        }
    }
    w.flush().with_context(named)?;
    Ok(())
}

/// Writes a text file, naming it on failure.
pub fn write_text(path: &Path, text: &str) -> Result<()> {
    std::fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))
}

/// Writes `trace.csv`, `summary.json` and `report.md` into `dir`. The folder's `config.toml` is
/// not written here: [`crate::run::run`] writes it once, before the runs (the child processes
/// read it, and it documents a run that fails).
pub fn write_run_folder(
    dir: &Path,
    summary: &Summary<'_>,
    runs: &[LawRun],
    reference: &JointReference,
    report_md: &str,
) -> Result<()> {
    std::fs::create_dir_all(dir)
        .with_context(|| format!("cannot create run folder {}", dir.display()))?;
    write_text(
        &dir.join("summary.json"),
        &serde_json::to_string_pretty(summary)?,
    )?;
    write_text(&dir.join("report.md"), report_md)?;
    write_trace(
        &dir.join("trace.csv"),
        runs,
        reference,
        summary.controller.m_bar,
    )?;
    Ok(())
}
