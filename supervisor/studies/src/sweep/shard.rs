//! A shard: some points of a plan run into a folder of their own, which says what it holds
//! (`shard.json`: the plan hash, the sweep file, the points) and carries the sweep and its base
//! (`sweep.toml`, `base.toml`), so a merge needs nothing but the folders.

use super::plan::Plan;
use super::{Row, run_job};
use anyhow::{Context, Result, bail};
use deltaloop_config::LoopMode;
use deltaloop_config::files;
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::sync::Mutex;
use std::sync::atomic::Ordering;

/// `shard.json`'s format tag.
pub const FORMAT: &str = "deltaloop-sweep-shard/1";
pub const MANIFEST: &str = "shard.json";

/// Largest `shard.json` read, bytes: its point ids take about 30 bytes each, so 16 MiB holds
/// [`super::MAX_POINTS`] of them many times over.
pub const MAX_MANIFEST_BYTES: u64 = 16 << 20;

/// `shard.json`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    pub format: String,
    /// The sweep's `name`.
    pub sweep: String,
    /// The sweep file as given on the command line (named in the merged report).
    pub sweep_file: String,
    /// SHA-256 of the plan (see [`super::plan`]).
    pub plan_hash: String,
    /// Points in the whole plan.
    pub plan_points: usize,
    /// The ids of the points this shard was asked to run, ascending.
    pub points: Vec<String>,
    /// The `deltaloop` version that ran them.
    pub deltaloop_version: String,
}

impl Manifest {
    pub fn new(plan: &Plan, sweep_file: &str, indices: &[usize]) -> Self {
        Manifest {
            format: FORMAT.into(),
            sweep: plan.sweep.name.clone(),
            sweep_file: sweep_file.into(),
            plan_hash: plan.hash.clone(),
            plan_points: plan.points.len(),
            points: indices.iter().map(|&i| plan.points[i].id.clone()).collect(),
            deltaloop_version: env!("CARGO_PKG_VERSION").into(),
        }
    }

    pub fn write(&self, dir: &Path) -> Result<()> {
        std::fs::write(
            dir.join(MANIFEST),
            serde_json::to_string_pretty(self)? + "\n",
        )
        .with_context(|| format!("cannot write {}", dir.join(MANIFEST).display()))
    }

    /// Reads `dir/shard.json`; a folder without one is not a shard.
    pub fn read(dir: &Path) -> Result<Self> {
        let path = dir.join(MANIFEST);
        let shown = dir.display();
        let bytes = match files::read_regular(&path, MAX_MANIFEST_BYTES, "a shard manifest") {
            Ok(b) => b,
            Err(e) if !path.exists() => bail!(
                "{shown} is not a sweep shard folder: no readable {MANIFEST} ({e}); pass folders written by `deltaloop sweep run` or `deltaloop sweep`"
            ),
            Err(e) => bail!("{shown}: cannot read {MANIFEST}: {e}"),
        };
        let m: Manifest = serde_json::from_slice(&bytes)
            .map_err(|e| anyhow::anyhow!("{shown}: {MANIFEST} is not a shard manifest: {e}"))?;
        if m.format != FORMAT {
            bail!(
                "{shown}: {MANIFEST} has format {:?}: this deltaloop reads {FORMAT:?}",
                m.format
            );
        }
        Ok(m)
    }
}

/// Runs the points `indices` of `plan` into `out` (which exists and is ours): writes
/// `sweep.toml`, `base.toml`, `shard.json`, and appends each point's row to `sweep.csv` as it
/// finishes. Inproc points run on `jobs` threads, process points one at a time. Stops starting
/// points on Ctrl-C / SIGTERM. Returns the rows, in completion order.
pub fn run(
    plan: &Plan,
    indices: &[usize],
    sweep_file: &str,
    out: &Path,
    jobs: usize,
    progress: bool,
) -> Result<Vec<Row>> {
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    std::fs::write(out.join("sweep.toml"), toml::to_string_pretty(&plan.sweep)?)?;
    std::fs::write(out.join("base.toml"), plan.base.to_toml_string())?;
    Manifest::new(plan, sweep_file, indices).write(out)?;
    let bar = deltaloop_report::progress_bar(indices.len(), progress);
    let writer = Mutex::new(
        csv::Writer::from_path(out.join("sweep.csv")).context("cannot create sweep.csv")?,
    );
    let rows: Mutex<Vec<Row>> = Mutex::new(Vec::with_capacity(indices.len()));
    let record = |r: Row| -> Result<()> {
        {
            let mut w = writer.lock().expect("csv writer");
            w.serialize(&r)?;
            w.flush()?;
        }
        bar.set_message(format!(
            "{} {} {} l={} d={} c={}us: {}",
            r.scenario,
            r.preset,
            r.law,
            r.tde_delay_samples,
            r.transport_delay_samples,
            r.compute_delay_us,
            r.status
        ));
        bar.inc(1);
        rows.lock().expect("rows").push(r);
        Ok(())
    };
    let run_one = |i: usize| -> Result<()> {
        let p = &plan.points[i];
        let mut r = run_job(&plan.sweep, &plan.base, &p.job, out);
        r.point = p.id.clone();
        record(r)
    };
    let (parallel, serial): (Vec<usize>, Vec<usize>) = indices
        .iter()
        .partition(|&&i| plan.points[i].mode == LoopMode::Inproc);
    // A worker that hit an error (a row it could not write) ends the sweep's parallel part:
    // the others take no new point.
    let failed = std::sync::atomic::AtomicBool::new(false);
    let done = deltaloop_runner::pool::map(&parallel, jobs, |&i| -> Result<()> {
        if deltaloop_runner::signals::interrupted() || failed.load(Ordering::Relaxed) {
            return Ok(());
        }
        run_one(i).inspect_err(|_| failed.store(true, Ordering::Relaxed))
    });
    done.into_iter().collect::<Result<Vec<()>>>()?;
    for i in serial {
        if deltaloop_runner::signals::interrupted() {
            break;
        }
        run_one(i)?;
    }
    bar.finish_with_message("done");
    Ok(rows.into_inner().expect("rows"))
}
