//! What each form of `deltaloop sweep` does, with the folder it claims and what it tells the
//! user, as plain calls: the command line only parses and prints.

use super::plan::{self, Plan, Selection};
use super::{Row, merge, shard};
use anyhow::Result;
use deltaloop_report::{RunFolder, default_run_dir};
use deltaloop_study::record::RunStatus;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// `sweep FILE`: every point on this machine into `out` (default `runs/sweep-<name>`); returns
/// the line to print.
pub fn run_here(sweep: &Path, out: Option<PathBuf>, force: bool, progress: bool) -> Result<String> {
    let t0 = Instant::now();
    let (sw, base) = super::load(sweep)?;
    let out = out.unwrap_or_else(|| default_run_dir(&format!("sweep-{}", sw.name)));
    let reads = sweep_reads(sweep, super::base_path(sweep, &sw, None), &base);
    let _folder = RunFolder::claim_apart(&out, force, &reads)?;
    let rows = super::run_loaded(&sw, &base, sweep, &out, progress)?;
    Ok(format!(
        "{}\nsweep folder: {}",
        counts(&rows, t0.elapsed().as_secs_f64()),
        out.display()
    ))
}

/// What a sweep reads, each with what it is: the sweep file, its base config and the files the
/// base's commands name. Its folder may be, hold or lie inside none of them.
fn sweep_reads(
    sweep: &Path,
    base_path: PathBuf,
    base: &deltaloop_config::RunConfig,
) -> Vec<(PathBuf, &'static str)> {
    let mut v = vec![
        (sweep.to_path_buf(), "the sweep file"),
        (base_path, "the sweep's base config"),
    ];
    v.extend(deltaloop_runner::run::command_files(base));
    v
}

/// `sweep plan FILE`: every point with its id, as text or (for a cluster driver) JSON. Every
/// point is checked here, once, before a cluster runs any.
pub fn plan_text(sweep: &Path, json: bool) -> Result<String> {
    let (sw, base) = super::load(sweep)?;
    let plan = Plan::new(sw, base)?;
    plan.check_points(&(0..plan.points.len()).collect::<Vec<_>>())?;
    let shown = sweep.display().to_string();
    Ok(if json {
        plan.to_json(&shown)? + "\n"
    } else {
        plan.to_text(&shown)
    })
}

/// `sweep run FILE --points|--shard`: some points into a shard folder.
pub struct ShardRun<'a> {
    pub sweep: &'a Path,
    /// The points (None: all).
    pub selection: Option<Selection>,
    /// A copy of the base config to read instead of the sweep file's `base`.
    pub base: Option<&'a Path>,
    /// Threads for inproc points (None: one per CPU).
    pub jobs: Option<u32>,
    pub out: Option<PathBuf>,
    pub force: bool,
    pub progress: bool,
}

/// Runs a [`ShardRun`]; returns the line to print (an error on Ctrl-C, naming the folder).
pub fn run_shard(r: ShardRun<'_>) -> Result<String> {
    let t0 = Instant::now();
    let (sw, base) = super::load_with_base(r.sweep, r.base)?;
    let reads = sweep_reads(r.sweep, super::base_path(r.sweep, &sw, r.base), &base);
    let plan = Plan::new(sw, base)?;
    let idx = r
        .selection
        .unwrap_or(Selection::All)
        .indices(plan.points.len())?;
    plan.check_points(&idx)?;
    let out = r
        .out
        .unwrap_or_else(|| default_run_dir(&format!("sweep-{}-shard", plan.sweep.name)));
    let _folder = RunFolder::claim_apart(&out, r.force, &reads)?;
    let jobs = r.jobs.map_or_else(
        || std::thread::available_parallelism().map_or(1, |n| n.get()),
        |j| j as usize,
    );
    let shown = r.sweep.display().to_string();
    let rows = shard::run(&plan, &idx, &shown, &out, jobs, r.progress)?;
    if deltaloop_runner::signals::interrupted() {
        return Err(anyhow::Error::new(deltaloop_runner::run::Interrupted(out)));
    }
    Ok(format!(
        "{} of {} points of plan {}: {}\nshard folder: {}",
        idx.len(),
        plan.points.len(),
        plan.short_hash(),
        counts(&rows, t0.elapsed().as_secs_f64()),
        out.display()
    ))
}

/// `sweep merge DIRS --out OUT`: shard folders into one sweep folder. Everything is read and
/// checked before the output folder is made, and a merge never empties its input. Returns the
/// line to print and, with points missing (their outputs written with `allow_missing`), the
/// error that names how to run them.
pub fn merge_shards(
    dirs: &[PathBuf],
    out: &Path,
    force: bool,
    allow_missing: bool,
) -> Result<(String, Option<anyhow::Error>)> {
    let t0 = Instant::now();
    let opts = merge::Options {
        allow_missing,
        interrupted: false,
    };
    let m = merge::gather(dirs, opts)?;
    let shards: Vec<(&Path, &str)> = dirs.iter().map(|d| (d.as_path(), "shard folder")).collect();
    let _folder = RunFolder::claim_apart(out, force, &shards)?;
    merge::write(&m.plan, &m.rows, &m.missing, &m.sweep_file, out, opts)?;
    for d in dirs {
        merge::copy_points(d, out)?;
    }
    let said = format!(
        "merged {} shard folder(s), {} of {} points of plan {}: {}\nsweep folder: {}",
        dirs.len(),
        m.rows.len(),
        m.plan.points.len(),
        m.plan.short_hash(),
        counts(&m.rows, t0.elapsed().as_secs_f64()),
        out.display()
    );
    let missing = (!m.missing.is_empty()).then(|| {
        anyhow::anyhow!(
            "{} of {} points missing (listed in {}): re-run them with `deltaloop sweep run {} --points {}`",
            m.missing.len(),
            m.plan.points.len(),
            out.join("report.md").display(),
            m.sweep_file,
            plan::ranges_text(&m.missing)
        )
    });
    Ok((said, missing))
}

/// `N points in T s: … ok, … diverged, …` (and the runs, when points repeat).
pub fn counts(rows: &[Row], secs: f64) -> String {
    let n = |st: RunStatus| rows.iter().filter(|r| r.status == st).count();
    // An interrupted point is not a run that finished: counted apart, when there is one.
    let interrupted = n(RunStatus::Interrupted);
    let runs: u64 = rows
        .iter()
        .filter(|r| r.status != RunStatus::Interrupted)
        .map(|r| u64::from(r.repeats))
        .sum();
    let points = rows.len() - interrupted;
    format!(
        "{points} points{} in {secs:.1} s: {} ok, {} diverged, {} stopped, {} errors{}{}",
        if runs as usize == points {
            String::new()
        } else {
            format!(" ({runs} runs)")
        },
        n(RunStatus::Ok),
        n(RunStatus::Diverged),
        n(RunStatus::Fault) + n(RunStatus::Stopped),
        n(RunStatus::Error),
        match n(RunStatus::LostData) {
            0 => String::new(),
            l => format!(", {l} lost data"),
        },
        if interrupted > 0 {
            format!(" ({interrupted} interrupted, not counted)")
        } else {
            String::new()
        },
    )
}
