//! `[loop]`: the timing of the control loop and the overrun policy, their keys and their checks
//! (the per-mode layouts are in [`crate::layout`]).

use crate::error::ConfigError;
use crate::key::range;
use crate::keys::{LOOP, LoopKeys};
use crate::layout::Layout;
use serde::{Deserialize, Serialize};

deltaloop_names::text_enum! {
    "kebab-case", "overrun policy";
    /// What the realtime plant does when its own process wakes for a tick later than the bound
    /// (`[loop] overrun`, `--overrun`): the host stalled the simulator, not the robot.
    #[derive(Default)]
    pub enum Overrun {
        /// Simulated time pauses for the stall: the plant's clock epoch moves by its lateness, the
        /// backlog is not integrated, and the run's real-time factor falls below 1 (and says so).
        #[default]
        Stretch,
        /// The plant stays locked to the wall clock: it runs the missed ticks back to back, each
        /// reply acting at its (late) arrival, as a real robot would have moved meanwhile.
        CatchUp,
        /// The plant stops the loop with an overrun fault and brakes, as a realtime target does on
        /// a task overrun.
        Fault,
    }
}

/// `[loop]`: timing of the control loop and the process layout per mode.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LoopSection {
    /// Control period Ts, s.
    #[serde(default = "LoopKeys::ts_s")]
    pub ts_s: f64,

    /// Realtime: how long after publishing a state the plant waits for its torque, µs.
    #[serde(default = "LoopKeys::torque_budget_us")]
    pub torque_budget_us: u32,

    /// A peer silent this long is a fault (lockstep, and the controller's wait for states), ms.
    #[serde(default = "LoopKeys::silence_timeout_ms")]
    pub silence_timeout_ms: u32,

    /// Realtime: what the plant does when its own process wakes for a tick more than
    /// `overrun_after_us` late (the host did not run it): pause simulated time (`stretch`), run
    /// the backlog on the wall clock (`catch-up`), or end the run (`fault`). A late reply from
    /// the controller or the link never triggers it: that latency acts on the physics.
    #[serde(default = "LoopKeys::overrun")]
    pub overrun: Overrun,

    /// Realtime: the plant's wake lateness beyond which `overrun` acts, µs (1..=1000000).
    /// Default: one period Ts (a later wake would push every reply past its tick).
    #[serde(default)]
    pub overrun_after_us: Option<u32>,
    #[serde(default)]
    pub realtime: Layout,
    #[serde(default)]
    pub lockstep: Layout,
}

impl Default for LoopSection {
    fn default() -> Self {
        Self {
            ts_s: LoopKeys::ts_s(),
            torque_budget_us: LoopKeys::torque_budget_us(),
            silence_timeout_ms: LoopKeys::silence_timeout_ms(),
            overrun: LoopKeys::overrun(),
            overrun_after_us: None,
            realtime: Layout::default(),
            lockstep: Layout::default(),
        }
    }
}

impl LoopSection {
    /// `[loop]`: the period first (the budget and both layouts are bounded by it), then the
    /// torque budget, the silence timeout and the layout of each process mode.
    pub(crate) fn validate(&self) -> Result<(), ConfigError> {
        let ts = self.ts_s;
        LOOP.ts_s.check(ts)?;
        let budget = self.torque_budget_us;
        if budget == 0 || f64::from(budget) * 1e-6 >= ts {
            return Err(range(
                "loop.torque_budget_us",
                budget,
                &format!("0 < torque_budget_us < Ts = {} us", ts * 1e6),
            ));
        }
        LOOP.silence_timeout_ms
            .check_int(self.silence_timeout_ms.into())?;
        if let Some(after) = self.overrun_after_us {
            LOOP.overrun_after_us.check_int(after.into())?;
        }
        self.realtime.validate("loop.realtime", ts)?;
        self.lockstep.validate("loop.lockstep", ts)
    }
}
