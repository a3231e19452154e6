//! The plant process (`deltaloop-plant`): runs the plant's tick ([`PlantSide`], the same every
//! mode uses) once per tick and exchanges state and torque with the controller over the loop's
//! transport (iceoryx2, or across two hosts the link's socket), which its binary's
//! [`Connector`] picks at START; the process is generic over it.
//!
//! - lockstep: publish state k, wait (without limit but the silence timeout) for τ_k, integrate.
//! - realtime: wake at the absolute deadline t0 + k·Ts, publish state k, wait for τ_k at most the
//!   torque budget (counted from the state's publication); if it is not there, hold the last
//!   applied torque and count a miss. A reply sent after its budget, or for an earlier tick, is
//!   dropped: never applied late or to the wrong tick. A reply in time takes effect at its arrival
//!   (`apply_torque = "arrival"`, the default): its publish time minus the tick's deadline, plus
//!   the configured transport delay, cuts the interval there (docs/delta-robot.md §5.2).
//!
//! After a fault (or a STOP) the drives brake for `safe_stop_ms` before the process exits. Exit
//! codes: the table in `deltaloop_transport::exit` (0 done, 2 arguments, 3 set-up, 4 fault,
//! 5 stopped).

use crate::reply::{Awaited, wait_torque};
use crate::{Arrival, Physics, PlantSide, PlantStop, plant_from_config};
use anyhow::{Context, Result, bail};
use clap::Parser;
use deltaloop_config::{ApplyTorque, Overrun, Poll};
use deltaloop_config::{LoopMode, RunConfig};
use deltaloop_model::Vec3;
use deltaloop_transport::args::LoopArgs;
use deltaloop_transport::exchange::{
    Connector, IpcPlant, OverTransport, PlantTransport, Transport,
};
use deltaloop_transport::exit::{self, ProcessEnd};
use deltaloop_transport::ipc::{self, ControlIn, ControlPorts, IpcContext, TelemetryOut};
use deltaloop_transport::rt;
use deltaloop_transport::wire::{self, ControlKind, ControlMsg, Sender};
use std::marker::PhantomData;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};

const NAME: &str = "deltaloop-plant";

#[derive(Parser, Debug)]
#[command(
    name = "deltaloop-plant",
    about = "deltaloop plant process (started by `deltaloop run`)"
)]
struct Args {
    #[command(flatten)]
    run: LoopArgs,
}

/// Entry point of `deltaloop-plant`, over the transport `connector` gives at START.
pub fn main(connector: impl Connector) -> ExitCode {
    let args = Args::parse();
    let term = rt::child_signals();
    let end = serve(&args.run, &term, NAME, connector, |cfg| {
        let cfg = cfg.clone();
        Ok(move |q0| Ok(plant_from_config(&cfg, q0)?))
    });
    exit::exit(NAME, end)
}

/// The plant's iceoryx2 ports beside the loop's: telemetry and run control.
struct Ports {
    telemetry: TelemetryOut,
    control: ControlPorts,
    /// The controller's own control service: its CONTROLLER_ERROR (its step failed) ends the
    /// loop at once instead of after the silence window.
    from_controller: ControlIn,
    _node: ipc::RunNode,
}

impl Ports {
    /// These ports and the loop's (which go to the transport at START).
    fn open(run_id: &str) -> Result<(Self, IpcPlant)> {
        let node = ipc::node("plant", run_id)?;
        let loop_ports = IpcPlant::open(&node, run_id)?;
        let ports = Self {
            telemetry: ipc::telemetry(&node, run_id)?.sole_publisher("telemetry")?,
            control: ipc::control_ports(&node, run_id, Sender::Plant)?,
            from_controller: ipc::control(&node, run_id, Sender::Controller)?
                .subscriber(None, "control-controller subscriber")?,
            _node: node,
        };
        Ok((ports, loop_ports))
    }
}

/// The loop's settings, in integer nanoseconds, and the realtime clock's epoch.
struct Clock {
    mode: LoopMode,
    t0_ns: u64,
    ts_ns: u64,
    budget_ns: u64,
    silence_ns: u64,
    spin_ns: u64,
    early_ns: u64,
    /// Between looks for the reply: spin, or yield to a controller on this CPU.
    poll: Poll,
    /// Replies act on the physics at their measured arrival (realtime, `apply_torque = "arrival"`).
    at_arrival: bool,
    /// What a wake later than `overrun_after_ns` does (realtime).
    overrun: Overrun,
    overrun_after_ns: u64,
    /// How far the epoch has moved: the stalls simulated time paused for (`stretch`), ns.
    paused_ns: u64,
}

/// Tick k's times: its deadline and when the plant woke for it, ns.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Woke {
    deadline: u64,
    wake: u64,
}

impl Clock {
    /// Waits for tick k. Lockstep has no deadline: both times are now. In realtime a wake more
    /// than the overrun bound late (the host did not run this process) moves the epoch with
    /// `stretch`: tick k is due now, and simulated time has paused for the stall.
    fn wake(&mut self, k: u64) -> Woke {
        match self.mode {
            LoopMode::Realtime => {
                let d = self.t0_ns + self.paused_ns + k * self.ts_ns;
                rt::wake_at_ns(d, self.early_ns);
                let woke = self.overrun_of(Woke {
                    deadline: d,
                    wake: rt::now_ns(),
                });
                self.paused_ns += woke.deadline - d;
                woke
            }
            _ => {
                let now = rt::now_ns();
                Woke {
                    deadline: now,
                    wake: now,
                }
            }
        }
    }

    /// The tick's times after the overrun policy: with `stretch` and a wake beyond the bound, the
    /// deadline moves to the wake.
    fn overrun_of(&self, w: Woke) -> Woke {
        let late = w.wake.saturating_sub(w.deadline);
        if self.overrun == Overrun::Stretch && late > self.overrun_after_ns {
            Woke {
                deadline: w.wake,
                ..w
            }
        } else {
            w
        }
    }

    /// With `fault`, how late (ns) the plant woke for a tick beyond the bound: the loop stops.
    fn overrun_fault(&self, w: Woke) -> Option<u64> {
        let late = w.wake.saturating_sub(w.deadline);
        (self.mode == LoopMode::Realtime
            && self.overrun == Overrun::Fault
            && late > self.overrun_after_ns)
            .then_some(late)
    }
}

/// Why the loop ended before its last tick.
struct LoopStop {
    tick: u64,
    cause: String,
    /// What the plant tells the supervisor: STOPPED (on request), FAULT, OVERRUN, PLANT_ERROR
    /// (it can brake) or DIVERGED (the model failed: it cannot).
    kind: ControlKind,
    /// The last deadline the loop kept, ns (the safe stop keeps the clock from there).
    last_deadline_ns: u64,
}

/// The plant process of run `args`: `open` prepares the plant from the run's config (before
/// READY: a rig opens its drives here) and returns how to start it at rest at q0 (rad, after
/// START); then the loop until the run ends, and the safe stop, over the transport `connector`
/// picks at START (asked at set-up, before READY). `name` prefixes its messages.
pub fn serve<P, S>(
    args: &LoopArgs,
    term: &AtomicBool,
    name: &str,
    mut connector: impl Connector,
    open: impl FnOnce(&RunConfig) -> Result<S>,
) -> Result<ProcessEnd>
where
    P: Physics,
    S: FnOnce(Vec3) -> Result<P>,
{
    let cfg = RunConfig::from_file(&args.config)?;
    let Some(layout) = args.mode.layout(&cfg) else {
        bail!("mode {} has no processes", args.mode);
    };
    let start_at = open(&cfg)?;
    let (ports, loop_ports) = Ports::open(&args.run_id)?;
    connector.prepare(&cfg)?;
    rt::schedule_and_report_ready(
        &rt::Sched {
            core: layout.plant_cpu,
            priority: layout.plant_priority,
            lock_memory: layout.lock_memory,
        },
        name,
        || -> Result<()> {
            ports
                .control
                .0
                .send_copy(ControlMsg::new(ControlKind::Ready, Sender::Plant))
                .ipc("send READY")?;
            Ok(())
        },
    )?;
    let handshake_ms = u32::try_from(ipc::START_TIMEOUT_NS / 1_000_000).unwrap_or(u32::MAX);
    let Some(start) = wait_for_start(
        &ports.control.1,
        cfg.loop_.silence_timeout_ms.max(handshake_ms),
        term,
    )?
    else {
        return Ok(ProcessEnd::Stopped("stopped before start".into()));
    };
    let clock = Clock {
        mode: args.mode,
        t0_ns: start.t0_ns,
        ts_ns: cfg.ts_ns(),
        budget_ns: u64::from(cfg.loop_.torque_budget_us) * 1000,
        silence_ns: u64::from(cfg.loop_.silence_timeout_ms) * 1_000_000,
        spin_ns: layout.spin_ns(),
        early_ns: layout.wake_early_ns(),
        poll: layout.poll,
        at_arrival: args.mode == LoopMode::Realtime
            && cfg.plant.apply_torque == ApplyTorque::Arrival,
        overrun: cfg.loop_.overrun,
        overrun_after_ns: cfg.overrun_after_ns(),
        paused_ns: 0,
    };
    let end = connector.connect(FromStart {
        ports: &ports,
        loop_ports,
        cfg: &cfg,
        start,
        start_at,
        clock,
        term,
        physics: PhantomData,
    })??;
    std::thread::sleep(ipc::LINGER);
    Ok(end)
}

/// The run from START, over the transport the connector picked.
struct FromStart<'r, P, S> {
    ports: &'r Ports,
    loop_ports: IpcPlant,
    cfg: &'r RunConfig,
    start: ControlMsg,
    start_at: S,
    clock: Clock,
    term: &'r AtomicBool,
    physics: PhantomData<fn() -> P>,
}

impl<P: Physics, S: FnOnce(Vec3) -> Result<P>> OverTransport for FromStart<'_, P, S> {
    type Output = Result<ProcessEnd>;

    fn run<T: Transport>(self, transport: T) -> Result<ProcessEnd> {
        let Self {
            ports,
            loop_ports,
            cfg,
            start,
            start_at,
            mut clock,
            term,
            physics: _,
        } = self;
        let mut link = transport.plant(loop_ports, clock.mode);
        link.connect()?;
        ipc::connect_now(&[&ports.telemetry, &ports.from_controller])?;
        let physics = start_at(Vec3::from(start.q0)).context("initial configuration")?;
        let mut side = PlantSide::new(physics, cfg, start.ticks);
        let end = match run_loop(ports, &mut link, &mut side, &mut clock, cfg, term)? {
            Some(stop) => end_run(ports, &mut link, &mut side, &clock, cfg, stop),
            // No DONE message: the final state and the exit status say it, and the
            // controller's ports are already going away (a send now would race their teardown).
            None => ProcessEnd::Completed,
        };
        link.finish();
        Ok(end)
    }
}

/// Ticks 0..=N, then the final state N + 1. Some(stop) if the loop ended early.
fn run_loop<P: Physics, T: PlantTransport>(
    ports: &Ports,
    link: &mut T,
    side: &mut PlantSide<P>,
    clock: &mut Clock,
    cfg: &RunConfig,
    term: &AtomicBool,
) -> Result<Option<LoopStop>> {
    // Until when the controller polls for the next state (its last reply's declaration).
    let mut ctrl_poll_until = 0;
    loop {
        let k = side.tick();
        let Woke { deadline, wake } = clock.wake(k);
        let why = if stop_requested(&ports.control.1) {
            Some(STOPPED)
        } else if term.load(Ordering::Relaxed) {
            Some("stopped by SIGTERM")
        } else {
            None
        };
        if let Some(why) = why {
            return Ok(Some(LoopStop {
                tick: k,
                cause: why.into(),
                kind: ControlKind::Stopped,
                last_deadline_ns: deadline,
            }));
        }
        if let Some(late) = clock.overrun_fault(Woke { deadline, wake }) {
            return Ok(Some(LoopStop {
                tick: k,
                cause: format!(
                    "overrun: the plant process woke {:.3} ms late for tick {k} (bound {:.3} ms, overrun = \"fault\"): the host did not run it",
                    late as f64 * 1e-6,
                    clock.overrun_after_ns as f64 * 1e-6
                ),
                kind: ControlKind::Overrun,
                last_deadline_ns: deadline,
            }));
        }
        let mut msg = match side.try_state() {
            Ok(msg) => msg,
            Err(stop) => return Ok(Some(loop_stop(stop, deadline))),
        };
        msg.t_deadline_ns = deadline;
        msg.t_wake_ns = wake;
        msg.t_publish_ns = rt::now_ns();
        let until = match clock.mode {
            // The budget runs from the state's publication, not from the deadline: after a late
            // wake the controller still gets its chance, instead of being starved (it runs below
            // the plant on the same CPU) while the plant races through its backlog.
            LoopMode::Realtime => msg.t_publish_ns + clock.budget_ns,
            _ => msg.t_publish_ns + clock.silence_ns,
        };
        msg.t_poll_until_ns = (msg.t_publish_ns + clock.spin_ns).min(until);
        link.send_state(msg, ctrl_poll_until)?;
        if msg.flags & wire::STATE_FINAL != 0 {
            return Ok(None);
        }
        let reply = match wait_torque(
            link,
            &ports.from_controller,
            k,
            (msg.t_publish_ns, msg.t_poll_until_ns, until),
            clock.poll,
            side,
        )? {
            Awaited::Reply(r) => Some(r),
            Awaited::Nothing => None,
            Awaited::ControllerError(cause) => {
                return Ok(Some(LoopStop {
                    tick: k,
                    cause,
                    kind: ControlKind::Fault,
                    last_deadline_ns: deadline,
                }));
            }
        };
        ctrl_poll_until = reply.map_or(0, |r| r.msg.t_poll_until_ns);
        let arrival = match reply {
            // The reply acts on the physics when it became visible: its (trusted) publish time,
            // mapped into simulated time as an offset from the tick's deadline.
            Some(r) if clock.at_arrival => {
                Arrival::ReplyAfter(r.msg, r.stamp_ns.saturating_sub(deadline))
            }
            Some(r) => Arrival::Reply(r.msg),
            None if clock.mode != LoopMode::Realtime => {
                // A controller that saw STOP before this tick's state stops without answering
                // it: then the silence is the supervisor's stop, not the controller's fault.
                let (cause, kind) = if stop_requested(&ports.control.1) {
                    (STOPPED.into(), ControlKind::Stopped)
                } else {
                    let ms = cfg.loop_.silence_timeout_ms;
                    let why = format!("controller silent: no torque for tick {k} within {ms} ms");
                    (why, ControlKind::Fault)
                };
                return Ok(Some(LoopStop {
                    tick: k,
                    cause,
                    kind,
                    last_deadline_ns: deadline,
                }));
            }
            None => Arrival::Missed,
        };
        let mut tel = match side.advance(arrival) {
            Ok(tel) => tel,
            Err(stop) => {
                // The failed interval's telemetry first (its reply's arrival: the record keeps
                // it, and the run replays), then DIVERGED.
                if let Some(t) = stop.failed_interval() {
                    let mut t = *t;
                    t.t_deadline_ns = deadline;
                    t.t_wake_ns = wake;
                    t.t_state_pub_ns = msg.t_publish_ns;
                    t.t_torque_rx_ns = reply.map_or(0, |r| r.rx_ns);
                    ports.telemetry.send_copy(t).ipc("publish telemetry")?;
                }
                return Ok(Some(loop_stop(stop, deadline)));
            }
        };
        tel.t_deadline_ns = deadline;
        tel.t_wake_ns = wake;
        tel.t_state_pub_ns = msg.t_publish_ns;
        tel.t_torque_rx_ns = reply.map_or(0, |r| r.rx_ns);
        if reply.is_some_and(|r| r.stamp_replaced) {
            tel.flags |= wire::TEL_STAMP_REPLACED;
        }
        ports.telemetry.send_copy(tel).ipc("publish telemetry")?;
    }
}

/// How the plant side's stop ends the loop, and what the plant tells the supervisor.
fn loop_stop(stop: PlantStop, last_deadline_ns: u64) -> LoopStop {
    LoopStop {
        tick: stop.tick(),
        cause: stop.cause().to_string(),
        kind: match stop {
            PlantStop::ControllerSilent { .. } => ControlKind::Fault,
            PlantStop::Diverged { .. } => ControlKind::Diverged,
            PlantStop::PlantError { .. } => ControlKind::PlantError,
        },
        last_deadline_ns,
    }
}

/// After an early stop: tell the supervisor, release the controller, and brake if the model
/// still works (keeping the clock in realtime).
fn end_run<P: Physics>(
    ports: &Ports,
    link: &mut impl PlantTransport,
    side: &mut PlantSide<P>,
    clock: &Clock,
    cfg: &RunConfig,
    stop: LoopStop,
) -> ProcessEnd {
    let LoopStop {
        tick,
        cause,
        kind,
        last_deadline_ns,
    } = stop;
    let t = tick as f64 * cfg.loop_.ts_s;
    let requested = kind == ControlKind::Stopped;
    let can_brake = kind != ControlKind::Diverged;
    let _ = ports
        .control
        .0
        .send_copy(ControlMsg::with_text(kind, Sender::Plant, tick, &cause));
    // Release the controller (it may be blocked waiting for a state): the run is over.
    let mut last = side.final_state(tick);
    last.t_publish_ns = rt::now_ns();
    let _ = link.send_state(last, 0);
    let end = |why: String| {
        if requested {
            ProcessEnd::Stopped(why)
        } else {
            ProcessEnd::Fault(format!("fault at tick {tick}: {why}"))
        }
    };
    if !can_brake {
        return end(format!("t = {t:.4} s: {cause}; no safe stop possible"));
    }
    let damping = cfg.faults.brake_damping_nm_s;
    match safe_stop(ports, side, clock, cfg, tick, last_deadline_ns) {
        Ok(speed) => end(format!(
            "t = {t:.4} s: {cause}; then braked for {} ms (τ = G(q) − {damping} q̇): safe stop, {}",
            cfg.faults.safe_stop_ms,
            match speed {
                Ok(v) => format!("max |q̇| = {v:.3} rad/s"),
                Err(e) => format!("the speed after it unknown ({e})"),
            }
        )),
        Err(e) => end(format!("t = {t:.4} s: {cause}; the safe stop failed: {e}")),
    }
}

/// The drives brake (τ = G(q) − D q̇) for `safe_stop_ms`; returns the final max |q̇| (rad/s), or
/// why the plant cannot say it (its truth failed).
fn safe_stop<P: Physics>(
    ports: &Ports,
    side: &mut PlantSide<P>,
    clock: &Clock,
    cfg: &RunConfig,
    tick: u64,
    last_deadline_ns: u64,
) -> Result<Result<f64, String>, String> {
    let stop_ticks = (f64::from(cfg.faults.safe_stop_ms) * 1e-3 / cfg.loop_.ts_s).round() as u64;
    for i in 1..=stop_ticks {
        if clock.mode == LoopMode::Realtime {
            rt::wake_at_ns(last_deadline_ns + i * clock.ts_ns, clock.early_ns);
        }
        let mut tel = side.brake(tick + i, cfg.faults.brake_damping_nm_s)?;
        tel.t_wake_ns = rt::now_ns();
        let _ = ports.telemetry.send_copy(tel);
    }
    Ok(side.plant().sample().map(|s| s.qd.amax()))
}

/// The cause of a loop the supervisor ended.
const STOPPED: &str = "stopped by the supervisor (STOP)";

/// Whether STOP came on the supervisor's control service (the only one the plant reads; only the
/// supervisor can publish there).
fn stop_requested(sub: &ControlIn) -> bool {
    while let Ok(Some(m)) = sub.receive() {
        if m.kind() == Some(ControlKind::Stop) {
            return true;
        }
    }
    false
}

/// Polls the control channel for START (1 ms steps) up to `timeout_ms`; None on STOP or SIGTERM.
fn wait_for_start(
    sub: &ControlIn,
    timeout_ms: u32,
    term: &AtomicBool,
) -> Result<Option<ControlMsg>> {
    let end = rt::now_ns() + u64::from(timeout_ms) * 1_000_000;
    while rt::now_ns() < end {
        while let Some(m) = sub.receive().ipc("receive control")? {
            match m.kind() {
                Some(ControlKind::Start) => return Ok(Some(m)),
                Some(ControlKind::Stop) => return Ok(None),
                _ => {}
            }
        }
        if term.load(Ordering::Relaxed) {
            return Ok(None);
        }
        std::thread::sleep(std::time::Duration::from_millis(1));
    }
    bail!("no START from the supervisor within {timeout_ms} ms")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn realtime_clock(overrun: Overrun) -> Clock {
        Clock {
            mode: LoopMode::Realtime,
            t0_ns: 1_000_000,
            ts_ns: 300_000,
            budget_ns: 150_000,
            silence_ns: 2_000_000_000,
            spin_ns: 0,
            early_ns: 0,
            poll: Poll::Spin,
            at_arrival: true,
            overrun,
            overrun_after_ns: 300_000,
            paused_ns: 0,
        }
    }

    /// With `stretch`, a wake beyond the bound moves the deadline to the wake (simulated time
    /// pauses for the stall); within the bound, and with the other policies, the deadline stays.
    #[test]
    fn stretch_moves_the_deadline_of_a_wake_beyond_the_bound_to_the_wake() {
        let late = |ns: u64| Woke {
            deadline: 5_000_000,
            wake: 5_000_000 + ns,
        };
        let c = realtime_clock(Overrun::Stretch);
        assert_eq!(c.overrun_of(late(300_000)), late(300_000), "at the bound");
        assert_eq!(
            c.overrun_of(late(10_300_000)),
            Woke {
                deadline: 15_300_000,
                wake: 15_300_000
            }
        );
        assert_eq!(c.overrun_fault(late(10_300_000)), None);
        let c = realtime_clock(Overrun::CatchUp);
        assert_eq!(c.overrun_of(late(10_300_000)), late(10_300_000));
        assert_eq!(c.overrun_fault(late(10_300_000)), None);
        let c = realtime_clock(Overrun::Fault);
        assert_eq!(c.overrun_of(late(10_300_000)), late(10_300_000));
        assert_eq!(c.overrun_fault(late(300_000)), None);
        assert_eq!(c.overrun_fault(late(300_001)), Some(300_001));
        let lockstep = Clock {
            mode: LoopMode::Lockstep,
            ..realtime_clock(Overrun::Fault)
        };
        assert_eq!(lockstep.overrun_fault(late(10_300_000)), None);
    }

    /// After a stretch every later deadline keeps the moved epoch: t0 + pauses + k·Ts.
    #[test]
    fn the_epoch_stays_moved_after_a_stretch() {
        let mut c = realtime_clock(Overrun::Stretch);
        let now = rt::now_ns();
        c.t0_ns = now.saturating_sub(10 * c.ts_ns + 5_000_000);
        let k = 10;
        let w = c.wake(k);
        assert_eq!(w.deadline, w.wake, "woke ≈ 5 ms late: stretched");
        assert_eq!(c.paused_ns, w.deadline - (c.t0_ns + k * c.ts_ns));
        let next = c.t0_ns + c.paused_ns + (k + 1) * c.ts_ns;
        assert_eq!(next, w.deadline + c.ts_ns);
    }
}
