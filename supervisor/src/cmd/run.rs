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
    refuse_if_too_big(&cfg, a.mode, a.out.out.as_deref())?;
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

/// Refuses up front a run whose per-tick files would not fit on the disk of its run folder (a
/// long `--hold-s`), as `soak` refuses a long `--duration`.
fn refuse_if_too_big(
    cfg: &deltaloop_config::RunConfig,
    mode: LoopMode,
    out: Option<&std::path::Path>,
) -> Result<()> {
    let laws = cfg.controller.laws.len() as u64;
    // Ticks 0..=N and the state after them, per law.
    let ticks = (cfg.ticks(cfg.motion_duration_s()) + 2).saturating_mul(laws);
    let record = deltaloop_config::RecordSection {
        // In-process runs write no timing file; only realtime runs record the kernel.
        timing_csv: cfg.record.timing_csv && mode.is_process(),
        explain: cfg.record.explain && mode == LoopMode::Realtime,
        ..cfg.record.clone()
    };
    let dir = out.map_or_else(
        || deltaloop_report::default_run_dir(&cfg.name),
        PathBuf::from,
    );
    let asked = format!(
        "a run of {:.0} s (scenario.hold_s = {}, {laws} law{})",
        cfg.motion_duration_s() + cfg.scenario.hold_s,
        cfg.scenario.hold_s,
        if laws == 1 { "" } else { "s" }
    );
    let ask = crate::ops::soak::DiskAsk {
        asked: &asked,
        shorter: "scenario.hold_s (--hold-s)",
    };
    crate::ops::soak::refuse_if_too_big(ticks, &record, &dir, &ask)
}
