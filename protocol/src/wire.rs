//! Messages exchanged over iceoryx2 shared memory. Plain `#[repr(C)]` data with explicit type
//! names, so every binary (and any other language) agrees on the layout. Times are
//! CLOCK_MONOTONIC nanoseconds; physical fields are SI, joint space.

use iceoryx2::prelude::ZeroCopySend;

/// `StateMsg::flags`: the last message of a run (tick N + 1); the controller exits on it.
pub const STATE_FINAL: u32 = 1;

/// Plant → controller (and supervisor), once per tick.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[repr(C)]
#[type_name("deltaloop::StateMsg/v1")]
pub struct StateMsg {
    /// Control tick k (t = k·Ts).
    pub tick: u64,
    /// Bit set of `STATE_*`.
    pub flags: u32,
    pub _pad: u32,
    /// Measured joint angles q_k, rad.
    pub q: [f64; 3],
    /// Measured joint rates q̇_k, rad/s.
    pub qd: [f64; 3],
    /// Torque the drives applied over [t_{k−1}, t_k) (τᵃ_k), N m.
    pub tau_applied: [f64; 3],
    /// Ground truth for evaluation (noise-free) joint angles, rad.
    pub q_true: [f64; 3],
    /// Ground truth joint rates, rad/s.
    pub qd_true: [f64; 3],
    /// Absolute deadline of this tick, ns (lockstep: the wake time).
    pub t_deadline_ns: u64,
    /// When the plant woke for this tick, ns.
    pub t_wake_ns: u64,
    /// When the plant published this message, ns.
    pub t_publish_ns: u64,
}

/// Controller → plant (and supervisor): the answer to one state.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[repr(C)]
#[type_name("deltaloop::TorqueMsg/v1")]
pub struct TorqueMsg {
    /// The tick of the state this answers.
    pub tick: u64,
    /// States the controller skipped to reach this one (it always answers the newest).
    pub skipped: u64,
    /// Commanded torque τ_k (unclamped), N m.
    pub tau: [f64; 3],
    /// Sliding variable s_k, rad/s.
    pub s: [f64; 3],
    /// TDE N̂_k, rad/s².
    pub n_hat: [f64; 3],
    /// Robust term u_k, rad/s².
    pub u: [f64; 3],
    /// When the controller took the state, ns.
    pub t_state_rx_ns: u64,
    /// When the controller published this message, ns.
    pub t_publish_ns: u64,
}

/// `TelemetryMsg::flags` bits.
pub const TEL_CLAMPED: u32 = 1;
/// The plant held the previous torque over this interval (no valid command in time).
pub const TEL_HELD: u32 = 2;
/// The torque for this tick did not arrive within the budget (realtime).
pub const TEL_MISSED: u32 = 4;
/// The command was rejected (non-finite, or over the limit with the `reject` policy).
pub const TEL_REJECTED: u32 = 8;
/// A safe-stop tick after a fault: the drives brake, no controller.
pub const TEL_SAFE_STOP: u32 = 16;

/// Plant → supervisor after each tick: what happened to the command, and the timing.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[repr(C)]
#[type_name("deltaloop::TelemetryMsg/v1")]
pub struct TelemetryMsg {
    pub tick: u64,
    /// Bit set of `TEL_*`.
    pub flags: u32,
    pub _pad: u32,
    /// The tick's deadline, wake, state publish and torque receive times, ns (rx 0 if missed).
    pub t_deadline_ns: u64,
    pub t_wake_ns: u64,
    pub t_state_pub_ns: u64,
    pub t_torque_rx_ns: u64,
    /// Late replies dropped so far: sent after their tick's budget, or for an earlier tick.
    pub late_dropped: u64,
    /// Deadline misses so far.
    pub misses: u64,
}

/// A loop message stamped with the tick it belongs to (the supervisor files them by it).
pub trait Ticked {
    fn tick(&self) -> u64;
}

macro_rules! ticked {
    ($($t:ty),*) => {$(impl Ticked for $t {
        fn tick(&self) -> u64 {
            self.tick
        }
    })*};
}
ticked!(StateMsg, TorqueMsg, TelemetryMsg);

/// `ControlMsg::kind`.
pub mod control {
    /// A child has created its ports and waits for `START`.
    pub const READY: u32 = 1;
    /// Supervisor → children: begin at `t0_ns` (plant) with `ticks` and `q0`.
    pub const START: u32 = 2;
    /// Supervisor → children: stop now (interrupt).
    pub const STOP: u32 = 3;
    /// A child failed: `tick` and `text` say where and why.
    pub const FAULT: u32 = 4;
    /// The controller holds the reference (mapped and touched) and can answer tick 0.
    pub const ARMED: u32 = 6;
    /// The plant's model failed at `tick` (left the workspace, non-finite state): the run
    /// diverged, as the study's divergence rule counts it; `text` says how.
    pub const DIVERGED: u32 = 7;
    /// Senders.
    pub const PLANT: u32 = 1;
    pub const CONTROLLER: u32 = 2;
    pub const SUPERVISOR: u32 = 3;
}

/// Run control: handshake, start, stop, faults.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[repr(C)]
#[type_name("deltaloop::ControlMsg/v1")]
pub struct ControlMsg {
    pub kind: u32,
    pub from: u32,
    pub tick: u64,
    /// START: N, the last tick that gets a command (the plant then publishes tick N + 1 as final).
    pub ticks: u64,
    /// START: initial joint angles q_d(0), rad.
    pub q0: [f64; 3],
    /// START: the monotonic time of tick 0's deadline, ns.
    pub t0_ns: u64,
    /// FAULT: UTF-8 text, NUL-padded.
    pub text: [u8; 160],
}

impl ControlMsg {
    /// A message of `kind` from `from` with everything else zero.
    pub fn new(kind: u32, from: u32) -> Self {
        Self {
            kind,
            from,
            tick: 0,
            ticks: 0,
            q0: [0.0; 3],
            t0_ns: 0,
            text: [0; 160],
        }
    }

    /// A FAULT message at `tick` with `text` (truncated at a character boundary).
    pub fn fault(from: u32, tick: u64, text: &str) -> Self {
        Self::with_text(control::FAULT, from, tick, text)
    }

    /// A message of `kind` at `tick` carrying `text` (truncated at a character boundary).
    pub fn with_text(kind: u32, from: u32, tick: u64, text: &str) -> Self {
        let mut m = Self::new(kind, from);
        m.tick = tick;
        let mut end = text.len().min(m.text.len());
        while !text.is_char_boundary(end) {
            end -= 1;
        }
        m.text[..end].copy_from_slice(&text.as_bytes()[..end]);
        m
    }

    /// The text field as a string.
    pub fn text(&self) -> String {
        let end = self
            .text
            .iter()
            .position(|&b| b == 0)
            .unwrap_or(self.text.len());
        String::from_utf8_lossy(&self.text[..end]).into_owned()
    }
}

/// One tick of the joint reference (supervisor → controller, all ticks in one slice sample).
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[repr(C)]
#[type_name("deltaloop::RefSample/v1")]
pub struct RefSample {
    /// q_d,k, rad.
    pub q: [f64; 3],
    /// q̇_d,k, rad/s.
    pub qd: [f64; 3],
    /// q̈_d,k, rad/s².
    pub qdd: [f64; 3],
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fault_text_round_trips_and_truncates_on_char_boundary() {
        let m = ControlMsg::fault(control::PLANT, 7, "left the workspace");
        assert_eq!(m.text(), "left the workspace");
        assert_eq!(m.tick, 7);
        let long = "é".repeat(200);
        let t = ControlMsg::fault(control::PLANT, 0, &long).text();
        assert!(t.len() <= 160 && t.chars().all(|c| c == 'é'));
    }
}
