//! `deltaloop export RUN_DIR --mcap`: a finished run as one MCAP file.

use super::Context;
use crate::ops::export;
use anyhow::{Result, bail};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The run folder.
    run_dir: PathBuf,
    /// Write MCAP (Foxglove, PlotJuggler, ros2 bag): the only format so far, and required.
    #[arg(long)]
    mcap: bool,
    /// The file to write (default: RUN_DIR/run.mcap): a new file unless --force, never one of
    /// the run's files.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Replace an existing --out file (never one of the run's files, never through a link).
    #[arg(long)]
    force: bool,
}

pub fn exec(a: Args, _cx: &Context) -> Result<()> {
    if !a.mcap {
        bail!("export: say the format: --mcap (the only one so far)");
    }
    let e = export::export(&export::ExportRequest {
        run_dir: &a.run_dir,
        out: a.out,
        force: a.force,
    })?;
    let total: u64 = e.messages.values().sum();
    println!(
        "{}: {total} messages on {} channels, {:.1} MB",
        e.path.display(),
        e.messages.len(),
        e.bytes as f64 / 1e6
    );
    Ok(())
}
