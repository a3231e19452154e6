//! `deltaloop join HOST:PORT --role controller|plant`: the controller's or the plant's half of a
//! run split over two hosts (the other half is `deltaloop run … --controller-remote HOST:PORT` or
//! `--plant-remote HOST:PORT`).

use super::Context;
use super::words::Words;
use crate::ops::join::{self, Join};
use anyhow::Result;
use deltaloop_config::RemoteSide;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The supervisor's host: the HOST:PORT given to `deltaloop run --controller-remote` or
    /// `--plant-remote`.
    endpoint: String,
    /// What runs on this host: the controller (`--controller-remote` there) or the plant
    /// (`--plant-remote` there).
    #[arg(long, value_parser = Words::<RemoteSide>::new(), default_value = "controller")]
    role: RemoteSide,
    /// Run this command instead of the built-in controller (split at whitespace); it gets the
    /// usual --run-id, --config, --mode and --law.
    #[arg(long, value_name = "CMD")]
    controller_cmd: Option<String>,
    /// `--role plant`: run this command instead of the built-in plant (split at whitespace); it
    /// gets the usual --run-id, --config and --mode.
    #[arg(long, value_name = "CMD")]
    plant_cmd: Option<String>,
    /// Runs to serve, one after the other (each law of a run is one; 0: until Ctrl-C).
    #[arg(long, default_value_t = 1)]
    runs: u32,
    /// How long to keep trying to reach the supervisor's host for each run, s (0: forever).
    #[arg(long, default_value_t = 120)]
    wait_s: u64,
    /// Poll this long for the reply after passing a state on before blocking, µs
    /// (0: block at once). Worth it where the bridge has a CPU of its own.
    #[arg(long, default_value_t = 0)]
    spin_us: u32,
    /// The run's link key file (a copy of the one given to `deltaloop run --link-key`).
    #[arg(long, value_name = "FILE")]
    link_key: Option<std::path::PathBuf>,
    /// The run's one-time link key, as `deltaloop run` printed it (64 hex digits).
    #[arg(long, value_name = "HEX")]
    link_token: Option<String>,
    /// CPU of the process started here (−1: not pinned; default: the mode's default layout).
    /// This host's choice: the run's config cannot set it.
    #[arg(long, allow_hyphen_values = true, value_parser = clap::value_parser!(i32).range(-1..=1023))]
    cpu: Option<i32>,
    /// Its SCHED_FIFO priority, 1..=99 (0: SCHED_OTHER; default: the mode's default layout).
    #[arg(long, value_parser = clap::value_parser!(i32).range(0..=99))]
    priority: Option<i32>,
}

pub fn exec(a: Args, _cx: &Context) -> Result<()> {
    join::join(&Join {
        endpoint: &a.endpoint,
        role: a.role,
        controller_cmd: a.controller_cmd.as_deref(),
        plant_cmd: a.plant_cmd.as_deref(),
        runs: a.runs,
        wait_s: a.wait_s,
        spin_us: a.spin_us,
        link_key: a.link_key.as_deref(),
        link_token: a.link_token.as_deref(),
        cpu: a.cpu,
        priority: a.priority,
    })
}
