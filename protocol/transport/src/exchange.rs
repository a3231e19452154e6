//! The loop's own exchange, behind one interface: what the plant and the controller processes
//! send and take every tick (states, replies, the wake-ups between them, the link's counts at the
//! end), whatever carries it. The supervisor's services (control, telemetry, the reference) are
//! not part of it: they stay iceoryx2 ports.
//!
//! - [`PlantTransport`], [`ControllerTransport`]: one end of the loop each, called per tick. The
//!   processes are generic over them (static dispatch: no `dyn`, nothing allocated per tick).
//! - [`Transport`]: a way of carrying the loop, and how each end is made over it from the end's
//!   iceoryx2 ports, which every transport keeps (the record's copies, the final state,
//!   wake-ups). iceoryx2 alone is [`Iceoryx`] ([`iceoryx`]); the direct path across two hosts is
//!   the link's (`deltaloop-link`).
//! - [`Connector`]: how a process learns which transport to use, supplied by its binary: asked
//!   at set-up (before READY), answered at START, where it runs the loop ([`OverTransport`])
//!   over the transport picked.

pub mod iceoryx;

pub use iceoryx::{Iceoryx, IpcController, IpcPlant};

use deltaloop_config::{LoopMode, RunConfig};
use deltaloop_wire::{StateMsg, TorqueMsg};

/// The plant's end of the loop: states out, replies in.
pub trait PlantTransport {
    type Error: std::error::Error + Send + Sync + 'static;

    /// Connects its ports now (iceoryx2 connects lazily: set-up work the first tick should not
    /// do).
    fn connect(&self) -> Result<(), Self::Error>;

    /// Sends state `msg` (the final one too), waking the controller unless it declared it polls
    /// until `ctrl_poll_until_ns` (its last reply's `t_poll_until_ns`, CLOCK_MONOTONIC ns; 0:
    /// always wake it).
    fn send_state(&mut self, msg: StateMsg, ctrl_poll_until_ns: u64) -> Result<(), Self::Error>;

    /// Hands `take` each reply that came in, oldest first, until `take` returns true; the replies
    /// after that wait for the next call, or, where the transport has them in hand already, go
    /// to `take` too.
    fn take_replies(&mut self, take: impl FnMut(TorqueMsg) -> bool) -> Result<(), Self::Error>;

    /// Before blocking: drains the wake-ups (`woke`: the last [`block`](Self::block) of this
    /// wait saw one). False if a reply is already waiting: look again rather than block.
    fn settle(&mut self, woke: bool) -> Result<bool, Self::Error>;

    /// Blocks until a reply or a wake-up may be there, at most until `until_ns` (`now_ns`: the
    /// clock's last reading, CLOCK_MONOTONIC ns). Whether it saw a wake-up event.
    fn block(&mut self, now_ns: u64, until_ns: u64) -> Result<bool, Self::Error>;

    /// At the loop's end: what it counted (refused, lost), to whoever reports it.
    fn finish(&mut self) {}
}

/// The controller's end of the loop: states in, replies out.
pub trait ControllerTransport {
    type Error: std::error::Error + Send + Sync + 'static;

    /// Whether START's t0 is on this transport's clock on time, so the controller may sleep to
    /// its schedule before the first state (false: only once a state has set the schedule).
    const START_ON_TIME: bool;

    /// Connects its ports now (as [`PlantTransport::connect`]).
    fn connect(&self) -> Result<(), Self::Error>;

    /// The newest state that came in and how many older ones came with it; None if none.
    fn take_state(&mut self) -> Result<Option<(StateMsg, u64)>, Self::Error>;

    /// Sends reply `msg`, waking the plant unless its state declared it polls until
    /// `plant_poll_until_ns` (CLOCK_MONOTONIC ns).
    fn send_reply(&mut self, msg: TorqueMsg, plant_poll_until_ns: u64) -> Result<(), Self::Error>;

    /// Wakes the plant, best effort (after a control message it must see at once).
    fn wake_plant(&self);

    /// Sleeps until `t_ns` (the controller's schedule, CLOCK_MONOTONIC ns).
    fn sleep_until(&mut self, t_ns: u64) -> Result<(), Self::Error>;

    /// Blocks until a state or a wake-up may be there, at most `slice_ns` from `now_ns`; `woke`:
    /// the last block of this wait saw a wake-up (drained first). Whether this one saw one.
    fn block(&mut self, now_ns: u64, slice_ns: u64, woke: bool) -> Result<bool, Self::Error>;

    /// At the loop's end: what it counted (refused, lost), to whoever reports it.
    fn finish(&mut self) {}
}

/// A way of carrying the loop: each end made over it from that end's iceoryx2 ports.
pub trait Transport {
    type Plant: PlantTransport;
    type Controller: ControllerTransport;

    /// The plant's end (`mode`: lockstep waits for every reply, and may ask again).
    fn plant(self, ipc: IpcPlant, mode: LoopMode) -> Self::Plant;

    /// The controller's end.
    fn controller(self, ipc: IpcController) -> Self::Controller;
}

/// What runs over the transport picked at START: the loop, compiled for each transport.
pub trait OverTransport {
    type Output;

    fn run<T: Transport>(self, transport: T) -> Self::Output;
}

/// How a loop process gets its transport; its binary supplies it.
pub trait Connector {
    type Error: std::error::Error + Send + Sync + 'static;

    /// At set-up, before READY (across hosts: ask the bridge beside the process for the link).
    fn prepare(&mut self, cfg: &RunConfig) -> Result<(), Self::Error>;

    /// At START: runs `then` over the transport to use.
    fn connect<V: OverTransport>(&mut self, then: V) -> Result<V::Output, Self::Error>;
}
