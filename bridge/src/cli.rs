//! `deltaloop-bridge`'s command line: its sides and their arguments, the one place the bridge
//! uses clap. The sides' code takes these structs as parsed.

use crate::parse_endpoint;
use clap::{Parser, Subcommand};
use deltaloop_config::{Law, RemoteSide};
use deltaloop_transport::args::LoopArgs;
use std::net::SocketAddr;

#[derive(Parser, Debug)]
#[command(
    name = "deltaloop-bridge",
    about = "Carries one deltaloop run between two hosts (started by `deltaloop run --controller-remote` or `--plant-remote`, and `deltaloop join`)"
)]
pub struct Cli {
    #[command(subcommand)]
    pub side: Side,
}

impl Cli {
    /// This process's arguments; on a bad one, clap's message and exit.
    pub fn from_args() -> Self {
        Self::parse()
    }
}

#[derive(Subcommand, Debug)]
pub enum Side {
    /// The supervisor's host: stands in for the remote controller or plant (started by the
    /// supervisor).
    Near(NearArgs),
    /// The other host: stands in for the supervisor and the process with it, starts the remote
    /// one.
    Far(FarArgs),
    /// Plain UDP ping-pong, client side: the baseline round trip.
    Ping(PingArgs),
    /// Plain UDP ping-pong, echo side.
    Pong(PongArgs),
    /// The same ping-pong over Zenoh, client side (feature `zenoh`).
    #[cfg(feature = "zenoh")]
    Zping(ZPingArgs),
    /// The same ping-pong over Zenoh, echo side (feature `zenoh`).
    #[cfg(feature = "zenoh")]
    Zpong(ZPongArgs),
}

/// `deltaloop-bridge near`: the loop process's arguments; what the link is (the far role, where
/// to listen, the emulation) is the run config's `[link]`.
#[derive(clap::Args, Debug)]
pub struct NearArgs {
    #[command(flatten)]
    pub run: LoopArgs,
    /// The control law (passed on to the far controller; `--role controller` only).
    #[arg(long, value_parser = Law::parse)]
    pub law: Option<Law>,
}

/// `deltaloop-bridge far`.
#[derive(clap::Args, Debug)]
pub struct FarArgs {
    /// The near side: HOST:PORT given to `deltaloop run --controller-remote` or `--plant-remote`.
    #[arg(long, value_parser = parse_endpoint)]
    pub connect: SocketAddr,
    /// What runs here: `controller` (the plant and the supervisor are there) or `plant` (the
    /// controller and the supervisor are there).
    #[arg(long, value_parser = side, default_value = "controller")]
    pub role: RemoteSide,
    /// Run this controller command instead of the built-in `deltaloop-controller` (split at
    /// whitespace); the run's arguments are appended as for `--controller-cmd`.
    #[arg(long, value_name = "CMD")]
    pub controller_cmd: Option<String>,
    /// Run this plant command instead of the built-in `deltaloop-plant` (`--role plant`; split
    /// at whitespace); the run's arguments are appended as for `--plant-cmd`.
    #[arg(long, value_name = "CMD")]
    pub plant_cmd: Option<String>,
    /// Runs to serve, one after the other (0: until interrupted).
    #[arg(long, default_value_t = 1)]
    pub runs: u32,
    /// How long to keep trying to reach the near side for each run, s (0: forever).
    #[arg(long, default_value_t = 120)]
    pub wait_s: u64,
    /// Poll this long for the reply after passing a state on before blocking, µs (0: block at
    /// once; at most loop.torque_budget_us in realtime).
    #[arg(long, default_value_t = 0)]
    pub spin_us: u32,
    #[command(flatten)]
    pub placement: Placement,
}

/// Where and how the process runs on this host: this host's choice, never the near side's.
#[derive(clap::Args, Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Placement {
    /// CPU of the process started here (−1: not pinned; default: the mode's default layout).
    #[arg(long, allow_hyphen_values = true, value_parser = clap::value_parser!(i32).range(-1..=1023))]
    pub cpu: Option<i32>,
    /// Its SCHED_FIFO priority, 1..=99 (0: SCHED_OTHER; default: the mode's default layout).
    #[arg(long, value_parser = clap::value_parser!(i32).range(0..=99))]
    pub priority: Option<i32>,
}

/// `--role`: a remote side's word (its error lists the allowed ones).
fn side(s: &str) -> Result<RemoteSide, String> {
    RemoteSide::parse(s)
}

#[derive(clap::Args, Debug)]
pub struct PingArgs {
    /// The echo side (`deltaloop-bridge pong --listen`).
    #[arg(long, value_parser = parse_endpoint)]
    pub connect: SocketAddr,
    /// Round trips to time (after 1000 untimed ones).
    #[arg(long, default_value_t = 100_000)]
    pub count: u32,
    /// Pause between round trips, µs (300: the loop's period).
    #[arg(long, default_value_t = 300)]
    pub period_us: u64,
}

#[derive(clap::Args, Debug)]
pub struct PongArgs {
    /// HOST:PORT to answer on.
    #[arg(long, value_parser = parse_endpoint)]
    pub listen: SocketAddr,
}

#[cfg(feature = "zenoh")]
#[derive(clap::Args, Debug)]
pub struct ZPingArgs {
    /// The echo side's Zenoh endpoint, e.g. tcp/10.77.0.2:7600 or udp/10.77.0.2:7600.
    #[arg(long)]
    pub connect: String,
    /// Round trips to time (after 1000 untimed ones).
    #[arg(long, default_value_t = 100_000)]
    pub count: u32,
    /// Pause between round trips, µs.
    #[arg(long, default_value_t = 300)]
    pub period_us: u64,
}

#[cfg(feature = "zenoh")]
#[derive(clap::Args, Debug)]
pub struct ZPongArgs {
    /// The Zenoh endpoint to listen on, e.g. tcp/10.77.0.2:7600.
    #[arg(long)]
    pub listen: String,
}
