//! The loop over iceoryx2 alone (one host, or relayed by a bridge): the state and torque services
//! and their two wake-up events, as the plant's and the controller's ends of the loop.

use super::{Connector, ControllerTransport, OverTransport, PlantTransport, Transport};
use crate::ipc::{self, IpcContext, IpcError, ListenerWaitError, Node, Svc};
use crate::ports::{Ping, StateIn, StateOut, TorqueIn, TorqueOut, Wake};
use crate::rt;
use deltaloop_config::{LoopMode, RunConfig};
use deltaloop_wire::{StateMsg, TorqueMsg};
use std::time::Duration;

/// iceoryx2 alone: a [`Transport`], and the [`Connector`] of a process that uses nothing else.
#[derive(Clone, Copy, Debug, Default)]
pub struct Iceoryx;

impl Transport for Iceoryx {
    type Plant = IpcPlant;
    type Controller = IpcController;

    fn plant(self, ipc: IpcPlant, _mode: LoopMode) -> IpcPlant {
        ipc
    }

    fn controller(self, ipc: IpcController) -> IpcController {
        ipc
    }
}

impl Connector for Iceoryx {
    type Error = std::convert::Infallible;

    fn prepare(&mut self, _cfg: &RunConfig) -> Result<(), Self::Error> {
        Ok(())
    }

    fn connect<V: OverTransport>(&mut self, then: V) -> Result<V::Output, Self::Error> {
        Ok(then.run(Iceoryx))
    }
}

/// The plant's loop ports: `state` publisher, `torque` subscriber, `state-ready` notifier,
/// `torque-ready` listener ([`ipc::plant_loop`]).
pub struct IpcPlant {
    pub state: StateOut,
    pub torque: TorqueIn,
    pub state_ready: Ping,
    pub torque_ready: Wake,
}

impl IpcPlant {
    /// Opens them on `node` for run `run_id`, the torque queue [`ipc::LOOP_BUFFER`] deep.
    pub fn open(node: &Node<Svc>, run_id: &str) -> Result<Self, IpcError> {
        let (state, torque, state_ready, torque_ready) =
            ipc::plant_loop(node, run_id, ipc::LOOP_BUFFER)?;
        Ok(Self {
            state,
            torque,
            state_ready,
            torque_ready,
        })
    }
}

impl PlantTransport for IpcPlant {
    type Error = IpcError;

    fn connect(&self) -> Result<(), IpcError> {
        ipc::connect_now(&[&self.state, &self.torque, &self.state_ready])
    }

    fn send_state(&mut self, msg: StateMsg, ctrl_poll_until_ns: u64) -> Result<(), IpcError> {
        self.state.send_copy(msg).ipc("publish state")?;
        if ipc::published_needs_notify(ctrl_poll_until_ns) {
            self.state_ready.notify().ipc("notify state")?;
        }
        Ok(())
    }

    fn take_replies(&mut self, mut take: impl FnMut(TorqueMsg) -> bool) -> Result<(), IpcError> {
        while let Some(m) = self.torque.receive().ipc("receive torque")? {
            if take(m) {
                break;
            }
        }
        Ok(())
    }

    fn settle(&mut self, _woke: bool) -> Result<bool, IpcError> {
        // Drop wake-ups already seen (e.g. a late reply's), so the poll sleeps until a new one.
        self.torque_ready.try_wait().ipc("drain torque events")?;
        Ok(!self.torque.has_samples().unwrap_or(true))
    }

    fn block(&mut self, now_ns: u64, until_ns: u64) -> Result<bool, IpcError> {
        ipc::wait_event(&self.torque_ready, until_ns - now_ns)?;
        Ok(false)
    }
}

/// The controller's loop ports: `state` subscriber, `torque` publisher, `state-ready` listener,
/// `torque-ready` notifier ([`ipc::controller_loop`]).
pub struct IpcController {
    pub state: StateIn,
    pub torque: TorqueOut,
    pub state_ready: Wake,
    pub torque_ready: Ping,
}

impl IpcController {
    /// Opens them on `node` for run `run_id`, the state queue [`ipc::LOOP_BUFFER`] deep.
    pub fn open(node: &Node<Svc>, run_id: &str) -> Result<Self, IpcError> {
        let (state, torque, state_ready, torque_ready) =
            ipc::controller_loop(node, run_id, ipc::LOOP_BUFFER)?;
        Ok(Self {
            state,
            torque,
            state_ready,
            torque_ready,
        })
    }
}

impl ControllerTransport for IpcController {
    type Error = IpcError;

    const START_ON_TIME: bool = true;

    fn connect(&self) -> Result<(), IpcError> {
        ipc::connect_now(&[&self.state, &self.torque, &self.torque_ready])
    }

    fn take_state(&mut self) -> Result<Option<(StateMsg, u64)>, IpcError> {
        let mut newest: Option<StateMsg> = None;
        let mut seen = 0u64;
        while let Some(sample) = self.state.receive().ipc("receive state")? {
            newest = Some(sample);
            seen += 1;
        }
        Ok(newest.map(|s| (s, seen - 1)))
    }

    fn send_reply(&mut self, msg: TorqueMsg, plant_poll_until_ns: u64) -> Result<(), IpcError> {
        self.torque.send_copy(msg).ipc("publish torque")?;
        if ipc::published_needs_notify(plant_poll_until_ns) {
            self.torque_ready.notify().ipc("notify torque")?;
        }
        Ok(())
    }

    fn wake_plant(&self) {
        let _ = self.torque_ready.notify();
    }

    fn sleep_until(&mut self, t_ns: u64) -> Result<(), IpcError> {
        rt::sleep_until_ns(t_ns);
        Ok(())
    }

    fn block(&mut self, _now_ns: u64, slice_ns: u64, _woke: bool) -> Result<bool, IpcError> {
        // The only timeout here is the silence limit (seconds), so iceoryx2's own timed wait (a
        // blocking receive, woken directly by the notification) is precise enough and cheapest.
        // A signal (SIGTERM, or SIGCONT after a SIGSTOP) only interrupts the wait: look again.
        match self.state_ready.timed_wait(Duration::from_nanos(slice_ns)) {
            Ok(_) | Err(ListenerWaitError::InterruptSignal) => Ok(false),
            Err(e) => Err(e).ipc("wait for state"),
        }
    }
}
