//! Running: one law's ticks stepped in-process over an arrival schedule ([`inproc`]: the
//! in-process mode and the replay of a recorded run) or run by the plant and controller
//! processes and observed ([`procs`]); the recorder every mode fills ([`lawrun`]); the reference
//! feed and the signals that stop a run. [`run_law`] runs one law in any mode; [`run::run`] a
//! config's laws into their run folder; [`join`] puts a process on another host (and is that
//! host's half); [`replay`] runs a recorded run again; [`loopback`] stands up a far host on this
//! one. Below the commands and the studies; on the study, timing and report crates.

pub mod feed;
pub mod inproc;
pub mod join;
pub mod lawrun;
pub mod link_key;
pub mod loopback;
pub mod peer_text;
pub mod pool;
pub mod procs;
pub mod replay;
pub mod run;
pub mod signals;

use anyhow::Result;
use deltaloop_config::{Law, LoopMode};
use deltaloop_study::Study;
use lawrun::{Keep, LawRun};
use procs::{OnTick, ProcessRun};
use std::path::Path;

/// One law's run: its record, and for a process mode what the pair left besides.
pub enum Ran {
    Inproc(Box<LawRun>),
    Process(Box<ProcessRun>),
}

impl Ran {
    /// The record.
    pub fn into_run(self) -> LawRun {
        match self {
            Ran::Inproc(r) => *r,
            Ran::Process(p) => p.run,
        }
    }
}

/// Runs `law` over the study in `mode`, recording what `keep` asks for. A process mode runs a
/// pair whose files (the config it reads, logs, `<law>.timing.csv`) are in `dir`, and calls
/// `on_tick` with every tick it finishes; the in-process mode uses neither.
pub fn run_law(
    study: &Study,
    law: Law,
    mode: LoopMode,
    dir: &Path,
    keep: &Keep,
    on_tick: Option<OnTick<'_>>,
) -> Result<Ran> {
    Ok(if mode.is_process() {
        Ran::Process(Box::new(procs::run_law(
            study, law, mode, dir, keep, on_tick,
        )?))
    } else {
        Ran::Inproc(Box::new(inproc::run_law(study, law, keep)?))
    })
}
