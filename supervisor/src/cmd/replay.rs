//! `deltaloop replay RUN_DIR`: exit 0 when the trace is reproduced byte for byte, 1 otherwise.

use super::{Context, OutArgs};
use crate::ops::replay;
use anyhow::Result;
use deltaloop_report::RunFolder;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
#[command(mut_arg("out", |a| a.help(
    "Where the replayed trace goes (default: RUN_DIR/replay, reused). Must be new or empty, and \
     apart from RUN_DIR (neither inside it nor holding it)"
)))]
pub struct Args {
    /// The run folder.
    run_dir: PathBuf,
    #[command(flatten)]
    out: OutArgs,
    /// Also run the same scenario with ideal timing (no latency, no misses) and say what the
    /// measured latency cost.
    #[arg(long)]
    ideal: bool,
}

pub fn exec(a: Args, _cx: &Context) -> Result<()> {
    let run_dir = a.run_dir.as_path();
    let own = run_dir.join("replay");
    // RUN_DIR/replay is the replay's own folder, reused; any other --out follows `run --out`'s
    // rules, and may not be or hold the run folder (regression: `--out RUN` emptied the run).
    let folder = match a.out.out {
        Some(out) if !RunFolder::same(&out, &own) => RunFolder::claim_apart(
            &out,
            a.out.force,
            &[(run_dir, "the run folder being replayed")],
        )?,
        _ => RunFolder::claim(&own, true)?,
    };
    let (verdict, runs) = match replay::replay(run_dir, folder.path()) {
        Ok(r) => r,
        Err(e) => {
            // Refused before anything was replayed: no empty folder left behind.
            folder.release_unused();
            return Err(e);
        }
    };
    let line = replay::describe(&verdict, run_dir);
    if a.ideal {
        let cfg = deltaloop_config::RunConfig::from_file(&run_dir.join("config.toml"))?;
        let study = deltaloop_study::Study::new(cfg)?;
        let measured: Vec<_> = runs.iter().map(|r| &r.metrics).collect();
        let best = replay::ideal_rms(&study, &measured)?;
        for l in replay::latency_cost(&measured, &best) {
            println!("{l}");
        }
    }
    match verdict {
        replay::Verdict::Identical { .. } => {
            println!("{line}");
            Ok(())
        }
        _ => anyhow::bail!("{line}"),
    }
}
