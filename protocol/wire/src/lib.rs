//! The messages of a run, as the loop processes exchange them (over iceoryx2 shared memory on one
//! host, in sealed datagrams across two). Plain `#[repr(C)]` data with explicit type names, so
//! every binary (and any other language) agrees on the layout; with the feature `iceoryx2` each
//! also derives iceoryx2's `ZeroCopySend`. Times are
//! CLOCK_MONOTONIC nanoseconds; physical fields are SI, joint space.

#[cfg(feature = "iceoryx2")]
use iceoryx2::prelude::ZeroCopySend;

/// The version of the run's wire as a whole (the services, who publishes where, what each kind
/// means), carried by every publish-subscribe service as the attribute [`WIRE_ATTRIBUTE`] so a
/// peer can check it when it opens the run's services. Bumped when a peer of the previous version
/// could no longer take part: 3 is the first with one control service per sender.
pub const WIRE_VERSION: u32 = 3;
/// The service attribute that holds [`WIRE_VERSION`] (its value in decimal).
pub const WIRE_ATTRIBUTE: &str = "deltaloop-wire";

/// `StateMsg::flags`: the last message of a run (tick N + 1); the controller exits on it.
pub const STATE_FINAL: u32 = 1;

/// Plant → controller (and supervisor), once per tick.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
#[cfg_attr(
    feature = "iceoryx2",
    derive(ZeroCopySend),
    type_name("deltaloop::StateMsg/v2")
)]
#[repr(C)]
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
    /// The plant polls the torque queue until at least this time (ns, CLOCK_MONOTONIC) before it
    /// blocks on `torque-ready`; a reply published and visible before it, less
    /// [`POLL_MARGIN_NS`], needs no wake-up notification. 0: always notify.
    pub t_poll_until_ns: u64,
}

/// Controller → plant (and supervisor): the answer to one state.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
#[cfg_attr(
    feature = "iceoryx2",
    derive(ZeroCopySend),
    type_name("deltaloop::TorqueMsg/v2")
)]
#[repr(C)]
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
    /// The controller polls the state queue until at least this time (ns, CLOCK_MONOTONIC)
    /// before it blocks on `state-ready`; a state published and visible before it, less
    /// [`POLL_MARGIN_NS`], needs no wake-up notification. 0: always notify.
    pub t_poll_until_ns: u64,
}

/// How far before a peer's `t_poll_until_ns` a message must be published, and visible, for its
/// notification to be skipped: covers the clock reads on either side (ns).
pub const POLL_MARGIN_NS: u64 = 5_000;

/// Whether a message whose publication finished at `published_ns` (clock read after the send
/// and a full fence) still needs the peer woken, given the peer's declared `poll_until_ns`.
#[inline]
pub fn needs_notify(published_ns: u64, poll_until_ns: u64) -> bool {
    published_ns.saturating_add(POLL_MARGIN_NS) >= poll_until_ns
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
/// The applied reply's `t_publish_ns` lay outside [state published, reply received] on the
/// plant's clock (a stamp no honest controller can write): the plant used its own receive time.
pub const TEL_STAMP_REPLACED: u32 = 32;

/// Plant → supervisor after each tick: what happened to the command, and the timing.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
#[cfg_attr(
    feature = "iceoryx2",
    derive(ZeroCopySend),
    type_name("deltaloop::TelemetryMsg/v2")
)]
#[repr(C)]
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
    /// When this tick's command reached the drives, A_k − t_k, ns: the transport delay plus, in
    /// realtime with `apply_torque = "arrival"`, the reply's measured latency (its publish time
    /// minus the tick's deadline). 0 when no command was applied (`TEL_MISSED`).
    pub arrival_ns: u64,
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

/// What a [`ControlMsg`] says (`ControlMsg::kind` on the wire).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u32)]
pub enum ControlKind {
    /// A child has created its ports and waits for `Start`.
    Ready = 1,
    /// Supervisor → children: begin at `t0_ns` (plant) with `ticks` and `q0`.
    Start = 2,
    /// Supervisor → children: stop now (interrupt).
    Stop = 3,
    /// The plant stopped the loop at `tick` and brakes (e.g. the controller went silent); `text`
    /// says why.
    Fault = 4,
    /// The controller has tick 0's reference row (its reference ring allocated and touched) and
    /// can answer tick 0.
    Armed = 6,
    /// The plant's model failed at `tick` (left the workspace, non-finite state): the run
    /// diverged, as the study's divergence rule counts it; `text` says how.
    Diverged = 7,
    /// The plant stopped the loop at `tick` on request (STOP from the supervisor, or SIGTERM) and
    /// brakes; `text` says which.
    Stopped = 8,
    /// The plant's own process woke for `tick` later than its overrun bound with
    /// `overrun = "fault"`: it stopped the loop and brakes; `text` says how late.
    Overrun = 9,
    /// The plant's own physics reported an error at `tick` (a foreign plant's `truth` or
    /// `measure` failed): it stopped the loop there and brakes; `text` quotes the error.
    PlantError = 10,
    /// The controller's step reported an error answering `tick` (it returned one instead of a
    /// torque): the controller sends no reply to it and exits with its fault code; `text` quotes
    /// the error. The plant reads it on `control-controller` and stops the loop at once (FAULT
    /// naming it) instead of holding through the silence window.
    ControllerError = 11,
    /// The controller's replies to ticks `tick..=ticks` may have been lost on the way to the
    /// plant's host and could not be recovered (the near bridge of a remote controller says it,
    /// as the controller): the supervisor records those ticks' `reply` as unknown, rather than
    /// as unanswered, and counts them. `text` says why.
    RepliesLost = 12,
    /// Once, at the loop's end: the controller's own transport refused `ticks` replies in all
    /// (the robot of `--controller ros2`: a ROS 2 node's commands with other joint names or
    /// lengths, non-finite, stale, from a second publisher, undecodable); `text` counts each
    /// cause. The supervisor counts them (`refused_replies`); a controller that refused nothing
    /// need not say it. The plant ignores it.
    RepliesRefused = 13,
}

impl ControlKind {
    /// Whether a plant may send this kind (what the supervisor and a bridge believe from one).
    pub fn said_by_plant(self) -> bool {
        use ControlKind::*;
        matches!(
            self,
            Ready | Fault | Diverged | Stopped | Overrun | PlantError
        )
    }

    /// Whether a controller may send this kind.
    pub fn said_by_controller(self) -> bool {
        matches!(
            self,
            ControlKind::Ready
                | ControlKind::Armed
                | ControlKind::ControllerError
                | ControlKind::RepliesLost
                | ControlKind::RepliesRefused
        )
    }

    /// The kind of a wire value, None for a value this version does not know.
    pub fn from_wire(v: u32) -> Option<Self> {
        [
            Self::Ready,
            Self::Start,
            Self::Stop,
            Self::Fault,
            Self::Armed,
            Self::Diverged,
            Self::Stopped,
            Self::Overrun,
            Self::PlantError,
            Self::ControllerError,
            Self::RepliesLost,
            Self::RepliesRefused,
        ]
        .into_iter()
        .find(|k| *k as u32 == v)
    }
}

/// Who sent a [`ControlMsg`] (`ControlMsg::from` on the wire).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u32)]
pub enum Sender {
    Plant = 1,
    Controller = 2,
    Supervisor = 3,
}

impl Sender {
    /// The sender of a wire value, None for a value this version does not know.
    pub fn from_wire(v: u32) -> Option<Self> {
        [Self::Plant, Self::Controller, Self::Supervisor]
            .into_iter()
            .find(|s| *s as u32 == v)
    }
}

/// Run control: handshake, start, stop, faults.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(
    feature = "iceoryx2",
    derive(ZeroCopySend),
    type_name("deltaloop::ControlMsg/v1")
)]
#[repr(C)]
pub struct ControlMsg {
    /// A [`ControlKind`] value.
    pub kind: u32,
    /// A [`Sender`] value.
    pub from: u32,
    pub tick: u64,
    /// START: N, the last tick that gets a command (the plant then publishes tick N + 1 as final);
    /// REPLIES_LOST: the last tick of the range; REPLIES_REFUSED: how many replies.
    pub ticks: u64,
    /// START: initial joint angles q_d(0), rad.
    pub q0: [f64; 3],
    /// START: the monotonic time of tick 0's deadline, ns.
    pub t0_ns: u64,
    /// FAULT, DIVERGED, STOPPED, OVERRUN, PLANT_ERROR, CONTROLLER_ERROR, REPLIES_LOST,
    /// REPLIES_REFUSED: UTF-8 text, NUL-padded;
    /// read it with [`ControlMsg::text`].
    pub text: [u8; 160],
}

impl ControlMsg {
    /// A message of `kind` from `from` with everything else zero.
    pub fn new(kind: ControlKind, from: Sender) -> Self {
        Self {
            kind: kind as u32,
            from: from as u32,
            tick: 0,
            ticks: 0,
            q0: [0.0; 3],
            t0_ns: 0,
            text: [0; 160],
        }
    }

    /// What the message says (None: a kind this version does not know).
    pub fn kind(&self) -> Option<ControlKind> {
        ControlKind::from_wire(self.kind)
    }

    /// Who sent it (None: a sender this version does not know).
    pub fn sender(&self) -> Option<Sender> {
        Sender::from_wire(self.from)
    }

    /// A message of `kind` at `tick` carrying `text` (truncated at a character boundary).
    pub fn with_text(kind: ControlKind, from: Sender, tick: u64, text: &str) -> Self {
        let mut m = Self::new(kind, from);
        m.tick = tick;
        let mut end = text.len().min(m.text.len());
        while !text.is_char_boundary(end) {
            end -= 1;
        }
        m.text[..end].copy_from_slice(&text.as_bytes()[..end]);
        m
    }

    /// The text field as one line of data, safe to store and show: decoded lossily, control
    /// characters escaped ([`escape_peer_text`]). The text comes from another process, which may
    /// put escape codes or newlines in it.
    pub fn text(&self) -> String {
        let end = self
            .text
            .iter()
            .position(|&b| b == 0)
            .unwrap_or(self.text.len());
        escape_peer_text(&String::from_utf8_lossy(&self.text[..end]))
    }
}

/// Text from another process as one line of inert data: every control character (newline,
/// escape, DEL, C1) and every invisible format character that reorders or hides text (bidi
/// overrides, zero-width marks) written as its Rust escape (`\n`, `\u{1b}`); all else kept.
pub fn escape_peer_text(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        let hidden = matches!(c, '\u{200b}'..='\u{200f}' | '\u{202a}'..='\u{202e}' | '\u{2066}'..='\u{2069}' | '\u{feff}');
        if c.is_control() || hidden {
            out.extend(c.escape_default());
        } else {
            out.push(c);
        }
    }
    out
}

/// One tick of the joint reference, joint frame (supervisor → controller, up to
/// `REF_CHUNK` rows per slice sample; the chunking rule is in
/// `deltaloop_transport::ipc`). The row names its own tick, so the controller files it without knowing which
/// chunk it came in. Layout: 80 bytes, `tick` at 0, `q` at 8, `qd` at 32, `qdd` at 56.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
#[cfg_attr(
    feature = "iceoryx2",
    derive(ZeroCopySend),
    type_name("deltaloop::RefSample/v2")
)]
#[repr(C)]
pub struct RefSample {
    /// The control tick k this row is for (t = k·Ts).
    pub tick: u64,
    /// q_d,k, rad.
    pub q: [f64; 3],
    /// q̇_d,k, rad/s.
    pub qd: [f64; 3],
    /// q̈_d,k, rad/s².
    pub qdd: [f64; 3],
}
