//! `deltaloop run CONFIG`: one scenario, its laws, one run folder.

use super::overrides::OverrideArgs;
use super::{Context, OutArgs};
use crate::ops::run::{self, Overrides, RunRequest};
use anyhow::Result;
use deltaloop_config::LoopMode;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Scenario file (TOML), e.g. configs/s2-fast.toml.
    config: PathBuf,
    /// Loop transport.
    #[arg(long, value_parser = LoopMode::parse, default_value = "realtime")]
    mode: LoopMode,
    /// Also run each law's round-off twin (the plant started one ulp away) and print every
    /// figure with the digits that survive it (inproc and lockstep; doubles the cost).
    #[arg(long)]
    sensitivity: bool,
    /// Also write each law's `<law>.mcap` (Foxglove, PlotJuggler, ros2 bag) while it records.
    #[arg(long)]
    mcap: bool,
    #[command(flatten)]
    overrides: OverrideArgs,
    #[command(flatten)]
    out: OutArgs,
}

pub fn exec(a: Args, cx: &Context) -> Result<()> {
    let overrides = Overrides::from(a.overrides);
    overrides.check_mode(a.mode)?;
    let cfg = run::load_config(&a.config, &overrides)?;
    overrides.remote.check_run(a.mode, &cfg, a.sensitivity)?;
    let tap = crate::ops::ros2::live_tap(&cfg, overrides.ros2)?;
    let o = run::run(RunRequest {
        tap,
        out: a.out.out,
        force: a.out.force,
        reads: run::config_reads(&a.config, &overrides),
        sensitivity: a.sensitivity,
        mcap: a.mcap,
        ..RunRequest::new(cfg, a.mode, &cx.command_line)
    })?;
    o.print();
    Ok(())
}
