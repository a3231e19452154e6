//! The plant process (`deltaloop-plant`): steps [`Plant`] once per tick and exchanges state and
//! torque with the controller over iceoryx2. The loop is the same `Plant::advance` every mode uses.
//!
//! - lockstep: publish state k, wait (without limit but the silence timeout) for τ_k, integrate.
//! - realtime: wake at the absolute deadline t0 + k·Ts, publish state k, wait for τ_k at most the
//!   torque budget; if it is not there, hold the last applied torque and count a miss. A reply
//!   sent after its budget, or for an earlier tick, is dropped: never applied late or to the
//!   wrong tick.
//!
//! Exit codes: 0 done, 2 bad arguments, 3 setup failed, 4 fault during the run (stderr says why).

use crate::{DeltaRobot, Plant, SimConfig, Vec3};
use anyhow::{Context, Result, bail};
use clap::Parser;
use deltaloop_protocol::config::{Layout, ProcMode};
use deltaloop_protocol::ipc::{self, LOOP_BUFFER};
use deltaloop_protocol::wire::{self, ControlMsg, StateMsg, TelemetryMsg, control};
use deltaloop_protocol::{RunConfig, rt};
use std::path::PathBuf;
use std::process::ExitCode;

/// The plant's simulation settings for a config (one mapping for every mode).
pub fn sim_config(cfg: &RunConfig) -> SimConfig {
    SimConfig {
        ts: cfg.loop_.ts_s,
        substeps: cfg.plant.substeps,
        friction: cfg.plant.friction,
        check_margins: true,
        payload_step: cfg.payload_step_tick().map(|tick| crate::sim::PayloadStep {
            mass_kg: cfg.plant.payload_step_kg,
            tick,
        }),
    }
}

/// The plant a config describes, at rest at `q0` (rad): dynamics, drives (clamp, transport delay)
/// and sensors. Every mode builds its plant here.
pub fn plant_from_config(cfg: &RunConfig, q0: Vec3) -> Result<Plant, crate::KinematicsError> {
    let plant = Plant::new(
        DeltaRobot::default(),
        sim_config(cfg),
        cfg.plant.tau_max_nm,
        cfg.plant.transport_delay_samples as usize,
        q0,
    )?
    .reject_over_limit(cfg.faults.torque_limit == deltaloop_protocol::config::TorqueLimit::Reject);
    let se = &cfg.sensor;
    Ok(if se.is_ideal() {
        plant
    } else {
        plant.with_sensor(crate::sensor::Sensor::new(crate::sensor::SensorConfig {
            encoder_counts_per_rev: se.encoder_counts_per_rev,
            q_noise_std: se.q_noise_std_rad,
            qd_noise_std: se.qd_noise_std_rad_s,
            seed: se.seed,
        }))
    })
}

#[derive(Parser, Debug)]
#[command(
    name = "deltaloop-plant",
    about = "deltaloop plant process (started by `deltaloop run`)"
)]
struct Args {
    /// Run id: scopes every iceoryx2 service of this run.
    #[arg(long)]
    run_id: String,
    /// Resolved scenario config.
    #[arg(long)]
    config: PathBuf,
    /// The loop to run: lockstep or realtime.
    #[arg(long, value_parser = ProcMode::parse)]
    mode: ProcMode,
}

/// A fault during the run: the tick and why.
struct Fault(u64, String);

/// Entry point of `deltaloop-plant`.
pub fn main() -> ExitCode {
    let args = Args::parse();
    let term = rt::child_signals();
    match run(&args, &term) {
        Ok(Ok(())) => ExitCode::SUCCESS,
        Ok(Err(Fault(tick, why))) => {
            eprintln!("deltaloop-plant: fault at tick {tick}: {why}");
            ExitCode::from(4)
        }
        Err(e) => {
            eprintln!("deltaloop-plant: {e:#}");
            ExitCode::from(3)
        }
    }
}

fn run(args: &Args, term: &std::sync::atomic::AtomicBool) -> Result<Result<(), Fault>> {
    let cfg = RunConfig::from_file(&args.config)?;
    let layout = args.mode.layout(&cfg).clone();
    let node = ipc::node("plant", &args.run_id)?;
    let rid = &args.run_id;
    let state_pub = ipc::state(&node, rid)?
        .publisher_builder()
        .create()
        .map_err(|e| ipc::err("state publisher")(&e))?;
    let tel_pub = ipc::telemetry(&node, rid)?
        .publisher_builder()
        .create()
        .map_err(|e| ipc::err("telemetry publisher")(&e))?;
    let torque_sub = ipc::torque(&node, rid)?
        .subscriber_builder()
        .buffer_size(LOOP_BUFFER)
        .create()
        .map_err(|e| ipc::err("torque subscriber")(&e))?;
    let state_ready = ipc::wakeup(&node, rid, "state-ready")?
        .notifier_builder()
        .create()
        .map_err(|e| ipc::err("state notifier")(&e))?;
    let torque_ready = ipc::wakeup(&node, rid, "torque-ready")?
        .listener_builder()
        .create()
        .map_err(|e| ipc::err("torque listener")(&e))?;
    let (ctl_pub, ctl_sub) = ipc::control_ports(&node, rid)?;
    rt::schedule_and_report_ready(
        &rt::Sched {
            core: Layout::cpu(layout.plant_cpu),
            fifo_priority: layout.plant_priority.unwrap_or(0),
            lock_memory: layout.lock_memory.unwrap_or(false),
        },
        "deltaloop-plant",
        || {
            ctl_pub
                .send_copy(ControlMsg::new(control::READY, control::PLANT))
                .map(|_| ())
                .map_err(|e| ipc::err("send READY")(&e))
        },
    )?;
    let start = wait_for_start(&ctl_sub, cfg.loop_.silence_timeout_ms.max(30_000))?;

    let mut plant =
        plant_from_config(&cfg, Vec3::from(start.q0)).context("initial configuration")?;
    let ticks = start.ticks;
    let ts_ns = (cfg.loop_.ts_s * 1e9).round() as u64;
    let budget_ns = u64::from(cfg.loop_.torque_budget_us) * 1000;
    let silence_ns = u64::from(cfg.loop_.silence_timeout_ms) * 1_000_000;
    let spin_ns = u64::from(layout.spin_us.unwrap_or(0)) * 1000;
    let early_ns = u64::from(layout.wake_early_us.unwrap_or(0)) * 1000;
    let silence_ticks = u64::from(cfg.faults.controller_silence_ticks);
    let (mut misses, mut late, mut consecutive) = (0u64, 0u64, 0u64);
    let notify = |what: &str| {
        state_ready
            .notify()
            .map(|_| ())
            .map_err(|e| ipc::err(what.to_string())(&e))
    };

    // Set when the loop must end early: (tick, why, whether the plant can still brake).
    let mut fault: Option<(u64, String, bool)> = None;
    let mut last_deadline = start.t0_ns;
    for k in 0..=ticks + 1 {
        let (deadline, wake) = match args.mode {
            ProcMode::Realtime => {
                let d = start.t0_ns + k * ts_ns;
                rt::wake_at_ns(d, early_ns);
                (d, rt::now_ns())
            }
            ProcMode::Lockstep => {
                let now = rt::now_ns();
                (now, now)
            }
        };
        last_deadline = deadline;
        if stop_requested(&ctl_sub) || term.load(std::sync::atomic::Ordering::Relaxed) {
            fault = Some((k, "stopped by the supervisor".into(), true));
            break;
        }
        let truth = plant.sample();
        let s = plant.measure();
        let mut msg = StateMsg {
            tick: k,
            flags: if k == ticks + 1 { wire::STATE_FINAL } else { 0 },
            q: s.q.into(),
            qd: s.qd.into(),
            tau_applied: s.tau_applied.into(),
            q_true: truth.q.into(),
            qd_true: truth.qd.into(),
            t_deadline_ns: deadline,
            t_wake_ns: wake,
            ..StateMsg::default()
        };
        msg.t_publish_ns = rt::now_ns();
        state_pub
            .send_copy(msg)
            .map_err(|e| ipc::err("publish state")(&e))?;
        notify("notify state")?;
        if k == ticks + 1 {
            break;
        }

        let until = match args.mode {
            // The budget runs from the state's publication, not from the deadline: after a late
            // wake the controller still gets its chance, instead of being starved (it runs below
            // the plant on the same CPU) while the plant races through its backlog.
            ProcMode::Realtime => msg.t_publish_ns + budget_ns,
            ProcMode::Lockstep => rt::now_ns() + silence_ns,
        };
        let reply = wait_torque(&torque_sub, &torque_ready, k, until, spin_ns, &mut late)?;
        let mut tel = TelemetryMsg {
            tick: k,
            t_deadline_ns: deadline,
            t_wake_ns: wake,
            t_state_pub_ns: msg.t_publish_ns,
            ..TelemetryMsg::default()
        };
        let cmd = match reply {
            Some((t, rx)) => {
                tel.t_torque_rx_ns = rx;
                consecutive = 0;
                Some(Vec3::from(t.tau))
            }
            None if args.mode == ProcMode::Lockstep => {
                let why = format!(
                    "controller silent: no torque for tick {k} within {} ms",
                    cfg.loop_.silence_timeout_ms
                );
                fault = Some((k, why, true));
                break;
            }
            None => {
                misses += 1;
                consecutive += 1;
                tel.flags |= wire::TEL_MISSED;
                if consecutive >= silence_ticks {
                    let why = format!(
                        "no torque within the budget for {consecutive} consecutive ticks ({:.1} ms; controller dead, stalled or too slow, {late} late replies dropped); the plant held the last applied torque through them",
                        consecutive as f64 * cfg.loop_.ts_s * 1e3
                    );
                    fault = Some((k, why, true));
                    break;
                }
                None
            }
        };
        match plant.advance(cmd) {
            Ok(a) => {
                tel.flags |= if a.clamped { wire::TEL_CLAMPED } else { 0 }
                    | if a.held { wire::TEL_HELD } else { 0 }
                    | if a.rejected { wire::TEL_REJECTED } else { 0 };
            }
            Err(e) => {
                // The model itself failed (singularity, divergence): no brake can be computed.
                fault = Some((k + 1, e.to_string(), false));
                break;
            }
        }
        tel.misses = misses;
        tel.late_dropped = late;
        tel_pub
            .send_copy(tel)
            .map_err(|e| ipc::err("publish telemetry")(&e))?;
    }
    let Some((tick, why, can_brake)) = fault else {
        // No DONE message: the final state and the exit status say it, and the controller's ports
        // are already going away (a send now would race their teardown).
        return Ok(Ok(()));
    };
    let t = tick as f64 * cfg.loop_.ts_s;
    let kind = if can_brake {
        control::FAULT
    } else {
        control::DIVERGED
    };
    let _ = ctl_pub.send_copy(ControlMsg::with_text(kind, control::PLANT, tick, &why));
    // Release the controller (it may be blocked waiting for a state): the run is over.
    let last = plant.sample();
    let final_state = StateMsg {
        tick,
        flags: wire::STATE_FINAL,
        q: last.q.into(),
        qd: last.qd.into(),
        tau_applied: last.tau_applied.into(),
        q_true: last.q.into(),
        qd_true: last.qd.into(),
        t_publish_ns: rt::now_ns(),
        ..StateMsg::default()
    };
    let _ = state_pub.send_copy(final_state);
    let _ = state_ready.notify();
    if !can_brake {
        return Ok(Err(Fault(
            tick,
            format!("t = {t:.4} s: {why}; no safe stop possible"),
        )));
    }
    // Safe stop: the drives brake (τ = G(q) − D q̇) for safe_stop_ms, keeping the clock in realtime.
    let stop_ticks = (f64::from(cfg.faults.safe_stop_ms) * 1e-3 / cfg.loop_.ts_s).round() as u64;
    let damping = cfg.faults.brake_damping_nm_s;
    for i in 1..=stop_ticks {
        if args.mode == ProcMode::Realtime {
            rt::wake_at_ns(last_deadline + i * ts_ns, early_ns);
        }
        if let Err(e) = plant.brake_tick(damping) {
            return Ok(Err(Fault(
                tick,
                format!("t = {t:.4} s: {why}; the safe stop failed: {e}"),
            )));
        }
        let tel = TelemetryMsg {
            tick: tick + i,
            flags: wire::TEL_SAFE_STOP | wire::TEL_HELD,
            t_wake_ns: rt::now_ns(),
            ..TelemetryMsg::default()
        };
        let _ = tel_pub.send_copy(tel);
    }
    let speed = plant.sample().qd.amax();
    Ok(Err(Fault(
        tick,
        format!(
            "t = {t:.4} s: {why}; then braked for {} ms (τ = G(q) − {damping} q̇): safe stop, max |q̇| = {speed:.3} rad/s",
            cfg.faults.safe_stop_ms
        ),
    )))
}

/// Waits for τ_k until `until_ns`: busy-polls for `spin_ns`, then blocks on the wake-up event.
/// Replies for other ticks are dropped (and counted in `late` when older). Returns the reply and
/// its receive time.
/// What the plant does with a torque reply while it waits for tick `tick`'s.
#[derive(Debug, PartialEq, Eq)]
enum Reply {
    /// The answer to this tick, sent within the budget.
    Apply,
    /// Too late: for an earlier tick, or for this one but sent after the budget ended.
    Late,
    /// Not an answer to any state published yet (a misbehaving peer): dropped.
    Ignore,
}

/// Judges a reply by the controller's own send time, not by when the plant looks: a plant that
/// was itself preempted past the budget must not apply a reply that came late (it would count a
/// late controller as on time, and the miss statistics would depend on the plant's CPU).
fn reply_verdict(m: &wire::TorqueMsg, tick: u64, until_ns: u64) -> Reply {
    match m.tick.cmp(&tick) {
        std::cmp::Ordering::Equal if m.t_publish_ns <= until_ns => Reply::Apply,
        std::cmp::Ordering::Equal | std::cmp::Ordering::Less => Reply::Late,
        std::cmp::Ordering::Greater => Reply::Ignore,
    }
}

fn wait_torque(
    sub: &iceoryx2::port::subscriber::Subscriber<ipc::Svc, wire::TorqueMsg, ()>,
    listener: &iceoryx2::port::listener::Listener<ipc::Svc>,
    tick: u64,
    until_ns: u64,
    spin_ns: u64,
    late: &mut u64,
) -> Result<Option<(wire::TorqueMsg, u64)>> {
    let spin_end = rt::now_ns() + spin_ns;
    loop {
        while let Some(sample) = sub.receive().map_err(|e| ipc::err("receive torque")(&e))? {
            let m = *sample.payload();
            match reply_verdict(&m, tick, until_ns) {
                Reply::Apply => return Ok(Some((m, rt::now_ns()))),
                Reply::Late => *late += 1,
                Reply::Ignore => {}
            }
        }
        let now = rt::now_ns();
        if now >= until_ns {
            return Ok(None);
        }
        if now < spin_end {
            std::hint::spin_loop();
            continue;
        }
        // Drop wake-ups already seen (e.g. a late reply's), so the poll sleeps until a new one.
        listener
            .try_wait(|_| {})
            .map_err(|e| ipc::err("drain torque events")(&e))?;
        if sub.has_samples().unwrap_or(true) {
            continue;
        }
        ipc::wait_event(listener, until_ns - now)?;
    }
}

fn stop_requested(sub: &iceoryx2::port::subscriber::Subscriber<ipc::Svc, ControlMsg, ()>) -> bool {
    while let Ok(Some(m)) = sub.receive() {
        if m.payload().kind == control::STOP {
            return true;
        }
    }
    false
}

/// Polls the control channel for START (1 ms steps) up to `timeout_ms`.
fn wait_for_start(
    sub: &iceoryx2::port::subscriber::Subscriber<ipc::Svc, ControlMsg, ()>,
    timeout_ms: u32,
) -> Result<ControlMsg> {
    let end = rt::now_ns() + u64::from(timeout_ms) * 1_000_000;
    while rt::now_ns() < end {
        while let Some(m) = sub.receive().map_err(|e| ipc::err("receive control")(&e))? {
            match m.payload().kind {
                control::START => return Ok(*m.payload()),
                control::STOP => bail!("stopped before start"),
                _ => {}
            }
        }
        std::thread::sleep(std::time::Duration::from_millis(1));
    }
    bail!("no START from the supervisor within {timeout_ms} ms")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reply(tick: u64, t_publish_ns: u64) -> wire::TorqueMsg {
        wire::TorqueMsg {
            tick,
            t_publish_ns,
            ..wire::TorqueMsg::default()
        }
    }

    #[test]
    fn a_reply_in_budget_for_this_tick_is_applied() {
        assert_eq!(reply_verdict(&reply(7, 1_000), 7, 1_000), Reply::Apply);
        assert_eq!(reply_verdict(&reply(7, 999), 7, 1_000), Reply::Apply);
    }

    /// Regression: a plant preempted past its budget applied the late reply it found on waking,
    /// so a controller 1 ms late was counted on time whenever the plant's CPU was busy (seen as a
    /// flaky compute-delay test without SCHED_FIFO).
    #[test]
    fn regression_reply_sent_after_the_budget_is_late_even_if_the_plant_sees_it_late_too() {
        assert_eq!(reply_verdict(&reply(7, 1_001), 7, 1_000), Reply::Late);
    }

    #[test]
    fn replies_for_earlier_ticks_are_late_and_for_later_ticks_ignored() {
        assert_eq!(reply_verdict(&reply(6, 10), 7, 1_000), Reply::Late);
        assert_eq!(reply_verdict(&reply(8, 10), 7, 1_000), Reply::Ignore);
    }
}
