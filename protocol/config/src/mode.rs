//! How plant and controller are connected: the loop mode.

use crate::layout::ResolvedLayout;
use crate::schema::RunConfig;
use serde::{Deserialize, Serialize};
use std::fmt;

/// How plant and controller are connected: one enum for the CLI, the sweep and the processes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum LoopMode {
    /// Plant and controller stepped together in one process. Fastest; for sweeps and tests.
    #[default]
    Inproc,

    /// Real processes over iceoryx2; the plant waits for every torque (bit-identical to inproc).
    Lockstep,

    /// Real processes over iceoryx2 on an absolute clock; late torques are missed.
    Realtime,
}

impl LoopMode {
    /// Every mode, in documentation order.
    pub const ALL: [LoopMode; 3] = [LoopMode::Inproc, LoopMode::Lockstep, LoopMode::Realtime];

    /// The config/command-line name (`inproc`, `lockstep`, `realtime`).
    pub fn name(self) -> &'static str {
        match self {
            LoopMode::Inproc => "inproc",
            LoopMode::Lockstep => "lockstep",
            LoopMode::Realtime => "realtime",
        }
    }

    /// Parses a config/command-line name.
    pub fn parse(s: &str) -> Result<LoopMode, String> {
        LoopMode::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| format!("unknown mode `{s}` (allowed: inproc, lockstep, realtime)"))
    }

    /// Parses the mode of a loop process: `lockstep` or `realtime` (a process is never inproc).
    pub fn parse_process(s: &str) -> Result<LoopMode, String> {
        match LoopMode::parse(s)? {
            LoopMode::Inproc => Err(format!(
                "mode `{s}` has no processes (allowed: lockstep, realtime)"
            )),
            m => Ok(m),
        }
    }

    /// Whether plant and controller run as separate processes.
    pub fn is_process(self) -> bool {
        self != LoopMode::Inproc
    }

    /// The scheduling layout of this mode's processes, resolved (None for inproc).
    pub fn layout(self, cfg: &RunConfig) -> Option<ResolvedLayout> {
        match self {
            LoopMode::Inproc => None,
            LoopMode::Lockstep => Some(cfg.loop_.lockstep.resolve()),
            LoopMode::Realtime => Some(cfg.loop_.realtime.resolve()),
        }
    }
}

impl fmt::Display for LoopMode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.pad(self.name())
    }
}
