//! The controller process (`deltaloop-controller`): waits for each plant state, runs the
//! controller's tick ([`ControllerSide::answer`], the same every mode uses), and answers with the
//! torque. It knows no kinematics: the joint reference arrives from the supervisor as one
//! zero-copy slice sample.
//!
//! It always answers the newest state (older ones it skipped are counted in the reply). If the
//! plant is silent longer than the silence timeout, it ends with a fault. Exit codes: the table
//! in `deltaloop_transport::exit` (0 done, 2 arguments, 3 set-up, 4 fault, 5 stopped).

use crate::ControllerSide;
use anyhow::{Result, bail};
use clap::Parser;
use deltaloop_config::config::{FaultInjection, Layout};
use deltaloop_config::{Law, RunConfig};
use deltaloop_transport::args::LoopArgs;
use deltaloop_transport::exit::{self, ProcessEnd};
use deltaloop_transport::ipc::{self, ControlPorts, IpcContext, LOOP_BUFFER, Svc};
use deltaloop_transport::rt;
use deltaloop_transport::wire::{
    self, ControlKind, ControlMsg, RefSample, Sender, StateMsg, TorqueMsg,
};
use iceoryx2::port::listener::{Listener, ListenerWaitError};
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};

const NAME: &str = "deltaloop-controller";

#[derive(Parser, Debug)]
#[command(
    name = "deltaloop-controller",
    about = "deltaloop controller process (started by `deltaloop run`)"
)]
struct Args {
    #[command(flatten)]
    run: LoopArgs,
    /// The control law to run.
    #[arg(long, value_parser = Law::parse)]
    law: Law,
}

/// Entry point of `deltaloop-controller`.
pub fn main() -> ExitCode {
    let args = Args::parse();
    let term = rt::child_signals();
    exit::exit(NAME, run(&args, &term))
}

/// The controller's iceoryx2 ports.
struct Ports {
    state: Subscriber<Svc, StateMsg, ()>,
    torque: Publisher<Svc, TorqueMsg, ()>,
    state_ready: Listener<Svc>,
    torque_ready: Notifier<Svc>,
    reference: Subscriber<Svc, [RefSample], ()>,
    control: ControlPorts,
    _node: Node<Svc>,
}

impl Ports {
    fn open(run_id: &str) -> Result<Self> {
        let node = ipc::node("controller", run_id)?;
        Ok(Self {
            state: ipc::state(&node, run_id)?
                .subscriber_builder()
                .buffer_size(LOOP_BUFFER)
                .create()
                .ipc("state subscriber")?,
            torque: ipc::torque(&node, run_id)?
                .publisher_builder()
                .create()
                .ipc("torque publisher")?,
            state_ready: ipc::wakeup(&node, run_id, "state-ready")?
                .listener_builder()
                .create()
                .ipc("state listener")?,
            torque_ready: ipc::wakeup(&node, run_id, "torque-ready")?
                .notifier_builder()
                .create()
                .ipc("torque notifier")?,
            reference: ipc::reference(&node, run_id)?
                .subscriber_builder()
                .create()
                .ipc("reference subscriber")?,
            control: ipc::control_ports(&node, run_id)?,
            _node: node,
        })
    }

    fn send_control(&self, kind: ControlKind) -> Result<()> {
        self.control
            .0
            .send_copy(ControlMsg::new(kind, Sender::Controller))
            .ipc(format!("send {kind:?}"))?;
        Ok(())
    }
}

fn run(args: &Args, term: &AtomicBool) -> Result<ProcessEnd> {
    let cfg = RunConfig::from_file(&args.run.config)?;
    let Some(layout) = args.run.mode.layout(&cfg) else {
        bail!("mode {} has no processes", args.run.mode);
    };
    let ports = Ports::open(&args.run.run_id)?;
    rt::schedule_and_report_ready(
        &rt::Sched {
            core: Layout::cpu(layout.controller_cpu),
            fifo_priority: layout.controller_priority.unwrap_or(0),
            lock_memory: layout.lock_memory.unwrap_or(false),
        },
        NAME,
        || ports.send_control(ControlKind::Ready),
    )?;
    let Some(reference) = handshake(&ports, term)? else {
        return Ok(ProcessEnd::Stopped("stopped before start".into()));
    };
    let spin_ns = u64::from(layout.spin_us.unwrap_or(0)) * 1000;
    answer_states(&ports, &cfg, args.law, reference.payload(), spin_ns, term)
}

/// The handshake: take the reference (one slice sample), touch it, report ARMED, wait for START.
/// None if the supervisor stopped the run first (STOP or SIGTERM).
fn handshake(
    ports: &Ports,
    term: &AtomicBool,
) -> Result<Option<iceoryx2::sample::Sample<Svc, [RefSample], ()>>> {
    let end = rt::now_ns() + ipc::HANDSHAKE_TIMEOUT_NS;
    let reference = loop {
        if let Some(r) = ports.reference.receive().ipc("receive reference")? {
            break r;
        }
        if drain_control(&ports.control.1)?.1 || term.load(Ordering::Relaxed) {
            return Ok(None);
        }
        if rt::now_ns() > end {
            bail!(
                "no reference from the supervisor within {} s",
                ipc::HANDSHAKE_TIMEOUT_NS / 1_000_000_000
            );
        }
        std::thread::sleep(std::time::Duration::from_millis(1));
    };
    // Touch every row now, so no tick page-faults on its reference; then report ARMED.
    std::hint::black_box(reference.payload().iter().map(|r| r.q[0]).sum::<f64>());
    ports.send_control(ControlKind::Armed)?;
    loop {
        match drain_control(&ports.control.1)? {
            (_, true) => return Ok(None),
            _ if term.load(Ordering::Relaxed) => return Ok(None),
            (true, _) => return Ok(Some(reference)),
            _ => {}
        }
        if rt::now_ns() > end {
            bail!(
                "no START from the supervisor within {} s",
                ipc::HANDSHAKE_TIMEOUT_NS / 1_000_000_000
            );
        }
        std::thread::sleep(std::time::Duration::from_micros(200));
    }
}

/// The loop: answer every state until the final one, the plant's silence, or a stop.
fn answer_states(
    ports: &Ports,
    cfg: &RunConfig,
    law: Law,
    rows: &[RefSample],
    spin_ns: u64,
    term: &AtomicBool,
) -> Result<ProcessEnd> {
    let compute_delay_us = cfg.controller.compute_delay_us;
    let inject = cfg.faults.inject;
    let mut side = ControllerSide::from_config(cfg, law);
    let silence_ns = u64::from(cfg.loop_.silence_timeout_ms) * 1_000_000;
    loop {
        let waited = wait_state(&ports.state, &ports.state_ready, silence_ns, spin_ns);
        if term.load(Ordering::Relaxed) {
            return Ok(ProcessEnd::Stopped("stopped by SIGTERM".into()));
        }
        let Some((state, skipped, rx)) = waited? else {
            return Ok(ProcessEnd::Fault(format!(
                "plant silent for {} ms",
                cfg.loop_.silence_timeout_ms
            )));
        };
        if state.flags & wire::STATE_FINAL != 0 {
            return Ok(ProcessEnd::Completed);
        }
        // Injected faults (drills and tests): stall = stop answering, panic = die loudly.
        match inject {
            FaultInjection::Stall(k) if state.tick >= k => continue,
            FaultInjection::Panic(k) if state.tick >= k => {
                panic!("injected controller panic at tick {}", state.tick)
            }
            _ => {}
        }
        let Some(r) = rows.get(state.tick as usize) else {
            return Ok(ProcessEnd::Fault(format!(
                "state tick {} is beyond the reference ({} ticks)",
                state.tick,
                rows.len()
            )));
        };
        let mut msg = side.answer(&state, &crate::reference(r));
        if matches!(inject, FaultInjection::NanTorque(k) if state.tick == k) {
            msg.tau = [f64::NAN; 3];
        }
        // Injected compute delay: extra wall time before the reply (realtime: real misses).
        if compute_delay_us > 0 {
            rt::spin_for_us(compute_delay_us);
        }
        msg.skipped = skipped;
        msg.t_state_rx_ns = rx;
        msg.t_publish_ns = rt::now_ns();
        ports.torque.send_copy(msg).ipc("publish torque")?;
        ports.torque_ready.notify().ipc("notify torque")?;
    }
}

/// Waits for the next state (busy-polls for `spin_ns`, then blocks on the wake-up event) and
/// returns the newest one, how many older ones it skipped, and when it was taken.
fn wait_state(
    sub: &Subscriber<Svc, StateMsg, ()>,
    listener: &Listener<Svc>,
    silence_ns: u64,
    spin_ns: u64,
) -> Result<Option<(StateMsg, u64, u64)>> {
    let start = rt::now_ns();
    let (spin_end, until) = (start + spin_ns, start + silence_ns);
    loop {
        let mut newest: Option<StateMsg> = None;
        let mut seen = 0u64;
        while let Some(sample) = sub.receive().ipc("receive state")? {
            newest = Some(*sample.payload());
            seen += 1;
        }
        if let Some(s) = newest {
            return Ok(Some((s, seen - 1, rt::now_ns())));
        }
        let now = rt::now_ns();
        if now >= until {
            return Ok(None);
        }
        if now < spin_end {
            std::hint::spin_loop();
            continue;
        }
        // The only timeout here is the silence limit (seconds), so iceoryx2's own timed wait (a
        // blocking receive, woken directly by the notification) is precise enough and cheapest.
        // A signal (SIGCONT after a SIGSTOP, say) only interrupts the wait: look again.
        match listener.timed_wait(|_| {}, core::time::Duration::from_nanos(until - now)) {
            Ok(_) | Err(ListenerWaitError::InterruptSignal) => {}
            Err(e) => return Err(e).ipc("wait for state").map_err(Into::into),
        }
    }
}

/// Drains the control channel: (saw START, saw STOP).
fn drain_control(sub: &Subscriber<Svc, ControlMsg, ()>) -> Result<(bool, bool)> {
    let (mut start, mut stop) = (false, false);
    while let Some(m) = sub.receive().ipc("receive control")? {
        start |= m.payload().kind() == Some(ControlKind::Start);
        stop |= m.payload().kind() == Some(ControlKind::Stop);
    }
    Ok((start, stop))
}
