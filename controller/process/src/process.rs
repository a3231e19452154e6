//! The controller process (`deltaloop-controller`): waits for each plant state, runs the
//! controller's tick ([`ControllerSide::answer`], the same every mode uses), and answers with the
//! torque. It knows no kinematics: the joint reference arrives from the supervisor in chunks of
//! `REF_CHUNK` rows, which it copies into a fixed ring ([`RefRing`]) allocated before READY; the
//! supervisor sends the next chunk only as the loop moves on (the rule is in
//! `deltaloop_transport::ipc`), so memory stays the same however long the run. If a tick's row has
//! not arrived when the tick must be answered, the controller waits for it up to the silence
//! timeout, then ends with a fault.
//!
//! It always answers the newest state (older ones it skipped are counted in the reply). If the
//! plant is silent longer than the silence timeout, it ends with a fault. Exit codes: the table
//! in `deltaloop_transport::exit` (0 done, 2 arguments, 3 set-up, 4 fault, 5 stopped).

use crate::ControllerSide;

use crate::ring::RefRing;
use anyhow::{Result, bail};
use clap::Parser;
use deltaloop_config::{FaultInjection, Poll};
use deltaloop_config::{Law, LoopMode, RunConfig};
use deltaloop_transport::args::LoopArgs;
use deltaloop_transport::exchange::{
    Connector, ControllerTransport, IpcController, OverTransport, Transport,
};
use deltaloop_transport::exit::{self, ProcessEnd};
use deltaloop_transport::ipc::{self, ControlIn, ControlPorts, IpcContext, RefIn};
use deltaloop_transport::rt;
use deltaloop_transport::wire::{self, ControlKind, ControlMsg, RefSample, StateMsg};
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

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

/// Entry point of `deltaloop-controller`, over the transport `connector` gives at START.
pub fn main(connector: impl Connector) -> ExitCode {
    let args = Args::parse();
    let term = rt::child_signals();
    let law = args.law;
    exit::exit(
        NAME,
        serve(&args.run, &term, NAME, connector, |cfg| {
            Ok(crate::ControllerSide::from_config(cfg, law))
        }),
    )
}

/// What answers each state: the built-in law ([`ControllerSide`]), or a peer's own step (the C
/// ABI). Everything else of the process (handshake, reference ring, waits, stamps, exit) is
/// [`serve`]'s, the same for both.
pub trait Step {
    /// Tick k's reply to `state` with tick k's reference `row`: `tau`, `s`, `n_hat`, `u` (the
    /// transport sets the tick's stamps), or why the step failed (the run ends with a fault).
    fn step(&mut self, state: &StateMsg, row: &RefSample) -> Result<wire::TorqueMsg, String>;

    /// Rows ahead of the state's tick the step reads: Some(d) for a law that compensates a
    /// delay of d whole ticks (and a sub-tick part), whose [`Step::step_ahead`] gets rows k + d
    /// and k + d + 1; None (the default): [`Step::step`] with row k.
    fn lookahead(&self) -> Option<u64> {
        None
    }

    /// Tick k's reply with rows k + d (`row`) and k + d + 1 (`next`), d from
    /// [`Step::lookahead`] (each the last row past the reference's end).
    fn step_ahead(
        &mut self,
        state: &StateMsg,
        row: &RefSample,
        _next: &RefSample,
    ) -> Result<wire::TorqueMsg, String> {
        self.step(state, row)
    }

    /// What the controller calls itself, said in its READY (the run shows it beside the law);
    /// None: nothing (the built-in law, or a peer that did not say).
    fn label(&self) -> Option<&str> {
        None
    }

    /// At the loop's end: how many replies its own transport refused, and of which causes (one
    /// line); None: it refuses none of its own (the built-in law, a C peer: the plant judges).
    fn refused(&self) -> Option<(u64, String)> {
        None
    }
}

impl Step for ControllerSide {
    fn step(&mut self, state: &StateMsg, row: &RefSample) -> Result<wire::TorqueMsg, String> {
        Ok(self.answer(state, &crate::reference(row)))
    }

    fn lookahead(&self) -> Option<u64> {
        ControllerSide::lookahead(self)
    }

    fn step_ahead(
        &mut self,
        state: &StateMsg,
        row: &RefSample,
        next: &RefSample,
    ) -> Result<wire::TorqueMsg, String> {
        let (row, next) = (crate::reference(row), crate::reference(next));
        Ok(self.answer_ahead(state, &row, &next))
    }
}

/// The controller's iceoryx2 ports beside the loop's: the reference chunks and run control.
struct Ports {
    reference: RefIn,
    control: ControlPorts,
    _node: ipc::RunNode,
}

impl Ports {
    /// These ports and the loop's (which go to the transport at START).
    fn open(run_id: &str) -> Result<(Self, IpcController)> {
        let node = ipc::node("controller", run_id)?;
        let loop_ports = IpcController::open(&node, run_id)?;
        let ports = Self {
            reference: ipc::reference_subscriber(&node, run_id)?,
            control: ipc::control_ports(&node, run_id, wire::Sender::Controller)?,
            _node: node,
        };
        Ok((ports, loop_ports))
    }

    /// Sends `kind` (READY, ARMED, …) on the controller's control service.
    fn send_control(&self, kind: ControlKind) -> Result<()> {
        self.control
            .0
            .send_copy(ControlMsg::new(kind, wire::Sender::Controller))
            .ipc(format!("send {kind:?}"))?;
        Ok(())
    }
}

/// The controller process of run `args`: `make` builds what answers the states from the run's
/// config (before READY), then the handshake and the loop until the run ends, over the transport
/// `connector` picks at START (asked at set-up, before READY); `name` prefixes its warnings.
pub fn serve<S: Step>(
    args: &LoopArgs,
    term: &AtomicBool,
    name: &str,
    mut connector: impl Connector,
    make: impl FnOnce(&RunConfig) -> Result<S>,
) -> Result<ProcessEnd> {
    let cfg = RunConfig::from_file(&args.config)?;
    let Some(layout) = args.mode.layout(&cfg) else {
        bail!("mode {} has no processes", args.mode);
    };
    let mut side = make(&cfg)?;
    let (ports, loop_ports) = Ports::open(&args.run_id)?;
    connector.prepare(&cfg)?;
    // Allocated and touched before READY: the loop files rows without allocating or faulting.
    let mut ring = RefRing::new();
    rt::schedule_and_report_ready(
        &rt::Sched {
            core: layout.controller_cpu,
            priority: layout.controller_priority,
            lock_memory: layout.lock_memory,
        },
        name,
        || {
            let ready = ControlMsg::with_text(
                ControlKind::Ready,
                wire::Sender::Controller,
                0,
                side.label().unwrap_or(""),
            );
            ports
                .control
                .0
                .send_copy(ready)
                .ipc("send READY")
                .map(|_| ())
        },
    )?;
    let Some(start) = handshake(&ports, &mut ring, term)? else {
        return Ok(ProcessEnd::Stopped("stopped before start".into()));
    };
    let lp = Loop {
        cfg: &cfg,
        name,
        rows: start.ticks + 2,
        spin_ns: layout.spin_ns(),
        poll: layout.poll,
        schedule: match (args.mode, layout.controller_lead_ns()) {
            (LoopMode::Realtime, Some(lead_ns)) => Some(Schedule {
                t0_ns: start.t0_ns,
                ts_ns: cfg.ts_ns(),
                lead_ns,
                epochs: [0; EPOCHS],
                seen: 0,
            }),
            _ => None,
        },
    };
    connector.connect(FromStart {
        ports: &ports,
        loop_ports,
        lp,
        side: &mut side,
        ring: &mut ring,
        term,
    })?
}

/// The run from START, over the transport the connector picked.
struct FromStart<'r, S> {
    ports: &'r Ports,
    loop_ports: IpcController,
    lp: Loop<'r>,
    side: &'r mut S,
    ring: &'r mut RefRing,
    term: &'r AtomicBool,
}

impl<S: Step> OverTransport for FromStart<'_, S> {
    type Output = Result<ProcessEnd>;

    fn run<T: Transport>(self, transport: T) -> Result<ProcessEnd> {
        let Self {
            ports,
            loop_ports,
            mut lp,
            side,
            ring,
            term,
        } = self;
        let mut link = transport.controller(loop_ports);
        link.connect()?;
        let end = answer_states(ports, &mut link, &mut lp, side, ring, term);
        link.finish();
        if let Some((n, why)) = side.refused().filter(|(n, _)| *n > 0) {
            let mut m = ControlMsg::with_text(
                ControlKind::RepliesRefused,
                wire::Sender::Controller,
                0,
                &why,
            );
            m.ticks = n;
            if let Err(e) = ports.control.0.send_copy(m) {
                eprintln!("{}: cannot say the refused replies: {e:?}", lp.name);
            }
        }
        std::thread::sleep(ipc::LINGER);
        end
    }
}

/// The handshake: file the chunks the supervisor sends before START, report ARMED once tick 0's
/// row is there, and wait for START (filing the rest of the first chunks meanwhile, so the loop
/// starts with them in the ring). Returns START; None if the supervisor stopped the run first
/// (STOP or SIGTERM).
fn handshake(ports: &Ports, ring: &mut RefRing, term: &AtomicBool) -> Result<Option<ControlMsg>> {
    let end = rt::now_ns() + ipc::START_TIMEOUT_NS;
    while ring.get(0).is_none() {
        drain_reference(&ports.reference, ring)?;
        if drain_control(&ports.control.1)?.stop || term.load(Ordering::Relaxed) {
            return Ok(None);
        }
        if rt::now_ns() > end {
            bail!(
                "no reference from the supervisor within {} s",
                ipc::START_TIMEOUT_NS / 1_000_000_000
            );
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    ports.send_control(ControlKind::Armed)?;
    loop {
        drain_reference(&ports.reference, ring)?;
        let control = drain_control(&ports.control.1)?;
        if control.stop || term.load(Ordering::Relaxed) {
            return Ok(None);
        }
        if control.start.is_some() {
            return Ok(control.start);
        }
        if rt::now_ns() > end {
            bail!(
                "no START from the supervisor within {} s",
                ipc::START_TIMEOUT_NS / 1_000_000_000
            );
        }
        std::thread::sleep(Duration::from_micros(200));
    }
}

/// What the loop runs with.
struct Loop<'c> {
    cfg: &'c RunConfig,
    /// The process's name, for its warnings.
    name: &'c str,
    /// Rows of the reference, N + 2 (ticks 0..=N + 1), from START.
    rows: u64,
    /// Busy-poll time before blocking on the state wake-up, ns (with a schedule: past the
    /// deadline).
    spin_ns: u64,
    /// Between looks for the state: spin, or yield to a plant on this CPU.
    poll: Poll,
    /// Realtime with `controller_wake_early_us`: sleep to just before each deadline.
    schedule: Option<Schedule>,
}

/// The plant's clock as START gave it, and as its states move it: the controller sleeps until
/// `lead_ns` before each deadline t0 + k·Ts and polls for the state from there.
struct Schedule {
    t0_ns: u64,
    ts_ns: u64,
    lead_ns: u64,
    /// The epochs (deadline − k·Ts, ns) the last [`EPOCHS`] states said, a ring.
    epochs: [u64; EPOCHS],
    seen: usize,
}

/// States whose epochs must all have moved before the schedule follows: one late state (a link's
/// jitter spike, when its stamps were moved to this host's clock) does not move it.
const EPOCHS: usize = 8;

impl Schedule {
    /// The deadline of tick `k`, ns.
    fn deadline(&self, k: u64) -> u64 {
        self.t0_ns + k * self.ts_ns
    }
}

impl Loop<'_> {
    /// Follows the plant's clock: its epoch moves later when simulated time pauses for a stall of
    /// the plant's own process (`overrun = "stretch"`), and a state's deadline says where it is.
    /// Only a deadline already past when the state was taken (`rx_ns`) moves it: a plant's stamp
    /// cannot make the controller sleep past the states it publishes. Later only once [`EPOCHS`]
    /// states in a row say so (one late state does not move it); earlier at once, since waking
    /// sooner costs only a wait: across the link START's t0 arrives late by the control
    /// connection's latency (regression: a far controller whose t0 was 180–290 µs late slept past
    /// every other state and answered only the next, half the ticks missed).
    fn follow(&mut self, state: &StateMsg, rx_ns: u64) {
        if let Some(s) = &mut self.schedule
            && state.t_deadline_ns <= rx_ns
        {
            let epoch = state
                .t_deadline_ns
                .saturating_sub(state.tick.saturating_mul(s.ts_ns));
            s.epochs[s.seen % EPOCHS] = epoch;
            s.seen += 1;
            if epoch < s.t0_ns {
                s.t0_ns = epoch;
            } else if s.seen >= EPOCHS {
                let moved = s.epochs.iter().copied().min().unwrap_or(0);
                s.t0_ns = s.t0_ns.max(moved);
            }
        }
    }

    /// The wait for state `k`, from `from_ns` (START for state 0, else the last reply's
    /// publication): with a schedule, sleep to `lead_ns` before its deadline and poll to `spin_ns`
    /// past the deadline, or past `from_ns` if that deadline has gone by (after a freeze the plant
    /// publishes its backlog of states back to back, and a controller that blocked on each would
    /// be woken across CPUs for every one); without one, poll `spin_ns` from `from_ns`. State 0
    /// is waited for like every later one. The poll end is what a reply declares
    /// (`t_poll_until_ns`, docs/protocol.md §6.1), never less than the last declaration.
    fn wait_for(&self, k: u64, from_ns: u64, last_poll_until: u64) -> Wait {
        let (wake_ns, until) = match &self.schedule {
            Some(s) => {
                let d = s.deadline(k);
                (Some(d.saturating_sub(s.lead_ns)), d.max(from_ns))
            }
            None => (None, from_ns),
        };
        Wait {
            wake_ns,
            poll_until_ns: (until + self.spin_ns).max(last_poll_until),
        }
    }
}

/// The loop: answer every state until the final one, the plant's silence, or a stop.
fn answer_states(
    ports: &Ports,
    link: &mut impl ControllerTransport,
    lp: &mut Loop,
    side: &mut impl Step,
    ring: &mut RefRing,
    term: &AtomicBool,
) -> Result<ProcessEnd> {
    let cfg = lp.cfg;
    let compute_delay_us = cfg.controller.compute_delay_us;
    let inject = cfg.faults.inject;
    let silence_ns = u64::from(cfg.loop_.silence_timeout_ms) * 1_000_000;
    let mut wait = lp.wait_for(0, rt::now_ns(), 0);
    // The last tick answered, and the states not newer than it that were ignored.
    let mut answered: Option<u64> = None;
    let mut stale = 0u64;
    // A controller stalled by injection plays one that is alive but mute: it waits for the
    // plant's final state (or STOP, or SIGTERM) however long that takes. Waiting out the plant's
    // own silence limit raced the plant's (both start at the same state), and on a loaded host
    // the controller's ran out first: the run ended on the controller's fault, not its silence.
    let mut stalled = false;
    let end = loop {
        let silence_ns = if stalled { u64::MAX } else { silence_ns };
        let waited = wait_state(ports, link, silence_ns, lp, &wait, term)?;
        let (state, skipped, rx) = match waited {
            Waited::State(s, skipped, rx) => (s, skipped, rx),
            Waited::Silent => {
                break ProcessEnd::PeerSilent(format!(
                    "plant silent for {} ms",
                    cfg.loop_.silence_timeout_ms
                ));
            }
            Waited::Stopped(why) => break ProcessEnd::Stopped(why.into()),
        };
        if state.flags & wire::STATE_FINAL != 0 {
            // The plant releases the controller with a final state after a STOP too: that is
            // a stop on request, not a completed run.
            break if drain_control(&ports.control.1)?.stop {
                ProcessEnd::Stopped("stopped by the supervisor (STOP)".into())
            } else {
                ProcessEnd::Completed
            };
        }
        // A state not newer than one already answered (a duplicate, or a replay of an old
        // one) gets no second answer: the plant applies one reply per tick.
        if answered.is_some_and(|a| state.tick <= a) {
            stale += 1;
            continue;
        }
        // Injected faults (drills and tests): stall = stop answering, panic = die loudly.
        match inject {
            FaultInjection::Stall(k) if state.tick >= k => {
                stalled = true;
                continue;
            }
            FaultInjection::Panic(k) if state.tick >= k => {
                panic!("injected controller panic at tick {}", state.tick)
            }
            _ => {}
        }
        if state.tick >= lp.rows {
            break ProcessEnd::Fault(format!(
                "state tick {} is beyond the reference ({} ticks)",
                state.tick, lp.rows
            ));
        }
        let silence_ms = cfg.loop_.silence_timeout_ms;
        let stepped = match side.lookahead() {
            None => match await_row(ports, ring, state.tick, silence_ms, term)? {
                Ok(r) => side.step(&state, &r),
                Err(end) => break end,
            },
            Some(d) => {
                // Rows k + d and k + d + 1, or the last row past the reference's end.
                let last = lp.rows - 1;
                let j = (state.tick + d).min(last);
                let r = match await_row(ports, ring, j, silence_ms, term)? {
                    Ok(r) => r,
                    Err(end) => break end,
                };
                let next = match await_row(ports, ring, (j + 1).min(last), silence_ms, term)? {
                    Ok(r) => r,
                    Err(end) => break end,
                };
                side.step_ahead(&state, &r, &next)
            }
        };
        let mut msg = match stepped {
            Ok(m) => m,
            Err(why) => {
                tell_plant_the_step_failed(ports, link, state.tick, &why);
                break ProcessEnd::Fault(format!("the step failed at tick {}: {why}", state.tick));
            }
        };
        msg.tick = state.tick;
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
        lp.follow(&state, rx);
        wait = lp.wait_for(state.tick + 1, msg.t_publish_ns, wait.poll_until_ns);
        msg.t_poll_until_ns = wait.poll_until_ns;
        link.send_reply(msg, state.t_poll_until_ns)?;
        answered = Some(state.tick);
        // On the plant's CPU, hand it the CPU now: the reply is taken before our bookkeeping.
        if lp.poll == Poll::Yield {
            std::thread::yield_now();
        }
        // File any chunk that arrived now, in the slack before the next state, so copying its
        // 320 KiB never delays a reply (before the next answer, as the rule needs).
        drain_reference(&ports.reference, ring)?;
    };
    if stale > 0 {
        eprintln!(
            "{}: warning: ignored {stale} state(s) whose tick was not newer than the last one answered{}",
            lp.name,
            answered.map_or(String::new(), |a| format!(" (tick {a})"))
        );
    }
    Ok(end)
}

/// Says CONTROLLER_ERROR (tick `k`, the error `why`) on the controller's control service and
/// wakes the plant, which then ends the loop at once instead of holding the last torque through
/// its silence window. Best effort: the exit code says the same if this cannot be sent.
fn tell_plant_the_step_failed(ports: &Ports, link: &impl ControllerTransport, k: u64, why: &str) {
    let m = ControlMsg::with_text(
        ControlKind::ControllerError,
        wire::Sender::Controller,
        k,
        why,
    );
    let _ = ports.control.0.send_copy(m);
    link.wake_plant();
}

/// Tick `k`'s reference row: from the ring, where it normally already is. If it is not, the
/// supervisor has fallen behind the loop: file chunks as they arrive (polling every 50 µs) for up
/// to the silence timeout, stopping early on SIGTERM or STOP. Err says how the wait ended.
fn await_row(
    ports: &Ports,
    ring: &mut RefRing,
    k: u64,
    silence_timeout_ms: u32,
    term: &AtomicBool,
) -> Result<Result<RefSample, ProcessEnd>> {
    if let Some(r) = ring.get(k) {
        return Ok(Ok(*r));
    }
    let until = rt::now_ns() + u64::from(silence_timeout_ms) * 1_000_000;
    loop {
        drain_reference(&ports.reference, ring)?;
        if let Some(r) = ring.get(k) {
            return Ok(Ok(*r));
        }
        if term.load(Ordering::Relaxed) {
            return Ok(Err(ProcessEnd::Stopped("stopped by SIGTERM".into())));
        }
        if drain_control(&ports.control.1)?.stop {
            return Ok(Err(ProcessEnd::Stopped(
                "stopped by the supervisor (STOP)".into(),
            )));
        }
        if rt::now_ns() >= until {
            return Ok(Err(ProcessEnd::Fault(format!(
                "no reference for tick {k} from the supervisor within {silence_timeout_ms} ms: it fell behind the loop"
            ))));
        }
        std::thread::sleep(Duration::from_micros(50));
    }
}

/// Copies every chunk waiting on the reference subscriber into the ring, each row under its own
/// tick, and releases the samples at once (the supervisor reuses their memory).
fn drain_reference(sub: &RefIn, ring: &mut RefRing) -> Result<()> {
    while let Some(chunk) = sub.receive().ipc("receive reference")? {
        for row in chunk.payload() {
            ring.put(row);
        }
    }
    Ok(())
}

/// How the controller waits for the next state.
struct Wait {
    /// Sleep until this time first (realtime with a schedule), ns.
    wake_ns: Option<u64>,
    /// Poll until at least this time before blocking on the wake-up event (the promise made in
    /// the last reply), ns.
    poll_until_ns: u64,
}

/// How a wait for the next state ended.
enum Waited {
    /// The newest state, how many older ones were skipped, and when it was taken (ns).
    State(StateMsg, u64, u64),
    /// No state within the silence timeout.
    Silent,
    /// STOP from the supervisor, or SIGTERM: why.
    Stopped(&'static str),
}

/// Longest single block on the wake-up event, ns: STOP sends no wake-up, so the blocked wait
/// looks at the control channel (and SIGTERM's flag) at least this often.
const BLOCK_SLICE_NS: u64 = 50_000_000;

/// Waits for the next state: sleeps until `wait.wake_ns` if set, polls (spinning or yielding,
/// `lp.poll`) until `wait.poll_until_ns` (or `lp.spin_ns` past a late wake-up), then blocks on the
/// transport's wake-ups in slices of [`BLOCK_SLICE_NS`], looking for STOP and SIGTERM between
/// them. The clock is read before each look, so the look that precedes blocking happens at or
/// after `poll_until_ns` (docs/protocol.md §6.1).
fn wait_state<T: ControllerTransport>(
    ports: &Ports,
    link: &mut T,
    silence_ns: u64,
    lp: &Loop,
    wait: &Wait,
    term: &AtomicBool,
) -> Result<Waited> {
    let mut poll_until_ns = wait.poll_until_ns;
    // Where START's t0 may come late (`START_ON_TIME`), not before the first state: it wakes the
    // controller and puts the schedule on the plant's clock ([`Loop::follow`]).
    let on_schedule = T::START_ON_TIME || lp.schedule.as_ref().is_some_and(|s| s.seen > 0);
    if let Some(t) = wait.wake_ns.filter(|_| on_schedule) {
        link.sleep_until(t)?;
        poll_until_ns = poll_after_wake(poll_until_ns, rt::now_ns(), lp.spin_ns);
    }
    let until = rt::now_ns().saturating_add(silence_ns);
    // Whether this wait has blocked once already: STOP is looked for only after a block that
    // brought no state, so the tick's normal path (one block, woken by the state) reads no
    // control message.
    let mut blocked = false;
    // Whether the last block saw a wake-up event (a transport may drain only then).
    let mut woke = false;
    loop {
        // Before the states: SIGTERM ends the loop even while states keep coming.
        if term.load(Ordering::Relaxed) {
            return Ok(Waited::Stopped("stopped by SIGTERM"));
        }
        let now = rt::now_ns();
        if let Some((s, skipped)) = link.take_state()? {
            return Ok(Waited::State(s, skipped, rt::now_ns()));
        }
        if now >= until {
            return Ok(Waited::Silent);
        }
        if now < poll_until_ns {
            rt::poll_pause(lp.poll);
            continue;
        }
        if blocked && drain_control(&ports.control.1)?.stop {
            return Ok(Waited::Stopped("stopped by the supervisor (STOP)"));
        }
        blocked = true;
        let slice = (until - now).min(BLOCK_SLICE_NS);
        woke = link.block(now, slice, std::mem::take(&mut woke))?;
    }
}

/// Until when to poll after the scheduled sleep: the promise, or `spin_ns` past the wake-up if
/// the sleep ended after the promise (the host froze this CPU, or its timer fired late), so the
/// state the plant is about to publish is taken by polling, not by a cross-CPU wake-up. On time
/// it changes nothing: the wake-up is before the deadline and the promise `spin_ns` after it.
fn poll_after_wake(promised_ns: u64, woke_ns: u64, spin_ns: u64) -> u64 {
    promised_ns.max(woke_ns + spin_ns)
}

/// What the control channel said since it was last drained.
struct Control {
    /// START (`ticks` = N, the last tick that gets a command; `t0_ns`), if it came.
    start: Option<ControlMsg>,
    /// STOP came.
    stop: bool,
}

/// Drains the supervisor's control service (only the supervisor can publish there).
fn drain_control(sub: &ControlIn) -> Result<Control> {
    let mut c = Control {
        start: None,
        stop: false,
    };
    while let Some(m) = sub.receive().ipc("receive control")? {
        match m.kind() {
            Some(ControlKind::Start) => c.start = Some(m),
            Some(ControlKind::Stop) => c.stop = true,
            _ => {}
        }
    }
    Ok(c)
}

#[cfg(test)]
mod tests {
    use super::*;

    const US: u64 = 1_000;
    /// t0 of the test schedule, ns.
    const T0: u64 = 50_000_000;

    fn realtime_loop(cfg: &RunConfig) -> Loop<'_> {
        Loop {
            cfg,
            name: NAME,
            rows: 100,
            spin_ns: 150 * US,
            poll: Poll::Spin,
            schedule: Some(Schedule {
                t0_ns: T0,
                ts_ns: 300 * US,
                lead_ns: 100 * US,
                epochs: [0; EPOCHS],
                seen: 0,
            }),
        }
    }

    fn cfg() -> RunConfig {
        RunConfig::from_toml_str("name = \"t\"\n[scenario]\npath = \"s1\"\n", None).expect("config")
    }

    #[test]
    fn on_schedule_the_controller_sleeps_to_before_the_next_deadline_and_polls_past_it() {
        let cfg = cfg();
        let lp = realtime_loop(&cfg);
        let d6 = T0 + 6 * 300 * US;
        // Tick 5 answered 4 µs after its deadline.
        let w = lp.wait_for(6, T0 + 5 * 300 * US + 4 * US, 0);
        assert_eq!(w.wake_ns, Some(d6 - 100 * US));
        assert_eq!(w.poll_until_ns, d6 + 150 * US);
    }

    /// Regression: after the host froze both CPUs, the plant published its backlog of states back
    /// to back while the controller's poll window (anchored at deadlines already gone) had closed,
    /// so it blocked and was woken across CPUs for every state, and the backlog was missed tick
    /// after tick (seen as runs of 2–5 misses in split-layout runs).
    #[test]
    fn regression_a_reply_sent_after_the_next_deadline_polls_past_the_reply_not_the_deadline() {
        let cfg = cfg();
        let lp = realtime_loop(&cfg);
        let d6 = T0 + 6 * 300 * US;
        let published = d6 + 630 * US;
        let w = lp.wait_for(6, published, 0);
        assert_eq!(w.poll_until_ns, published + 150 * US);
    }

    /// Regression (one of the two causes of tick 0's miss; the other, the lazy port connection,
    /// is checked in tests/e2e/realtime.rs): the controller waited for state 0 as lockstep does
    /// (polled 150 µs after START, then blocked), so the state published at t0 = START + 10 ms
    /// had to wake it across CPUs.
    #[test]
    fn regression_tick_0_is_waited_for_on_the_schedule_not_blocked_for() {
        let cfg = cfg();
        let lp = realtime_loop(&cfg);
        let start = T0 - 10_000 * US;
        let w = lp.wait_for(0, start, 0);
        assert_eq!(w.wake_ns, Some(T0 - 100 * US));
        assert_eq!(w.poll_until_ns, T0 + 150 * US);
        let lockstep = Loop {
            schedule: None,
            ..realtime_loop(&cfg)
        };
        let w = lockstep.wait_for(0, start, 0);
        assert_eq!((w.wake_ns, w.poll_until_ns), (None, start + 150 * US));
    }

    /// After the plant paused simulated time for its own stall (`stretch`), its deadlines are
    /// later than t0 + k·Ts: once [`EPOCHS`] states in a row say so the controller's schedule
    /// follows them; one late state (a jitter spike), a deadline in the future (no honest plant
    /// stamps one) or an earlier epoch does not move it.
    #[test]
    fn the_schedule_follows_a_stretched_plant_clock_not_one_late_state() {
        let cfg = cfg();
        let mut lp = realtime_loop(&cfg);
        let pause = 10_000 * US;
        let state = |k: u64, deadline| StateMsg {
            tick: k,
            t_deadline_ns: deadline,
            ..StateMsg::default()
        };
        let d = |k: u64| T0 + k * 300 * US;
        // One state 10 ms late among on-time ones: the schedule stays.
        for k in 0..20 {
            let late = if k == 9 { pause } else { 0 };
            lp.follow(&state(k, d(k) + late), d(k) + late + 20 * US);
        }
        assert_eq!(lp.wait_for(20, d(19), 0).wake_ns, Some(d(20) - 100 * US));
        // Simulated time paused 10 ms at tick 20: after 8 states on the moved epoch, it follows.
        for k in 20..28 {
            assert_eq!(lp.wait_for(k, d(k), 0).wake_ns, Some(d(k) - 100 * US));
            lp.follow(&state(k, d(k) + pause), d(k) + pause + 20 * US);
        }
        assert_eq!(
            lp.wait_for(28, d(27), 0).wake_ns,
            Some(d(28) + pause - 100 * US)
        );
        // A stamp from the future: ignored.
        for k in 28..40 {
            lp.follow(&state(k, d(k) + 3 * pause), d(k) + pause + 20 * US);
        }
        assert_eq!(
            lp.wait_for(40, d(39), 0).wake_ns,
            Some(d(40) + pause - 100 * US)
        );
        // An earlier epoch: followed at once (the controller only wakes sooner).
        lp.follow(&state(40, d(40)), d(40) + 20 * US);
        assert_eq!(lp.wait_for(41, d(40), 0).wake_ns, Some(d(41) - 100 * US));
    }

    /// Regression: across the link START's t0 reached the far controller late by the control
    /// connection's latency (180–290 µs here), so it slept past every other state (its own
    /// deadline was later than the plant's) and only moved later, never back: half the ticks were
    /// missed until the plant's first stall moved its epoch. The first state taken after its
    /// deadline brings the schedule back to the plant's clock.
    #[test]
    fn regression_a_start_that_came_late_does_not_hold_the_schedule_behind_the_plant() {
        let cfg = cfg();
        let mut lp = realtime_loop(&cfg);
        let late = 285 * US;
        if let Some(s) = &mut lp.schedule {
            s.t0_ns = T0 + late;
        }
        let d = |k: u64| T0 + k * 300 * US;
        let state = StateMsg {
            tick: 1,
            t_deadline_ns: d(1),
            ..StateMsg::default()
        };
        lp.follow(&state, d(1) + 40 * US);
        assert_eq!(
            lp.wait_for(2, d(1) + 41 * US, 0).wake_ns,
            Some(d(2) - 100 * US)
        );
    }

    #[test]
    fn a_late_wake_up_polls_spin_past_it_and_an_early_one_keeps_the_promise() {
        let promised = 10_000 * US;
        // On time: woke 100 µs before the deadline, the promise is 150 µs after it.
        assert_eq!(
            poll_after_wake(promised, promised - 250 * US, 150 * US),
            promised
        );
        // Woke 480 µs after the promise: poll on for spin_ns from there.
        assert_eq!(
            poll_after_wake(promised, promised + 480 * US, 150 * US),
            promised + 630 * US
        );
    }

    #[test]
    fn lockstep_polls_spin_past_each_reply_and_never_less_than_it_promised() {
        let cfg = cfg();
        let lp = Loop {
            schedule: None,
            ..realtime_loop(&cfg)
        };
        let w = lp.wait_for(6, 2_000 * US, 0);
        assert_eq!((w.wake_ns, w.poll_until_ns), (None, 2_150 * US));
        let w = lp.wait_for(6, 2_000 * US, 3_000 * US);
        assert_eq!((w.wake_ns, w.poll_until_ns), (None, 3_000 * US));
    }
}
