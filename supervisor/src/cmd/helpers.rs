//! The hidden helper commands: the controller side of `bench loop`'s iceoryx2 and Unix-socket
//! baselines, run as a second process.

use super::Context;
use crate::ops::bench_loop::{self, Handoff};
use anyhow::Result;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct IoxArgs {
    #[arg(long)]
    run_id: String,
    #[arg(long)]
    config: PathBuf,
    #[arg(long)]
    cpu: Option<usize>,
    /// Block on the wake-up event instead of polling.
    #[arg(long)]
    blocking: bool,
}

#[derive(clap::Args, Debug)]
pub struct UdsArgs {
    #[arg(long)]
    socket: PathBuf,
    #[arg(long)]
    config: PathBuf,
    #[arg(long)]
    cpu: Option<usize>,
}

pub fn exec_iox(a: IoxArgs, _cx: &Context) -> Result<()> {
    let handoff = if a.blocking {
        Handoff::Blocking
    } else {
        Handoff::Polling
    };
    bench_loop::iox_controller(&a.run_id, &a.config, a.cpu, handoff)
}

pub fn exec_uds(a: UdsArgs, _cx: &Context) -> Result<()> {
    bench_loop::uds_controller(&a.socket, &a.config, a.cpu)
}
