//! `deltaloop top [RUN_ID]`: watch a live lockstep or realtime run.

use super::Context;
use anyhow::Result;
use std::net::SocketAddr;
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
    /// Also serve the run to Foxglove (its WebSocket protocol) on ADDR, a loopback address
    /// (default 127.0.0.1:8765; the protocol has no authentication). Needs a build with
    /// `--features foxglove`.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = "127.0.0.1:8765", value_parser = parse_addr)]
    foxglove: Option<SocketAddr>,
}

/// `top --foxglove ADDR`: a loopback socket address (the protocol has no authentication).
fn parse_addr(s: &str) -> Result<SocketAddr, String> {
    let addr: SocketAddr = s.trim().parse().map_err(|_| {
        format!("`{s}` is not an address: expected IP:PORT, e.g. 127.0.0.1:8765 (a run id goes before --foxglove)")
    })?;
    if !addr.ip().is_loopback() {
        return Err(format!(
            "`{s}` is not a loopback address: Foxglove's WebSocket protocol has no authentication, so top serves it on 127.0.0.1 or [::1] only (from another machine: ssh -L {p}:127.0.0.1:{p} this-host)",
            p = addr.port()
        ));
    }
    Ok(addr)
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
        foxglove: a.foxglove,
    })
}
