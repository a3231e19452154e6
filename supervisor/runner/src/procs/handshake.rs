//! The supervisor's ports (the children's control services, the observers of the loop streams)
//! and the handshake: READY from both, the first reference chunks, ARMED, START; or STOP when a
//! signal comes first.

use super::spawn::{Pair, in_process_tree};
use super::{ProcessRun, role};
use crate::feed::ReferenceFeed;
use crate::lawrun::{self, Keep};
use anyhow::{Result, bail};
use deltaloop_config::Law;
use deltaloop_study::Study;
use deltaloop_timing::Timing;
use deltaloop_transport::ipc::{self, IpcContext, OBSERVER_BUFFER, Svc};
use deltaloop_transport::rt;
use deltaloop_transport::wire::{
    ControlKind, ControlMsg, Sender, StateMsg, TelemetryMsg, TorqueMsg,
};
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::service::header::payload_header::PayloadHeader;
use std::cell::Cell;
use std::time::Duration;

/// What one child says, on its own control service, believed only from that child: the first
/// publisher seen there must belong to the child's process (or a descendant of it), and after it
/// only that publisher is heard. The service has one publisher slot, so once the child holds it
/// no other process can publish there; if another process took it first, the run is refused.
struct ControlIn {
    sub: Subscriber<Svc, ControlMsg, ()>,
    who: Sender,
    /// The child's pid, once it is spawned.
    root: Cell<Option<u32>>,
    /// The child's publisher, once its first message proved it.
    publisher: Cell<Option<iceoryx2::identifiers::UniquePublisherId>>,
    /// The first process not the child's that published here (pid; 0 if its pid is unknown).
    intruder: Cell<Option<u32>>,
}

impl ControlIn {
    fn open(node: &Node<Svc>, run_id: &str, who: Sender) -> Result<Self> {
        Ok(Self {
            sub: ipc::control(node, run_id, who)?
                .subscriber_builder()
                .create()
                .ipc(format!("subscriber on {}", ipc::control_service(who)))?,
            who,
            root: Cell::new(None),
            publisher: Cell::new(None),
            intruder: Cell::new(None),
        })
    }

    /// The kinds `who` may send.
    fn allowed(&self, kind: ControlKind) -> bool {
        match self.who {
            Sender::Plant => kind.said_by_plant(),
            Sender::Controller => kind.said_by_controller(),
            Sender::Supervisor => false,
        }
    }

    /// The next message the child itself sent, of a kind it may send; everything else is dropped
    /// (and a foreign publisher remembered).
    fn receive(&self) -> Result<Option<ControlMsg>> {
        while let Some(sample) = self.sub.receive().ipc("receive control")? {
            let origin = sample.origin();
            let trusted = match (self.publisher.get(), self.root.get()) {
                (Some(id), _) => id == origin,
                (None, Some(root)) => {
                    let pid = sample
                        .header()
                        .node_id()
                        .pid::<Svc>()
                        .map_or(0, |p| p.value() as u32);
                    let ok = pid != 0 && in_process_tree(pid, root);
                    if ok {
                        self.publisher.set(Some(origin));
                    } else if self.intruder.get().is_none() {
                        self.intruder.set(Some(pid));
                    }
                    ok
                }
                (None, None) => false,
            };
            let m = *sample.payload();
            if trusted && m.sender() == Some(self.who) && m.kind().is_some_and(|k| self.allowed(k))
            {
                return Ok(Some(m));
            }
        }
        Ok(None)
    }

    /// One line about a process that published on this child's service, if one did.
    fn intrusion(&self) -> Option<String> {
        let pid = self.intruder.get()?;
        let who = role(self.who);
        Some(format!(
            "a process that is not the {who} ({}) published on the {who}'s control service `{}`; its messages were ignored: only the {who} may speak there",
            ipc::describe_process(pid),
            ipc::control_service(self.who),
        ))
    }
}

/// The supervisor's ports: observers of the three loop streams, run control (the reference
/// publisher is a [`ReferenceFeed`] on the same node).
pub(super) struct Observer {
    pub(super) state: Subscriber<Svc, StateMsg, ()>,
    pub(super) torque: Subscriber<Svc, TorqueMsg, ()>,
    pub(super) telemetry: Subscriber<Svc, TelemetryMsg, ()>,
    /// START and STOP: the only publisher of `control`, taken before the children start.
    pub(super) control: Publisher<Svc, ControlMsg, ()>,
    from_plant: ControlIn,
    from_controller: ControlIn,
    pub(super) node: Node<Svc>,
}

impl Observer {
    pub(super) fn open(run_id: &str) -> Result<Self> {
        let node = ipc::node("supervisor", run_id)?;
        Ok(Self {
            state: ipc::state(&node, run_id)?
                .subscriber_builder()
                .buffer_size(OBSERVER_BUFFER)
                .create()
                .ipc("state observer")?,
            torque: ipc::torque(&node, run_id)?
                .subscriber_builder()
                .buffer_size(OBSERVER_BUFFER)
                .create()
                .ipc("torque observer")?,
            telemetry: ipc::telemetry(&node, run_id)?
                .subscriber_builder()
                .buffer_size(OBSERVER_BUFFER)
                .create()
                .ipc("telemetry observer")?,
            control: ipc::control(&node, run_id, Sender::Supervisor)?
                .publisher_builder()
                .create()
                .ipc("control publisher")?,
            from_plant: ControlIn::open(&node, run_id, Sender::Plant)?,
            from_controller: ControlIn::open(&node, run_id, Sender::Controller)?,
            node,
        })
    }

    /// The children's pids: from now on their control services are believed only from them.
    pub(super) fn trust(&self, pair: &Pair) {
        let (plant, controller) = pair.pids();
        self.from_plant.root.set(plant);
        self.from_controller.root.set(controller);
    }

    /// The plant's next message on its control service (from the plant only).
    pub(super) fn plant_said(&self) -> Result<Option<ControlMsg>> {
        self.from_plant.receive()
    }

    /// The controller's next message on its control service (from the controller only).
    pub(super) fn controller_said(&self) -> Result<Option<ControlMsg>> {
        self.from_controller.receive()
    }

    /// The next message of either child (the plant's first).
    pub(super) fn receive(&self) -> Result<Option<ControlMsg>> {
        match self.from_plant.receive()? {
            Some(m) => Ok(Some(m)),
            None => self.from_controller.receive(),
        }
    }

    /// Lines about processes that published on a child's control service.
    pub(super) fn intrusions(&self) -> Vec<String> {
        [&self.from_plant, &self.from_controller]
            .iter()
            .filter_map(|c| c.intrusion())
            .collect()
    }

    /// Sends STOP to both children.
    pub(super) fn stop(&self) {
        let _ = self
            .control
            .send_copy(ControlMsg::new(ControlKind::Stop, Sender::Supervisor));
    }
}

/// Polls the control channel until `done` says a handshake step is complete (Ok(true)), failing
/// (with the children's stderr) if a child exits first or the handshake timeout passes. Ok(false)
/// if Ctrl-C / SIGTERM / SIGHUP arrived first.
fn await_control(
    obs: &Observer,
    pair: &mut Pair,
    step: &dyn Fn() -> String,
    done: &mut dyn FnMut(&ControlMsg) -> bool,
) -> Result<bool> {
    let timeout = pair.handshake_timeout_ns();
    let deadline = rt::now_ns() + timeout;
    loop {
        while let Some(m) = obs.receive()? {
            if done(&m) {
                return Ok(true);
            }
        }
        if let Some(i) = obs.intrusions().into_iter().next() {
            bail!("{i}");
        }
        if crate::signals::interrupted() {
            return Ok(false);
        }
        pair.check_alive()?;
        if rt::now_ns() > deadline {
            let said = pair.logs().said();
            bail!(
                "{}{} within {} s{}{said}",
                step(),
                pair.far_side_note(),
                timeout / 1_000_000_000,
                if said.is_empty() { "" } else { ": " }
            );
        }
        std::thread::sleep(Duration::from_micros(200));
    }
}

/// READY from both children, the first chunks of the reference to the controller, ARMED from it.
/// Ok(false) if the run was interrupted first.
pub(super) fn handshake(
    obs: &Observer,
    feed: &mut ReferenceFeed,
    pair: &mut Pair,
    study: &Study,
) -> Result<bool> {
    let pair_shown = pair.shown().clone();
    let ready_from = [std::cell::Cell::new(false), std::cell::Cell::new(false)];
    let mut label = None;
    let silent = || {
        let who: Vec<String> = [
            (Sender::Plant, &pair_shown.0),
            (Sender::Controller, &pair_shown.1),
        ]
        .iter()
        .zip(&ready_from)
        .filter(|(_, r)| !r.get())
        .map(|((w, cmd), _)| format!("the {} (`{cmd}`)", role(*w)))
        .collect();
        format!("{} never said READY", who.join(" and "))
    };
    let ready = await_control(obs, pair, &silent, &mut |m| {
        match (m.kind(), m.sender()) {
            (Some(ControlKind::Ready), Some(Sender::Plant)) => ready_from[0].set(true),
            (Some(ControlKind::Ready), Some(Sender::Controller)) => {
                ready_from[1].set(true);
                // A controller may name itself in its READY (the C ABI's dl_run_set_label).
                let t = m.text();
                label =
                    (!t.is_empty()).then(|| crate::peer_text::sanitize(t.as_bytes(), LABEL_CHARS));
            }
            _ => {}
        }
        ready_from.iter().all(std::cell::Cell::get)
    })?;
    if !ready {
        return Ok(false);
    }
    pair.said_label(label);
    feed.send_initial(&study.reference)?;
    let unarmed = || {
        format!(
            "the controller (`{}`) never said ARMED (it takes the reference first)",
            pair_shown.1
        )
    };
    await_control(obs, pair, &unarmed, &mut |m| {
        m.kind() == Some(ControlKind::Armed)
    })
}

/// The longest name a controller gives itself that the run shows, characters.
const LABEL_CHARS: usize = 64;

/// Ctrl-C (or SIGTERM, SIGHUP) during the handshake: no START is sent; STOP releases both
/// children, which exit at once; the run holds no tick.
pub(super) fn stopped_before_start(
    obs: &Observer,
    mut pair: Pair,
    law: Law,
    study: &Study,
    run_id: String,
    keep: &Keep,
) -> Result<ProcessRun> {
    obs.stop();
    // A child that had not subscribed yet misses STOP: dropping the pair sends it SIGTERM.
    let end = rt::now_ns() + 200_000_000;
    while matches!(pair.exited(), (None, _) | (_, None)) && rt::now_ns() < end {
        std::thread::sleep(Duration::from_millis(2));
    }
    // Read the logs after the children are gone, so their last lines are in.
    let logs = pair.logs().clone();
    let controller_label = pair.take_label();
    drop(pair);
    let child_messages = logs.messages();
    let mut rec = lawrun::recorder(study, law, keep)?;
    rec.interrupt();
    Ok(ProcessRun {
        controller_label,
        fault: None,
        interrupted: true,
        run_id,
        run: lawrun::finish(rec, None)?,
        timing: Timing::default(),
        child_messages,
    })
}
