//! `deltaloop paper`: S1–S3 × both presets × four laws, tables, figures and report.md.

use super::{Context, OutArgs};
use crate::ops::paper;
use anyhow::Result;
use deltaloop_config::LoopMode;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Loop transport.
    #[arg(long, value_parser = LoopMode::parse, default_value = "inproc")]
    mode: LoopMode,
    /// Skip the round-off twins (each case's laws run once more with q(0) one ulp away).
    #[arg(long)]
    no_sensitivity: bool,
    /// Sensor-noise seeds of the robustness table (0: no table).
    #[arg(long, default_value_t = paper::robust::SEEDS, value_parser = clap::value_parser!(u32).range(0..=1000))]
    seeds: u32,
    /// Realtime runs per scenario of the robustness table (0: none).
    #[arg(long, default_value_t = paper::robust::REALTIME_RUNS, value_parser = clap::value_parser!(u32).range(0..=100))]
    realtime_runs: u32,
    #[command(flatten)]
    out: OutArgs,
}

pub fn exec(a: Args, cx: &Context) -> Result<()> {
    let out = a
        .out
        .out
        .unwrap_or_else(|| deltaloop_report::default_run_dir("paper"));
    let opts = paper::Options {
        sensitivity: !a.no_sensitivity,
        seeds: a.seeds,
        realtime_runs: a.realtime_runs,
    };
    let s = paper::run(a.mode, opts, &out, a.out.force, &cx.command_line, cx.tty)?;
    print!("{}", paper::terminal(&s, &out));
    Ok(())
}
