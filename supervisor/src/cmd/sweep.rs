//! `deltaloop sweep`: `sweep FILE` (everything on this machine), and `sweep plan | run | merge`
//! for sweeps split over machines.

use super::{Context, OutArgs};
use crate::ops::sweep::plan::Selection;
use crate::ops::sweep::tasks;
use anyhow::Result;
use clap::Subcommand;
use std::path::PathBuf;

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

/// `deltaloop sweep …`.
pub fn exec(a: Args, cx: &Context) -> Result<()> {
    let said = match a.action {
        None => {
            let sweep = a.sweep.expect("clap requires the sweep file");
            tasks::run_here(&sweep, a.out.out, a.out.force, cx.tty)?
        }
        Some(Action::Plan { sweep, json }) => tasks::plan_text(&sweep, json)?,
        Some(Action::Run {
            sweep,
            points,
            shard,
            base,
            jobs,
            out: OutArgs { out, force },
        }) => tasks::run_shard(tasks::ShardRun {
            sweep: &sweep,
            selection: points.or(shard),
            base: base.as_deref(),
            jobs,
            out,
            force,
            progress: cx.tty,
        })?,
        Some(Action::Merge {
            dirs,
            out: OutArgs { out, force },
            allow_missing,
        }) => {
            let out = out.expect("clap requires --out");
            let (said, missing) = tasks::merge_shards(&dirs, &out, force, allow_missing)?;
            println!("{said}");
            return missing.map_or(Ok(()), Err);
        }
    };
    // A closed pipe (`sweep plan | head`) is not an error worth a panic.
    use std::io::Write;
    let said = if said.ends_with('\n') {
        said
    } else {
        said + "\n"
    };
    let _ = std::io::stdout().lock().write_all(said.as_bytes());
    Ok(())
}
