//! `deltaloop sweep`: `sweep FILE` (everything on this machine), and `sweep plan | run | merge`
//! for sweeps split over machines.

use super::{Context, OutArgs};
use crate::ops::sweep::plan::{self, Plan, Selection};
use crate::ops::sweep::{self as ops, Row, merge, shard};
use crate::record::RunStatus;
use anyhow::Result;
use clap::Subcommand;
use std::path::{Path, PathBuf};

#[derive(clap::Args, Debug)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub struct Args {
    #[command(subcommand)]
    action: Option<Action>,
    /// Sweep file (TOML): runs every point on this machine (plan, run, merge in one).
    #[arg(required = true)]
    sweep: Option<PathBuf>,
    #[command(flatten)]
    out: OutArgs,
}

#[derive(Subcommand, Debug)]
enum Action {
    /// List every point of a sweep file with its stable id (same file, same ids, anywhere).
    Plan {
        /// Sweep file (TOML).
        sweep: PathBuf,
        /// Print JSON (the sweep and base as TOML text, the points and the CPUs each needs): what
        /// a cluster driver reads.
        #[arg(long)]
        json: bool,
    },
    /// Run some points of a sweep into a shard folder (merge the folders with `sweep merge`).
    Run {
        /// Sweep file (TOML).
        sweep: PathBuf,
        /// Point indices: `120-239`, or `3,7,10-12` (inclusive, from 0; see `sweep plan`).
        #[arg(long, value_parser = Selection::parse_points, conflicts_with = "shard")]
        points: Option<Selection>,
        /// Shard K of N (1 <= K <= N): the points whose index i has i mod N = K - 1.
        #[arg(long, value_parser = Selection::parse_shard)]
        shard: Option<Selection>,
        /// Read the base config from this file instead of the sweep file's `base` (a copy shipped
        /// to a cluster worker). The plan hash still checks it is the same config.
        #[arg(long)]
        base: Option<PathBuf>,
        /// Threads for inproc points (default: one per CPU); process points run one at a time.
        #[arg(long, value_parser = clap::value_parser!(u32).range(1..=1024))]
        jobs: Option<u32>,
        #[command(flatten)]
        out: OutArgs,
    },
    /// Merge shard folders into one sweep folder: sweep.csv, sweep.json, report.md and plots, as
    /// `deltaloop sweep FILE` writes them. Every point must be there exactly once.
    #[command(mut_arg("out", |a| a.required(true)))]
    Merge {
        /// Shard folders (from `sweep run`, `sweep`, or an earlier merge).
        #[arg(required = true)]
        dirs: Vec<PathBuf>,
        #[command(flatten)]
        out: OutArgs,
        /// Write the outputs even when points are missing (the report lists them); exits 1.
        #[arg(long)]
        allow_missing: bool,
    },
}

/// `N points in T s: … ok, … diverged, …` (and the runs, when points repeat).
fn counts(rows: &[Row], secs: f64) -> String {
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

/// `deltaloop sweep …`.
pub fn exec(a: Args, cx: &Context) -> Result<()> {
    let t0 = std::time::Instant::now();
    match a.action {
        None => {
            let sweep = a.sweep.expect("clap requires the sweep file");
            let (sw, base) = ops::load(&sweep)?;
            let out = a
                .out
                .out
                .unwrap_or_else(|| crate::output::default_run_dir(&format!("sweep-{}", sw.name)));
            let _folder = crate::output::RunFolder::claim_apart(
                &out,
                a.out.force,
                &[(&sweep, "the sweep file")],
            )?;
            let rows = ops::run_loaded(&sw, &base, &sweep, &out, cx.tty)?;
            println!(
                "{}\nsweep folder: {}",
                counts(&rows, t0.elapsed().as_secs_f64()),
                out.display()
            );
            Ok(())
        }
        Some(Action::Plan { sweep, json }) => {
            let (sw, base) = ops::load(&sweep)?;
            let plan = Plan::new(sw, base)?;
            // Every point is checked here, once, before a cluster runs any.
            plan.check_points(&(0..plan.points.len()).collect::<Vec<_>>())?;
            let shown = sweep.display().to_string();
            use std::io::Write;
            let text = if json {
                plan.to_json(&shown)? + "\n"
            } else {
                plan.to_text(&shown)
            };
            // A closed pipe (`| head`) is not an error worth a panic.
            let _ = std::io::stdout().lock().write_all(text.as_bytes());
            Ok(())
        }
        Some(Action::Run {
            sweep,
            points,
            shard,
            base,
            jobs,
            out: OutArgs { out, force },
        }) => {
            let (sw, base) = ops::load_with_base(&sweep, base.as_deref())?;
            let plan = Plan::new(sw, base)?;
            let sel = points.or(shard).unwrap_or(Selection::All);
            let idx = sel.indices(plan.points.len())?;
            plan.check_points(&idx)?;
            let out = out.unwrap_or_else(|| {
                crate::output::default_run_dir(&format!("sweep-{}-shard", plan.sweep.name))
            });
            let _folder =
                crate::output::RunFolder::claim_apart(&out, force, &[(&sweep, "the sweep file")])?;
            let jobs = jobs.map_or_else(
                || std::thread::available_parallelism().map_or(1, |n| n.get()),
                |j| j as usize,
            );
            let rows = shard::run(
                &plan,
                &idx,
                &sweep.display().to_string(),
                &out,
                jobs,
                cx.tty,
            )?;
            if crate::loops::signals::interrupted() {
                return Err(anyhow::Error::new(crate::ops::run::Interrupted(out)));
            }
            println!(
                "{} of {} points of plan {}: {}\nshard folder: {}",
                idx.len(),
                plan.points.len(),
                plan.short_hash(),
                counts(&rows, t0.elapsed().as_secs_f64()),
                out.display()
            );
            Ok(())
        }
        Some(Action::Merge {
            dirs,
            out: OutArgs { out, force },
            allow_missing,
        }) => {
            let out = out.expect("clap requires --out");
            merge_cmd(&dirs, &out, force, allow_missing, t0)
        }
    }
}

fn merge_cmd(
    dirs: &[PathBuf],
    out: &Path,
    force: bool,
    allow_missing: bool,
    t0: std::time::Instant,
) -> Result<()> {
    let opts = merge::Options {
        allow_missing,
        interrupted: false,
    };
    // Everything is read and checked before the output folder is made.
    let m = merge::gather(dirs, opts)?;
    // Not a shard, nor a folder holding one or inside one: a merge never empties its input.
    let shards: Vec<(&Path, &str)> = dirs.iter().map(|d| (d.as_path(), "shard folder")).collect();
    let _folder = crate::output::RunFolder::claim_apart(out, force, &shards)?;
    merge::write(&m.plan, &m.rows, &m.missing, &m.sweep_file, out, opts)?;
    for d in dirs {
        merge::copy_points(d, out)?;
    }
    println!(
        "merged {} shard folder(s), {} of {} points of plan {}: {}\nsweep folder: {}",
        dirs.len(),
        m.rows.len(),
        m.plan.points.len(),
        m.plan.short_hash(),
        counts(&m.rows, t0.elapsed().as_secs_f64()),
        out.display()
    );
    if !m.missing.is_empty() {
        anyhow::bail!(
            "{} of {} points missing (listed in {}): re-run them with `deltaloop sweep run {} --points {}`",
            m.missing.len(),
            m.plan.points.len(),
            out.join("report.md").display(),
            m.sweep_file,
            plan::ranges_text(&m.missing)
        );
    }
    Ok(())
}
