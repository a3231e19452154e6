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
    #[command(flatten)]
    out: OutArgs,
}

pub fn exec(a: Args, cx: &Context) -> Result<()> {
    let out = a
        .out
        .out
        .unwrap_or_else(|| crate::output::default_run_dir("paper"));
    let s = paper::run(a.mode, &out, a.out.force, &cx.command_line, cx.tty)?;
    print!("{}", paper::terminal(&s, &out));
    Ok(())
}
