//! The direct path as a transport of the loop ([`deltaloop_transport::exchange`]): the plant's and
//! the controller's ends over the link's socket a bridge handed on ([`crate::direct`]), beside
//! their iceoryx2 ports, which keep the record's copies, the final state (the bridge passes it on
//! over its control connection) and the wake-ups a bridge sends (a CONTROLLER_ERROR, a STOP).

use crate::direct::{self, ControllerEnd, PlantEnd};
use crate::udp::{self, Udp};
use deltaloop_config::LoopMode;
use deltaloop_transport::exchange::{
    ControllerTransport, IpcController, IpcPlant, PlantTransport, Transport,
};
use deltaloop_transport::handoff;
use deltaloop_transport::ipc::{IpcContext, IpcError, Wake};
use deltaloop_transport::wire::{self, StateMsg, TorqueMsg};

/// An error of the direct path, with its causes on one line.
#[derive(Debug)]
pub struct LinkError(anyhow::Error);

impl std::fmt::Display for LinkError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:#}", self.0)
    }
}

impl std::error::Error for LinkError {}

impl From<anyhow::Error> for LinkError {
    fn from(e: anyhow::Error) -> Self {
        Self(e)
    }
}

impl From<IpcError> for LinkError {
    fn from(e: IpcError) -> Self {
        Self(e.into())
    }
}

/// Blocks until the link's socket `sock` is readable or `listener` has an event, `slice_ns` at
/// most; whether the event came.
fn socket_or_event(sock: &Udp, listener: &Wake, slice_ns: u64) -> Result<bool, LinkError> {
    let mut fds = [direct::readable(sock), udp::event(listener)];
    udp::wait(&mut fds, slice_ns)?;
    Ok(fds[1].revents != 0)
}

/// The link's socket, taken from the bridge over `handoff` (which hears the link's counts at the
/// end).
pub struct Direct<'h> {
    udp: Udp,
    handoff: &'h handoff::End,
}

impl<'h> Direct<'h> {
    pub fn new(udp: Udp, handoff: &'h handoff::End) -> Self {
        Self { udp, handoff }
    }
}

impl<'h> Transport for Direct<'h> {
    type Plant = DirectPlant<'h>;
    type Controller = DirectController<'h>;

    fn plant(self, ipc: IpcPlant, mode: LoopMode) -> DirectPlant<'h> {
        DirectPlant {
            end: PlantEnd::new(self.udp, mode == LoopMode::Lockstep),
            ipc,
            handoff: self.handoff,
        }
    }

    /// The states' stamps move onto this host's clock on the direct path whichever side the
    /// plant is on: the record here needs them with the plant across, and the controller's
    /// schedule (sleep to just before each deadline) needs them with the controller across,
    /// where the plant's clock is another host's.
    fn controller(self, ipc: IpcController) -> DirectController<'h> {
        DirectController {
            end: ControllerEnd::new(self.udp, true),
            ipc,
            handoff: self.handoff,
        }
    }
}

/// The plant's end: states out on the link's socket, replies in from it, already stamped with
/// their arrival here.
pub struct DirectPlant<'h> {
    end: PlantEnd,
    ipc: IpcPlant,
    handoff: &'h handoff::End,
}

impl PlantTransport for DirectPlant<'_> {
    type Error = LinkError;

    fn connect(&self) -> Result<(), LinkError> {
        Ok(self.ipc.connect()?)
    }

    /// The state goes to the link's socket, and the copy on iceoryx2 is the record's: only the
    /// final state wakes the bridge, which passes it on over its control connection.
    fn send_state(&mut self, msg: StateMsg, _ctrl_poll_until_ns: u64) -> Result<(), LinkError> {
        let last = msg.flags & wire::STATE_FINAL != 0;
        if !last {
            self.end.send_state(&msg)?;
        }
        self.ipc.state.send_copy(msg).ipc("publish state")?;
        if last {
            self.ipc.state_ready.notify().ipc("notify state")?;
        }
        Ok(())
    }

    /// Every reply in hand goes to `take`; the record's copies on iceoryx2 are not for the loop.
    fn take_replies(&mut self, mut take: impl FnMut(TorqueMsg) -> bool) -> Result<(), LinkError> {
        self.end.poll(|m| {
            take(m);
        })?;
        Ok(())
    }

    /// Drains a wake-up event only if the last wait saw one (a system call saved on every other
    /// tick; a pending one makes the next wait return at once).
    fn settle(&mut self, woke: bool) -> Result<bool, LinkError> {
        if woke {
            self.ipc
                .torque_ready
                .try_wait()
                .ipc("drain torque events")?;
        }
        Ok(true)
    }

    /// Blocks on the socket and the wake-up event together (the bridge wakes the plant for a
    /// CONTROLLER_ERROR), no longer than until the next held datagram or resend is due.
    fn block(&mut self, now_ns: u64, until_ns: u64) -> Result<bool, LinkError> {
        let slice = (until_ns - now_ns).min(self.end.timeout_ns(now_ns));
        socket_or_event(&self.end.udp, &self.ipc.torque_ready, slice)
    }

    fn finish(&mut self) {
        direct::counts(self.handoff, &self.end.udp);
    }
}

/// The controller's end: states in from the link's socket (on iceoryx2 only the final one, which
/// the bridge passes on from its control connection, and the record's copies, not for
/// answering), replies out on it.
pub struct DirectController<'h> {
    end: ControllerEnd,
    ipc: IpcController,
    handoff: &'h handoff::End,
}

impl ControllerTransport for DirectController<'_> {
    type Error = LinkError;

    /// START's t0 came over the control connection, behind the reference chunks, and is late by
    /// as much as they took (regression: 4 ms, and the first 14 states were taken at once): the
    /// first state sets the schedule.
    const START_ON_TIME: bool = false;

    fn connect(&self) -> Result<(), LinkError> {
        Ok(self.ipc.connect()?)
    }

    fn take_state(&mut self) -> Result<Option<(StateMsg, u64)>, LinkError> {
        if let Some(newest) = self.end.poll()? {
            return Ok(Some(newest));
        }
        while let Some(s) = self.ipc.state.receive().ipc("receive state")? {
            if s.flags & wire::STATE_FINAL != 0 {
                return Ok(Some((s, 0)));
            }
        }
        Ok(None)
    }

    /// The plant is across the link: the reply goes to its socket; the copy on iceoryx2 is the
    /// record's (no one here waits for it).
    fn send_reply(&mut self, msg: TorqueMsg, _plant_poll_until_ns: u64) -> Result<(), LinkError> {
        self.end.send_reply(&msg)?;
        self.ipc.torque.send_copy(msg).ipc("publish torque")?;
        Ok(())
    }

    fn wake_plant(&self) {
        self.ipc.wake_plant();
    }

    fn sleep_until(&mut self, t_ns: u64) -> Result<(), LinkError> {
        Ok(self.end.sleep_until(t_ns)?)
    }

    /// Blocks on the socket and the wake-up event together, no longer than until the next held
    /// datagram is due; a wake-up event seen is drained only at the next block.
    fn block(&mut self, now_ns: u64, slice_ns: u64, woke: bool) -> Result<bool, LinkError> {
        if woke {
            self.ipc.state_ready.try_wait().ipc("drain state events")?;
        }
        let slice = slice_ns.min(self.end.timeout_ns(now_ns));
        socket_or_event(&self.end.udp, &self.ipc.state_ready, slice)
    }

    fn finish(&mut self) {
        direct::counts(self.handoff, &self.end.udp);
    }
}
