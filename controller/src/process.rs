//! The controller process (`deltaloop-controller`): waits for each plant state, runs the same
//! [`Controller::step`] every mode uses, and answers with the torque. It knows no kinematics: the
//! joint reference arrives from the supervisor as one zero-copy slice sample.
//!
//! It always answers the newest state (older ones it skipped are counted in the reply). If the
//! plant is silent longer than the silence timeout, it exits with a fault.
//!
//! Exit codes: 0 done, 2 bad arguments, 3 setup failed, 4 fault during the run (stderr says why).

use crate::{Controller, Law, Measurement, Reference, Vec3};
use anyhow::{Result, bail};
use clap::Parser;
use deltaloop_protocol::config::{FaultInjection, Layout, ProcMode};
use deltaloop_protocol::ipc::{self, LOOP_BUFFER};
use deltaloop_protocol::wire::{self, ControlMsg, RefSample, StateMsg, TorqueMsg, control};
use deltaloop_protocol::{RunConfig, rt};
use iceoryx2::port::subscriber::Subscriber;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Parser, Debug)]
#[command(
    name = "deltaloop-controller",
    about = "deltaloop controller process (started by `deltaloop run`)"
)]
struct Args {
    /// Run id: scopes every iceoryx2 service of this run.
    #[arg(long)]
    run_id: String,
    /// Resolved scenario config.
    #[arg(long)]
    config: PathBuf,
    /// The control law to run.
    #[arg(long, value_parser = Law::parse)]
    law: Law,
    /// The loop to run: lockstep or realtime.
    #[arg(long, value_parser = ProcMode::parse)]
    mode: ProcMode,
}

/// Entry point of `deltaloop-controller`.
pub fn main() -> ExitCode {
    let args = Args::parse();
    let term = rt::child_signals();
    match run(&args, &term) {
        Ok(None) => ExitCode::SUCCESS,
        Ok(Some(why)) => {
            eprintln!("deltaloop-controller: {why}");
            ExitCode::from(4)
        }
        Err(e) => {
            eprintln!("deltaloop-controller: {e:#}");
            ExitCode::from(3)
        }
    }
}

fn run(args: &Args, term: &std::sync::atomic::AtomicBool) -> Result<Option<String>> {
    let cfg = RunConfig::from_file(&args.config)?;
    let layout = args.mode.layout(&cfg).clone();
    let rid = &args.run_id;
    let node = ipc::node("controller", rid)?;
    let state_sub = ipc::state(&node, rid)?
        .subscriber_builder()
        .buffer_size(LOOP_BUFFER)
        .create()
        .map_err(|e| ipc::err("state subscriber")(&e))?;
    let torque_pub = ipc::torque(&node, rid)?
        .publisher_builder()
        .create()
        .map_err(|e| ipc::err("torque publisher")(&e))?;
    let state_ready = ipc::wakeup(&node, rid, "state-ready")?
        .listener_builder()
        .create()
        .map_err(|e| ipc::err("state listener")(&e))?;
    let torque_ready = ipc::wakeup(&node, rid, "torque-ready")?
        .notifier_builder()
        .create()
        .map_err(|e| ipc::err("torque notifier")(&e))?;
    let ref_sub = ipc::reference(&node, rid)?
        .subscriber_builder()
        .create()
        .map_err(|e| ipc::err("reference subscriber")(&e))?;
    let (ctl_pub, ctl_sub) = ipc::control_ports(&node, rid)?;
    rt::schedule_and_report_ready(
        &rt::Sched {
            core: Layout::cpu(layout.controller_cpu),
            fifo_priority: layout.controller_priority.unwrap_or(0),
            lock_memory: layout.lock_memory.unwrap_or(false),
        },
        "deltaloop-controller",
        || {
            ctl_pub
                .send_copy(ControlMsg::new(control::READY, control::CONTROLLER))
                .map(|_| ())
                .map_err(|e| ipc::err("send READY")(&e))
        },
    )?;

    // Handshake: the reference (one slice sample), then ARMED, then START.
    let end = rt::now_ns() + 30_000_000_000;
    let reference = loop {
        if let Some(r) = ref_sub
            .receive()
            .map_err(|e| ipc::err("receive reference")(&e))?
        {
            break r;
        }
        if drain_control(&ctl_sub)?.1 {
            return Ok(Some("stopped before start".into()));
        }
        if rt::now_ns() > end {
            bail!("no reference from the supervisor within 30 s");
        }
        std::thread::sleep(std::time::Duration::from_millis(1));
    };
    let rows: &[RefSample] = reference.payload();
    // Touch every row now, so no tick page-faults on its reference; then report ARMED.
    std::hint::black_box(rows.iter().map(|r| r.q[0]).sum::<f64>());
    ctl_pub
        .send_copy(ControlMsg::new(control::ARMED, control::CONTROLLER))
        .map_err(|e| ipc::err("send ARMED")(&e))?;
    loop {
        match drain_control(&ctl_sub)? {
            (_, true) => return Ok(Some("stopped before start".into())),
            (true, _) => break,
            _ => {}
        }
        if rt::now_ns() > end {
            bail!("no START from the supervisor within 30 s");
        }
        std::thread::sleep(std::time::Duration::from_micros(200));
    }

    let compute_delay_us = cfg.controller.compute_delay_us;
    let inject = cfg.faults.inject;
    let mut ctrl = Controller::new(
        args.law,
        cfg.controller_params(),
        cfg.loop_.ts_s,
        cfg.controller.tde_delay_samples as usize,
    )
    .with_velocity(cfg.sensor.velocity);
    let silence_ns = u64::from(cfg.loop_.silence_timeout_ms) * 1_000_000;
    let spin_ns = u64::from(layout.spin_us.unwrap_or(0)) * 1000;
    loop {
        let waited = wait_state(&state_sub, &state_ready, silence_ns, spin_ns);
        if term.load(std::sync::atomic::Ordering::Relaxed) {
            return Ok(Some("stopped by SIGTERM".into()));
        }
        let Some((state, skipped, rx)) = waited? else {
            return Ok(Some(format!(
                "plant silent for {} ms",
                cfg.loop_.silence_timeout_ms
            )));
        };
        if state.flags & wire::STATE_FINAL != 0 {
            return Ok(None);
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
            return Ok(Some(format!(
                "state tick {} is beyond the reference ({} ticks)",
                state.tick,
                rows.len()
            )));
        };
        let out = ctrl.step(
            &measurement(&state),
            &Reference {
                q: Vec3::from(r.q),
                qd: Vec3::from(r.qd),
                qdd: Vec3::from(r.qdd),
            },
        );
        let out = match inject {
            FaultInjection::NanTorque(k) if state.tick == k => crate::Output {
                tau: Vec3::repeat(f64::NAN),
                ..out
            },
            _ => out,
        };
        // Injected compute delay: extra wall time before the reply (realtime: real misses).
        if compute_delay_us > 0 {
            rt::spin_for_us(compute_delay_us);
        }
        let msg = TorqueMsg {
            skipped,
            t_state_rx_ns: rx,
            t_publish_ns: rt::now_ns(),
            ..reply(state.tick, &out)
        };
        torque_pub
            .send_copy(msg)
            .map_err(|e| ipc::err("publish torque")(&e))?;
        torque_ready
            .notify()
            .map_err(|e| ipc::err("notify torque")(&e))?;
    }
}

/// What the controller measures, read off a state message (joint data and applied torque only).
pub fn measurement(s: &StateMsg) -> Measurement {
    Measurement {
        q: Vec3::from(s.q),
        qd: Vec3::from(s.qd),
        tau_applied: Vec3::from(s.tau_applied),
    }
}

/// The reply to tick `tick`: the torque and the law's internals (skip count and times left zero,
/// for the caller to stamp).
pub fn reply(tick: u64, out: &crate::Output) -> TorqueMsg {
    TorqueMsg {
        tick,
        tau: out.tau.into(),
        s: out.s.into(),
        n_hat: out.n_hat.into(),
        u: out.u.into(),
        ..TorqueMsg::default()
    }
}

/// Waits for the next state (busy-polls for `spin_ns`, then blocks on the wake-up event) and
/// returns the newest one, how many older ones it skipped, and when it was taken.
fn wait_state(
    sub: &Subscriber<ipc::Svc, StateMsg, ()>,
    listener: &iceoryx2::port::listener::Listener<ipc::Svc>,
    silence_ns: u64,
    spin_ns: u64,
) -> Result<Option<(StateMsg, u64, u64)>> {
    let start = rt::now_ns();
    let (spin_end, until) = (start + spin_ns, start + silence_ns);
    loop {
        let mut newest: Option<StateMsg> = None;
        let mut seen = 0u64;
        while let Some(sample) = sub.receive().map_err(|e| ipc::err("receive state")(&e))? {
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
        listener
            .timed_wait(|_| {}, core::time::Duration::from_nanos(until - now))
            .map_err(|e| ipc::err("wait for state")(&e))?;
    }
}

/// Drains the control channel: (saw START, saw STOP).
fn drain_control(sub: &Subscriber<ipc::Svc, ControlMsg, ()>) -> Result<(bool, bool)> {
    let (mut start, mut stop) = (false, false);
    while let Some(m) = sub.receive().map_err(|e| ipc::err("receive control")(&e))? {
        start |= m.payload().kind == control::START;
        stop |= m.payload().kind == control::STOP;
    }
    Ok((start, stop))
}
