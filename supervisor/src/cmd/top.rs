//! `deltaloop top [RUN_ID]`: watch a live lockstep or realtime run.

use super::Context;
use anyhow::Result;
use std::time::Duration;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The run id (its iceoryx2 services are deltaloop/RUN_ID/...); default: the only live run.
    run_id: Option<String>,
    /// One key=value line per refresh on stdout instead of the screen (also when stdout is
    /// not a terminal); ends with the run.
    #[arg(long)]
    plain: bool,
    /// Time between refreshes, e.g. 250ms, 1s.
    #[arg(long, default_value = "250ms", value_parser = parse_refresh)]
    interval: Duration,
}

/// `top --interval`: 50 ms ..= 60 s.
fn parse_refresh(s: &str) -> Result<Duration, String> {
    let d = humantime::parse_duration(s.trim())
        .map_err(|e| format!("`{s}` is not a duration ({e}): expected e.g. 250ms or 1s"))?;
    if d < Duration::from_millis(50) || d > Duration::from_secs(60) {
        return Err(format!("`{s}` is out of range: 50ms ..= 60s"));
    }
    Ok(d)
}

pub fn exec(a: Args, _cx: &Context) -> Result<()> {
    crate::ops::top::run(crate::ops::top::Options {
        run_id: a.run_id,
        plain: a.plain,
        interval: a.interval,
    })
}
