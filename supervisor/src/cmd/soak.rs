//! `deltaloop soak CONFIG --duration 2h`: the loop for a long time, a summary per minute.

use super::overrides::OverrideArgs;
use super::{Context, OutArgs};
use crate::ops::run::Overrides;
use crate::ops::soak;
use anyhow::Result;
use deltaloop_config::LoopMode;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Scenario file (TOML), e.g. configs/soak.toml (one law, or choose one with --law).
    config: PathBuf,
    /// How long: 90s, 10m, 2h, 1h30m (up to 24h).
    #[arg(long, value_parser = soak::parse_duration)]
    duration: std::time::Duration,
    /// Loop transport (lockstep: --duration is loop time, run as fast as it goes).
    #[arg(long, value_parser = LoopMode::parse_process, default_value = "realtime")]
    mode: LoopMode,
    /// Also write the law's `<law>.mcap` (Foxglove, PlotJuggler, ros2 bag) while it records.
    #[arg(long)]
    mcap: bool,
    #[command(flatten)]
    overrides: OverrideArgs,
    #[command(flatten)]
    out: OutArgs,
}

pub fn exec(a: Args, cx: &Context) -> Result<()> {
    soak::soak(soak::Request {
        config: &a.config,
        duration: a.duration,
        mode: a.mode,
        overrides: &Overrides::from(a.overrides),
        out: a.out.out,
        force: a.out.force,
        command: &cx.command_line,
        tty: cx.tty,
        mcap: a.mcap,
    })
}
