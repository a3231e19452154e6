//! The plant process (`deltaloop-plant`): runs the plant's tick ([`PlantSide`], the same every
//! mode uses) once per tick and exchanges state and torque with the controller over iceoryx2.
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

use crate::{Arrival, Physics, PlantSide, PlantStop, plant_from_config};
use anyhow::{Context, Result, bail};
use clap::Parser;
use deltaloop_config::{ApplyTorque, Overrun, Poll};
use deltaloop_config::{LoopMode, RunConfig};
use deltaloop_link::direct::{self, PlantEnd};
use deltaloop_model::Vec3;
use deltaloop_transport::args::LoopArgs;
use deltaloop_transport::exit::{self, ProcessEnd};
use deltaloop_transport::ipc::{
    self, ControlIn, ControlPorts, IpcContext, Ping, StateOut, TelemetryOut, TorqueIn, Wake,
};
use deltaloop_transport::rt;
use deltaloop_transport::wire::{self, ControlKind, ControlMsg, Sender, StateMsg, TorqueMsg};
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

/// Entry point of `deltaloop-plant`.
pub fn main() -> ExitCode {
    let args = Args::parse();
    let term = rt::child_signals();
    let end = serve(&args.run, &term, NAME, |cfg| {
        let cfg = cfg.clone();
        Ok(move |q0| Ok(plant_from_config(&cfg, q0)?))
    });
    exit::exit(NAME, end)
}

/// The plant's iceoryx2 ports.
struct Ports {
    state: StateOut,
    telemetry: TelemetryOut,
    torque: TorqueIn,
    state_ready: Ping,
    torque_ready: Wake,
    control: ControlPorts,
    /// The controller's own control service: its CONTROLLER_ERROR (its step failed) ends the
    /// loop at once instead of after the silence window.
    from_controller: ControlIn,
    /// Across two hosts, the link's socket its bridge handed on: states out and replies in go
    /// there, not through the bridge (None: iceoryx2, on one host or relayed).
    link: Option<PlantEnd>,
    _node: ipc::RunNode,
}

impl Ports {
    fn open(run_id: &str) -> Result<Self> {
        let node = ipc::node("plant", run_id)?;
        let (state, torque, state_ready, torque_ready) =
            ipc::plant_loop(&node, run_id, ipc::LOOP_BUFFER)?;
        Ok(Self {
            state,
            telemetry: ipc::telemetry(&node, run_id)?.sole_publisher("telemetry")?,
            torque,
            state_ready,
            torque_ready,
            control: ipc::control_ports(&node, run_id, Sender::Plant)?,
            from_controller: ipc::control(&node, run_id, Sender::Controller)?
                .subscriber(None, "control-controller subscriber")?,
            link: None,
            _node: node,
        })
    }

    /// Publishes a state and wakes the controller unless it declared it is polling
    /// (`ctrl_poll_until_ns`, from its last reply; 0: always wake it). On the direct path the
    /// state goes to the link's socket, and the copy here is the record's: only the final state
    /// wakes the bridge, which passes it on over its control connection.
    fn publish_state(&mut self, msg: StateMsg, ctrl_poll_until_ns: u64) -> Result<()> {
        let last = msg.flags & wire::STATE_FINAL != 0;
        if let Some(l) = &mut self.link {
            if !last {
                l.send_state(&msg)?;
            }
            self.state.send_copy(msg).ipc("publish state")?;
            if last {
                self.state_ready.notify().ipc("notify state")?;
            }
            return Ok(());
        }
        self.state.send_copy(msg).ipc("publish state")?;
        if ipc::published_needs_notify(ctrl_poll_until_ns) {
            self.state_ready.notify().ipc("notify state")?;
        }
        Ok(())
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
/// START); then the loop until the run ends, and the safe stop. `name` prefixes its messages.
pub fn serve<P, S>(
    args: &LoopArgs,
    term: &AtomicBool,
    name: &str,
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
    let mut ports = Ports::open(&args.run_id)?;
    // Across two hosts: ask the bridge beside us for the link's socket (before READY).
    let handoff = match cfg.link {
        Some(_) => direct::hello()?,
        None => None,
    };
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
    if let Some(h) = &handoff {
        let lockstep = args.mode == LoopMode::Lockstep;
        ports.link = direct::answer(h)?.map(|udp| PlantEnd::new(udp, lockstep));
    }
    ipc::connect_now(&[
        &ports.state,
        &ports.telemetry,
        &ports.torque,
        &ports.state_ready,
        &ports.from_controller,
    ])?;
    let physics = start_at(Vec3::from(start.q0)).context("initial configuration")?;
    let mut side = PlantSide::new(physics, &cfg, start.ticks);
    let mut clock = Clock {
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
    let end = match run_loop(&mut ports, &mut side, &mut clock, &cfg, term)? {
        Some(stop) => end_run(&mut ports, &mut side, &clock, &cfg, stop),
        // No DONE message: the final state and the exit status say it, and the controller's ports
        // are already going away (a send now would race their teardown).
        None => ProcessEnd::Completed,
    };
    if let (Some(h), Some(l)) = (&handoff, &ports.link) {
        direct::counts(h, &l.udp);
    }
    std::thread::sleep(ipc::LINGER);
    Ok(end)
}

/// Ticks 0..=N, then the final state N + 1. Some(stop) if the loop ended early.
fn run_loop<P: Physics>(
    ports: &mut Ports,
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
        ports.publish_state(msg, ctrl_poll_until)?;
        if msg.flags & wire::STATE_FINAL != 0 {
            return Ok(None);
        }
        let reply = match wait_torque(
            &mut *ports,
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
    ports: &mut Ports,
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
    let _ = ports.publish_state(last, 0);
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

/// Judges a reply by the controller's own send time (`stamp_ns`, from [`trusted_stamp`]), not by
/// when the plant looks: a plant that was itself preempted past the budget must not apply a reply
/// that came late (it would count a late controller as on time, and the miss statistics would
/// depend on the plant's CPU).
fn reply_verdict(m: &TorqueMsg, stamp_ns: u64, tick: u64, until_ns: u64) -> Reply {
    match m.tick.cmp(&tick) {
        std::cmp::Ordering::Equal if stamp_ns <= until_ns => Reply::Apply,
        std::cmp::Ordering::Equal | std::cmp::Ordering::Less => Reply::Late,
        std::cmp::Ordering::Greater => Reply::Ignore,
    }
}

/// The controller's publish stamp `claimed` if it can be true, else the plant's own receive time
/// `rx_ns` (all CLOCK_MONOTONIC, ns); true when it was replaced. A reply cannot have been sent
/// before the state it answers was published (`state_pub_ns`) nor after the plant received it:
/// a stamp outside that window is a peer's lie (regression: a controller that stamped its replies
/// with the state's deadline, or 0, was charged no latency and never missed its budget), and the
/// physics then rests on what the plant itself observed.
fn trusted_stamp(claimed: u64, state_pub_ns: u64, rx_ns: u64) -> (u64, bool) {
    if (state_pub_ns..=rx_ns).contains(&claimed) {
        (claimed, false)
    } else {
        (rx_ns, true)
    }
}

/// A reply the plant applies.
#[derive(Clone, Copy, Debug)]
struct Received {
    msg: TorqueMsg,
    /// When the plant took it, ns.
    rx_ns: u64,
    /// When it was published, as far as the plant can trust the controller's stamp, ns.
    stamp_ns: u64,
    /// The controller's stamp was impossible and replaced by `rx_ns`.
    stamp_replaced: bool,
}

/// How the wait for a reply ended.
enum Awaited {
    Reply(Received),
    /// No reply by the end of the wait.
    Nothing,
    /// The controller said its step failed (CONTROLLER_ERROR): no reply will come. One line.
    ControllerError(String),
}

/// Waits for τ_k until `until_ns`: polls (spinning or yielding, `poll`) until `poll_until_ns`
/// (what the state declared), then blocks on the wake-up event. The clock is read before each
/// look, so the look that precedes blocking happens at or after `poll_until_ns`
/// (docs/protocol.md §6.1). Replies judged late are
/// dropped and counted on `side`; replies for later ticks are ignored. `state_pub_ns` is when
/// state `tick` was published. Before each block, and when the wait ends empty, it looks for the
/// controller's CONTROLLER_ERROR (the controller wakes the plant after sending it).
fn wait_torque<P: Physics>(
    ports: &mut Ports,
    tick: u64,
    times: (u64, u64, u64),
    poll: Poll,
    side: &mut PlantSide<P>,
) -> Result<Awaited> {
    if let Some(link) = &mut ports.link {
        let events = (&ports.torque_ready, &ports.from_controller);
        return wait_torque_direct(link, events, tick, times, poll, side);
    }
    let (state_pub_ns, poll_until_ns, until_ns) = times;
    let (sub, listener) = (&ports.torque, &ports.torque_ready);
    loop {
        let now = rt::now_ns();
        while let Some(m) = sub.receive().ipc("receive torque")? {
            let rx_ns = rt::now_ns();
            let (stamp_ns, stamp_replaced) = trusted_stamp(m.t_publish_ns, state_pub_ns, rx_ns);
            match reply_verdict(&m, stamp_ns, tick, until_ns) {
                Reply::Apply => {
                    return Ok(Awaited::Reply(Received {
                        msg: m,
                        rx_ns,
                        stamp_ns,
                        stamp_replaced,
                    }));
                }
                Reply::Late => side.late_reply(),
                Reply::Ignore => {}
            }
        }
        if now >= until_ns {
            return Ok(controller_error(&ports.from_controller)
                .map_or(Awaited::Nothing, Awaited::ControllerError));
        }
        if now < poll_until_ns {
            rt::poll_pause(poll);
            continue;
        }
        // Drop wake-ups already seen (e.g. a late reply's), so the poll sleeps until a new one.
        listener.try_wait().ipc("drain torque events")?;
        if sub.has_samples().unwrap_or(true) {
            continue;
        }
        if let Some(why) = controller_error(&ports.from_controller) {
            return Ok(Awaited::ControllerError(why));
        }
        ipc::wait_event(listener, until_ns - now)?;
    }
}

/// [`wait_torque`] on the direct path: the replies come on the link's socket, already stamped
/// with their arrival here; the wait blocks on the socket and the wake-up event together (the
/// bridge wakes the plant for a CONTROLLER_ERROR). Replies for earlier ticks (copies that came
/// late) are counted late, as on iceoryx2; the record's copies on iceoryx2 are not for the loop.
fn wait_torque_direct<P: Physics>(
    link: &mut PlantEnd,
    (listener, from_controller): (&Wake, &ControlIn),
    tick: u64,
    (state_pub_ns, poll_until_ns, until_ns): (u64, u64, u64),
    poll: Poll,
    side: &mut PlantSide<P>,
) -> Result<Awaited> {
    // Whether the last wait saw a wake-up event: only then is there one to drain (a system call
    // saved on every other tick; a pending one makes the next wait return at once).
    let mut event = false;
    loop {
        let now = rt::now_ns();
        let (mut got, mut late) = (None, 0u64);
        link.poll(|m| {
            // The reply's stamp is when it reached this host (the kernel's); the plant took it
            // now, and the round trip counts to now, as on one host.
            let rx_ns = rt::now_ns();
            let (stamp_ns, stamp_replaced) = trusted_stamp(m.t_publish_ns, state_pub_ns, rx_ns);
            match reply_verdict(&m, stamp_ns, tick, until_ns) {
                Reply::Apply if got.is_none() => {
                    got = Some(Received {
                        msg: m,
                        rx_ns,
                        stamp_ns,
                        stamp_replaced,
                    })
                }
                Reply::Apply | Reply::Ignore => {}
                Reply::Late => late += 1,
            }
        })?;
        for _ in 0..late {
            side.late_reply();
        }
        if let Some(r) = got {
            return Ok(Awaited::Reply(r));
        }
        if now >= until_ns {
            return Ok(controller_error(from_controller)
                .map_or(Awaited::Nothing, Awaited::ControllerError));
        }
        if now < poll_until_ns {
            rt::poll_pause(poll);
            continue;
        }
        if std::mem::take(&mut event) {
            listener.try_wait().ipc("drain torque events")?;
        }
        if let Some(why) = controller_error(from_controller) {
            return Ok(Awaited::ControllerError(why));
        }
        let slice = (until_ns - now).min(link.timeout_ns(now));
        let mut fds = [
            direct::readable(&link.udp),
            deltaloop_link::udp::event(listener),
        ];
        deltaloop_link::udp::wait(&mut fds, slice)?;
        event = fds[1].revents != 0;
    }
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

/// The controller's CONTROLLER_ERROR, if it sent one, as the plant's cause: which tick, and the
/// error it quoted. Only the controller can publish on its service (one publisher slot, checked
/// by the supervisor); its other kinds are not for the plant.
fn controller_error(sub: &ControlIn) -> Option<String> {
    while let Ok(Some(m)) = sub.receive() {
        if m.kind() == Some(ControlKind::ControllerError) && m.sender() == Some(Sender::Controller)
        {
            return Some(format!(
                "the controller reported an error at tick {}: {}",
                m.tick,
                m.text()
            ));
        }
    }
    None
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

    fn reply(tick: u64, t_publish_ns: u64) -> TorqueMsg {
        TorqueMsg {
            tick,
            t_publish_ns,
            ..wire::TorqueMsg::default()
        }
    }

    fn verdict(m: &TorqueMsg, tick: u64, until_ns: u64) -> Reply {
        reply_verdict(m, m.t_publish_ns, tick, until_ns)
    }

    #[test]
    fn a_reply_in_budget_for_this_tick_is_applied() {
        assert_eq!(verdict(&reply(7, 1_000), 7, 1_000), Reply::Apply);
        assert_eq!(verdict(&reply(7, 999), 7, 1_000), Reply::Apply);
    }

    /// Regression: the plant took the controller's publish stamp as the arrival time, so a slow
    /// controller that stamped its replies with the state's deadline (or 0) was charged zero
    /// latency and never missed its budget. A stamp outside [state published, reply received]
    /// is replaced by the plant's own receive time, and the tick says so.
    #[test]
    fn regression_a_forged_publish_stamp_is_replaced_by_the_plants_receive_time() {
        // State published at 1 000, reply received at 1 400.
        assert_eq!(trusted_stamp(1_200, 1_000, 1_400), (1_200, false));
        assert_eq!(trusted_stamp(1_000, 1_000, 1_400), (1_000, false));
        assert_eq!(trusted_stamp(1_400, 1_000, 1_400), (1_400, false));
        // The deadline (before the state was published), 0, or the future: not believed.
        assert_eq!(trusted_stamp(900, 1_000, 1_400), (1_400, true));
        assert_eq!(trusted_stamp(0, 1_000, 1_400), (1_400, true));
        assert_eq!(trusted_stamp(5_000, 1_000, 1_400), (1_400, true));
        // A reply received after the budget with a stamp of 0 is late, not applied.
        let (stamp, _) = trusted_stamp(0, 1_000, 1_400);
        assert_eq!(reply_verdict(&reply(7, 0), stamp, 7, 1_150), Reply::Late);
    }

    /// Regression: a plant preempted past its budget applied the late reply it found on waking,
    /// so a controller 1 ms late was counted on time whenever the plant's CPU was busy (seen as a
    /// flaky compute-delay test without SCHED_FIFO).
    #[test]
    fn regression_reply_sent_after_the_budget_is_late_even_if_the_plant_sees_it_late_too() {
        assert_eq!(verdict(&reply(7, 1_001), 7, 1_000), Reply::Late);
    }

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

    #[test]
    fn replies_for_earlier_ticks_are_late_and_for_later_ticks_ignored() {
        assert_eq!(verdict(&reply(6, 10), 7, 1_000), Reply::Late);
        assert_eq!(verdict(&reply(8, 10), 7, 1_000), Reply::Ignore);
    }
}
