//! How plant and controller are connected: the loop mode.

use crate::layout::ResolvedLayout;
use crate::schema::RunConfig;

deltaloop_names::text_enum! {
    "kebab-case", "mode";
    /// How plant and controller are connected: one enum for the CLI, the sweep and the processes.
    #[derive(Default)]
    pub enum LoopMode {
        /// Plant and controller stepped together in one process. Fastest; for sweeps and tests.
        #[default]
        Inproc,
        /// Real processes over iceoryx2; the plant waits for every torque (bit-identical to inproc).
        Lockstep,
        /// Real processes over iceoryx2 on an absolute clock; late torques are missed.
        Realtime,
    }
}

impl LoopMode {
    /// Parses the mode of a loop process: `lockstep` or `realtime` (a process is never inproc).
    pub fn parse_process(s: &str) -> Result<LoopMode, String> {
        match LoopMode::parse(s)? {
            LoopMode::Inproc => {
                let allowed: Vec<&str> = LoopMode::ALL
                    .iter()
                    .filter(|m| m.is_process())
                    .map(|m| m.name())
                    .collect();
                Err(format!(
                    "mode `{s}` has no processes (allowed: {})",
                    allowed.join(", ")
                ))
            }
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
