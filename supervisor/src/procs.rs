//! The process modes: one `deltaloop-plant` + `deltaloop-controller` pair per law, over iceoryx2.
//!
//! [`run_law`] goes through four phases: spawn the pair (found next to the supervisor's own
//! executable), the handshake (READY from both, the joint reference to the controller as one
//! slice sample, ARMED, START), observe (drain large queues every millisecond; never notify or
//! wait on the loop) until both children exit, and classify how they ended. Then the observed
//! streams go through the same [`Recorder`] the in-process loop fills, so every row and metric
//! comes from the same code.

use crate::record::{Fault, LawRun, Recorder};
use crate::study::Study;
use crate::timing::Timing;
use anyhow::{Context, Result, anyhow, bail};
use deltaloop_config::config::Layout;
use deltaloop_config::{Law, LoopMode};
use deltaloop_transport::ipc::{self, ControlPorts, IpcContext, OBSERVER_BUFFER, Svc};
use deltaloop_transport::rt;
use deltaloop_transport::wire::{
    self, ControlKind, ControlMsg, RefSample, Sender, StateMsg, TelemetryMsg, TorqueMsg,
};
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

/// What one law's process run produced.
pub struct ProcessRun {
    /// A loop fault (a child died, stalled, or the plant stopped).
    pub fault: Option<Fault>,
    /// Ctrl-C / SIGTERM stopped the run.
    pub interrupted: bool,
    /// The run id that scoped this pair's iceoryx2 services and nodes.
    pub run_id: String,
    pub run: LawRun,
    pub timing: Timing,
    /// Warnings and errors the children printed (one line each).
    pub child_messages: Vec<String>,
}

/// Files every waiting sample of `sub` into `slots` by its tick (a tick beyond `slots` is dropped).
fn file_by_tick<T>(sub: &Subscriber<Svc, T, ()>, slots: &mut [Option<T>], what: &str) -> Result<()>
where
    T: wire::Ticked + Copy + std::fmt::Debug + ZeroCopySend,
{
    while let Some(s) = sub.receive().ipc(what)? {
        if let Some(slot) = slots.get_mut(s.payload().tick() as usize) {
            *slot = Some(*s.payload());
        }
    }
    Ok(())
}

/// How messages name a process.
fn role(who: Sender) -> &'static str {
    match who {
        Sender::Plant => "plant",
        Sender::Controller => "controller",
        Sender::Supervisor => "supervisor",
    }
}

/// Where the child executables are: next to the running one.
pub fn exe_dir() -> Result<PathBuf> {
    let exe = std::env::current_exe().context("cannot locate the deltaloop executable")?;
    Ok(exe.parent().map(Path::to_path_buf).unwrap_or_default())
}

/// A run id unique on this machine: pid, a per-process counter and the clock.
pub fn new_run_id() -> String {
    static N: AtomicU64 = AtomicU64::new(0);
    format!(
        "{:x}-{:x}-{:x}",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed),
        rt::now_ns() & 0xffff_ffff
    )
}

/// Kills and reaps a child on drop, so no process outlives the run, whatever happens.
struct Reaped(Option<Child>, Sender);

impl Reaped {
    fn exited(&mut self) -> Option<std::process::ExitStatus> {
        self.0.as_mut().and_then(|c| c.try_wait().ok().flatten())
    }
}

impl Drop for Reaped {
    fn drop(&mut self) {
        if let Some(mut c) = self.0.take() {
            if c.try_wait().ok().flatten().is_none() {
                // Ask politely first; then make sure.
                // SAFETY: sending SIGTERM to our own child's pid.
                unsafe { libc::kill(c.id() as i32, libc::SIGTERM) };
                for _ in 0..200 {
                    if c.try_wait().ok().flatten().is_some() {
                        return;
                    }
                    std::thread::sleep(Duration::from_millis(5));
                }
                let _ = c.kill();
            }
            let _ = c.wait();
        }
    }
}

fn spawn(exe: &Path, args: &[String], log: &Path, who: Sender) -> Result<Reaped> {
    let err =
        std::fs::File::create(log).with_context(|| format!("cannot create {}", log.display()))?;
    let mut cmd = Command::new(exe);
    cmd.args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(err);
    // The terminal's Ctrl-C and hang-up reach the whole process group, and may come before the
    // child has set up its own signal handling: it starts with both ignored (kept across exec),
    // and the supervisor stops it in order.
    // SAFETY: signal() is async-signal-safe; nothing else runs between fork and exec.
    unsafe {
        use std::os::unix::process::CommandExt;
        cmd.pre_exec(|| {
            libc::signal(libc::SIGINT, libc::SIG_IGN);
            libc::signal(libc::SIGHUP, libc::SIG_IGN);
            Ok(())
        });
    }
    let child = cmd
        .spawn()
        .with_context(|| format!("cannot start {} (expected next to deltaloop: build all binaries with `cargo build --release`)", exe.display()))?;
    Ok(Reaped(Some(child), who))
}

fn read_log(path: &Path) -> Vec<String> {
    std::fs::read_to_string(path)
        .unwrap_or_default()
        .lines()
        .filter(|l| !l.trim().is_empty())
        .map(str::to_string)
        .collect()
}

/// The supervisor's ports: observers of the three loop streams, the control channel, and the
/// reference publisher.
struct Observer {
    state: Subscriber<Svc, StateMsg, ()>,
    torque: Subscriber<Svc, TorqueMsg, ()>,
    telemetry: Subscriber<Svc, TelemetryMsg, ()>,
    control: ControlPorts,
    reference: Publisher<Svc, [RefSample], ()>,
    _node: Node<Svc>,
}

impl Observer {
    fn open(run_id: &str, reference_len: usize) -> Result<Self> {
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
            control: ipc::control_ports(&node, run_id)?,
            reference: ipc::reference(&node, run_id)?
                .publisher_builder()
                .initial_max_slice_len(reference_len)
                .create()
                .ipc("reference publisher")?,
            _node: node,
        })
    }
}

/// The two children of one run and their stderr logs.
struct Pair {
    plant: Reaped,
    controller: Reaped,
    logs: Logs,
}

/// The children's stderr logs.
#[derive(Clone)]
struct Logs {
    plant: PathBuf,
    controller: PathBuf,
}

impl Logs {
    /// Every non-empty line both children printed.
    fn messages(&self) -> Vec<String> {
        let mut m = read_log(&self.plant);
        m.extend(read_log(&self.controller));
        m
    }
}

impl Pair {
    /// Starts both children with the run id, the resolved config and the mode.
    fn spawn(run_id: &str, law: Law, mode: LoopMode, run_dir: &Path) -> Result<Self> {
        let exe = exe_dir()?;
        let common = vec![
            "--run-id".to_string(),
            run_id.to_string(),
            "--config".into(),
            run_dir.join("config.toml").display().to_string(),
            "--mode".into(),
            mode.name().into(),
        ];
        let plant_log = run_dir.join(format!("{law}.plant.log"));
        let ctrl_log = run_dir.join(format!("{law}.controller.log"));
        let plant = spawn(
            &exe.join("deltaloop-plant"),
            &common,
            &plant_log,
            Sender::Plant,
        )?;
        let mut ctrl_args = common;
        ctrl_args.extend(["--law".to_string(), law.name().to_string()]);
        let controller = spawn(
            &exe.join("deltaloop-controller"),
            &ctrl_args,
            &ctrl_log,
            Sender::Controller,
        )?;
        Ok(Self {
            plant,
            controller,
            logs: Logs {
                plant: plant_log,
                controller: ctrl_log,
            },
        })
    }

    /// Fails, with the children's stderr, if either child has exited.
    fn check_alive(&mut self) -> Result<()> {
        for child in [&mut self.plant, &mut self.controller] {
            if let Some(status) = child.exited() {
                let who = role(child.1);
                bail!(
                    "{who} exited before the run started ({status}): {}",
                    self.logs.messages().join(" | ")
                );
            }
        }
        Ok(())
    }
}

/// Polls the control channel until `done` says a handshake step is complete (Ok(true)), failing
/// (with the children's stderr) if a child exits first or the handshake timeout passes. Ok(false)
/// if Ctrl-C / SIGTERM / SIGHUP arrived first.
fn await_control(
    obs: &Observer,
    pair: &mut Pair,
    step: &str,
    done: &mut dyn FnMut(&ControlMsg) -> bool,
) -> Result<bool> {
    let deadline = rt::now_ns() + ipc::HANDSHAKE_TIMEOUT_NS;
    loop {
        while let Some(m) = obs.control.1.receive().ipc("receive control")? {
            if done(m.payload()) {
                return Ok(true);
            }
        }
        if crate::signals::interrupted() {
            return Ok(false);
        }
        pair.check_alive()?;
        if rt::now_ns() > deadline {
            bail!(
                "{step} did not happen within {} s: {}",
                ipc::HANDSHAKE_TIMEOUT_NS / 1_000_000_000,
                pair.logs.messages().join(" | ")
            );
        }
        std::thread::sleep(Duration::from_micros(200));
    }
}

/// READY from both children, the reference to the controller, ARMED from it. Ok(false) if the
/// run was interrupted first.
fn handshake(obs: &Observer, pair: &mut Pair, study: &Study) -> Result<bool> {
    let (mut plant_ready, mut ctrl_ready) = (false, false);
    let ready = await_control(
        obs,
        pair,
        "the plant/controller pair reporting ready",
        &mut |m| {
            match (m.kind(), m.sender()) {
                (Some(ControlKind::Ready), Some(Sender::Plant)) => plant_ready = true,
                (Some(ControlKind::Ready), Some(Sender::Controller)) => ctrl_ready = true,
                _ => {}
            }
            plant_ready && ctrl_ready
        },
    )?;
    if !ready {
        return Ok(false);
    }
    let rows = &study.reference.rows;
    let sample = obs
        .reference
        .loan_slice_uninit(rows.len())
        .ipc("loan reference")?;
    let sample = sample.write_from_fn(|k| {
        let j = &rows[k].joint;
        RefSample {
            q: j.q.into(),
            qd: j.qd.into(),
            qdd: j.qdd.into(),
        }
    });
    sample.send().ipc("send reference")?;
    await_control(obs, pair, "the controller taking the reference", &mut |m| {
        m.kind() == Some(ControlKind::Armed)
    })
}

/// The three loop streams as the supervisor saw them, indexed by tick (None: not seen), and what
/// the plant said on the control channel.
struct Streams {
    states: Vec<Option<StateMsg>>,
    torques: Vec<Option<TorqueMsg>>,
    tels: Vec<Option<TelemetryMsg>>,
    /// The plant's FAULT: it stopped the loop at this tick (and braked).
    plant_fault: Option<Fault>,
    /// The plant's DIVERGED: its model failed at this tick.
    diverged: Option<Fault>,
}

impl Streams {
    fn new(len: usize) -> Self {
        Self {
            states: vec![None; len],
            torques: vec![None; len],
            tels: vec![None; len],
            plant_fault: None,
            diverged: None,
        }
    }

    /// Takes everything waiting on the observer's ports.
    fn drain(&mut self, obs: &Observer) -> Result<()> {
        file_by_tick(&obs.state, &mut self.states, "observe state")?;
        file_by_tick(&obs.torque, &mut self.torques, "observe torque")?;
        file_by_tick(&obs.telemetry, &mut self.tels, "observe telemetry")?;
        while let Some(m) = obs.control.1.receive().ipc("receive control")? {
            let m = m.payload();
            let fault = || Fault {
                tick: m.tick,
                cause: m.text(),
            };
            match m.kind() {
                Some(ControlKind::Diverged) if self.diverged.is_none() => {
                    self.diverged = Some(fault())
                }
                Some(ControlKind::Fault) if self.plant_fault.is_none() => {
                    self.plant_fault = Some(fault())
                }
                _ => {}
            }
        }
        Ok(())
    }
}

/// How the observed run ended.
struct Ending {
    plant: Option<ExitStatus>,
    controller: Option<ExitStatus>,
    /// When the first child exited while the other still ran, and which.
    first_exit: Option<(u64, Sender)>,
    /// The supervisor sent STOP (Ctrl-C / SIGTERM).
    interrupted: bool,
}

/// Observes until both children exit (or the bounded waits after a STOP or one child's exit run
/// out), filing every message by tick.
fn observe(
    obs: &Observer,
    pair: &mut Pair,
    study: &Study,
    streams: &mut Streams,
) -> Result<Ending> {
    let cfg = &study.config;
    let n = study.reference.n as u64;
    let ts_ns = (cfg.loop_.ts_s * 1e9).round() as u64;
    // Bounded waits: after STOP, or after one child exits early, the other gets the safe stop
    // (plus the silence timeout for the plant to notice a dead controller), then it is stopped.
    // The overall limit leaves room for the whole safe stop too (regression: a 60 s safe stop
    // was cut off after 14 s, and the plant's reason with it).
    let silence_ns = u64::from(cfg.loop_.silence_timeout_ms) * 1_000_000;
    let grace_ns = u64::from(cfg.faults.safe_stop_ms) * 1_000_000 + 2_000_000_000;
    let expected_ns = (n + 2) * ts_ns * 20 + 10_000_000_000;
    let give_up = rt::now_ns() + expected_ns.max(silence_ns * 3) + silence_ns + grace_ns;
    let mut stop_sent: Option<u64> = None;
    let mut first_exit: Option<(u64, Sender)> = None;
    loop {
        streams.drain(obs)?;
        let (p, c) = (pair.plant.exited(), pair.controller.exited());
        let now = rt::now_ns();
        if first_exit.is_none() {
            first_exit = match (p.is_some(), c.is_some()) {
                (false, true) => Some((now, Sender::Controller)),
                (true, false) => Some((now, Sender::Plant)),
                _ => None,
            };
        }
        if p.is_some() && c.is_some() {
            break;
        }
        if crate::signals::interrupted() && stop_sent.is_none() {
            let _ = obs
                .control
                .0
                .send_copy(ControlMsg::new(ControlKind::Stop, Sender::Supervisor));
            stop_sent = Some(now);
        }
        let waited_out = match first_exit {
            // The plant is gone. If it exited by itself it released the controller with a final
            // state: give the controller 1 s to finish and say why. If it was killed by a signal
            // nothing will release the controller: stop it now.
            Some((t, Sender::Plant)) => {
                use std::os::unix::process::ExitStatusExt;
                let killed = p.is_some_and(|s| s.signal().is_some());
                now > t + if killed { 20_000_000 } else { 1_000_000_000 }
            }
            // A dead controller: the plant notices, holds, brakes, and exits by itself.
            Some((t, _)) => now > t + silence_ns + grace_ns,
            None => false,
        };
        if waited_out || stop_sent.is_some_and(|t| now > t + grace_ns) || now > give_up {
            break;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    streams.drain(obs)?;
    Ok(Ending {
        plant: pair.plant.exited(),
        controller: pair.controller.exited(),
        first_exit,
        interrupted: stop_sent.is_some(),
    })
}

/// Runs `law` over the study with a real process pair. `run_dir` holds the resolved config the
/// children read and receives their stderr logs and `<law>.timing.csv`.
pub fn run_law(study: &Study, law: Law, mode: LoopMode, run_dir: &Path) -> Result<ProcessRun> {
    let cfg = &study.config;
    let Some(layout) = mode.layout(cfg) else {
        bail!("mode {mode} runs no processes");
    };
    // A full /dev/shm would kill a child with SIGBUS mid-set-up: say so up front instead.
    if let Some(free) = ipc::shm_free_bytes() {
        ipc::check_shm(ipc::shm_needed_bytes(study.reference.rows.len()), free)
            .map_err(|e| anyhow!(e))?;
    }
    let rid = new_run_id();
    let obs = Observer::open(&rid, study.reference.rows.len())?;
    let mut pair = Pair::spawn(&rid, law, mode, run_dir)?;
    let ready = match handshake(&obs, &mut pair, study) {
        Ok(r) => r,
        Err(e) => {
            // A child that died during set-up leaves a half-created node: remove it now.
            drop(pair);
            drop(obs);
            let removed = ipc::remove_dead_nodes();
            return Err(if removed.is_empty() {
                e
            } else {
                anyhow!(
                    "{e:#}; removed the iceoryx2 resources of the {} dead node(s) it left",
                    removed.len()
                )
            });
        }
    };
    if !ready {
        return Ok(stopped_before_start(&obs, pair, law, study, rid));
    }

    let sched_warnings = rt::apply(&rt::Sched {
        core: Layout::cpu(layout.supervisor_cpu),
        fifo_priority: 0,
        lock_memory: false,
    });
    let n = study.reference.n as u64;
    // Allocate (and touch) everything the observer fills before START, not after: for a long run
    // that takes seconds, during which the loop would overflow the observer's queues (regression:
    // a 10-minute lockstep run lost its first 32 k ticks; an hour-long realtime run, all of them).
    let mut streams = Streams::new(n as usize + 2);
    let mut start = ControlMsg::new(ControlKind::Start, Sender::Supervisor);
    start.ticks = n;
    start.q0 = study.reference.q0().into();
    // Both children poll for START every ≤ 1 ms: tick 0 comes 10 ms after it.
    start.t0_ns = rt::now_ns() + 10_000_000;
    let steal_before = crate::timing::steal_jiffies();
    obs.control.0.send_copy(start).ipc("send START")?;

    let ending = observe(&obs, &mut pair, study, &mut streams)?;
    let mut child_messages = pair.logs.messages();
    let cause = if ending.interrupted {
        None
    } else {
        fault_cause(&ending, &pair, &streams)
    };
    drop(pair);
    // A child killed by a signal leaves its iceoryx2 node behind: the surviving supervisor
    // removes it now (and says so) rather than leaving it to the next run.
    let removed = ipc::remove_dead_nodes();
    if !removed.is_empty() {
        child_messages.push(format!(
            "removed the iceoryx2 resources of {} dead node(s): {}",
            removed.len(),
            removed.join(", ")
        ));
    }
    child_messages.extend(
        sched_warnings
            .into_iter()
            .map(|w| format!("deltaloop: warning: {w}")),
    );
    write_timing_csv(&run_dir.join(format!("{law}.timing.csv")), &streams)?;
    let ts_ns = (cfg.loop_.ts_s * 1e9).round() as u64;
    let mut timing = Timing::from_streams(
        &streams.states,
        &streams.torques,
        &streams.tels,
        n,
        ts_ns,
        mode == LoopMode::Realtime,
    );
    timing.steal = crate::timing::steal_ms_between(&steal_before, &crate::timing::steal_jiffies());
    let run = record(ending.interrupted, cause.as_ref(), law, study, &streams)?;
    Ok(ProcessRun {
        fault: cause,
        interrupted: ending.interrupted,
        run_id: rid,
        run,
        timing,
        child_messages,
    })
}

/// Ctrl-C (or SIGTERM, SIGHUP) during the handshake: no START is sent; STOP releases both
/// children, which exit at once; the run holds no tick.
fn stopped_before_start(
    obs: &Observer,
    mut pair: Pair,
    law: Law,
    study: &Study,
    run_id: String,
) -> ProcessRun {
    let _ = obs
        .control
        .0
        .send_copy(ControlMsg::new(ControlKind::Stop, Sender::Supervisor));
    // A child that had not subscribed yet misses STOP: dropping the pair sends it SIGTERM.
    let end = rt::now_ns() + 200_000_000;
    while (pair.plant.exited().is_none() || pair.controller.exited().is_none())
        && rt::now_ns() < end
    {
        std::thread::sleep(Duration::from_millis(2));
    }
    // Read the logs after the children are gone, so their last lines are in.
    let logs = pair.logs.clone();
    drop(pair);
    let child_messages = logs.messages();
    let mut rec = Recorder::new(law, study.reference.n);
    rec.interrupt();
    ProcessRun {
        fault: None,
        interrupted: true,
        run_id,
        run: rec.finish(None),
        timing: Timing::default(),
        child_messages,
    }
}

/// Feeds the observed streams through the [`Recorder`], tick by tick, exactly as the in-process
/// loop feeds it.
fn record(
    interrupted: bool,
    cause: Option<&Fault>,
    law: Law,
    study: &Study,
    streams: &Streams,
) -> Result<LawRun> {
    let n = study.reference.n;
    let mut rec = Recorder::new(law, n);
    if let Some(f) = cause {
        rec.fault(f.clone());
    }
    // The last tick the supervisor saw anything of: a hole before it is a loss, not an end.
    let last_seen = (0..streams.states.len())
        .rev()
        .find(|&i| {
            streams.states[i].is_some() || streams.torques[i].is_some() || streams.tels[i].is_some()
        })
        .unwrap_or(0);
    for k in 0..=n {
        let (state, reply, tel) = (streams.states[k], streams.torques[k], streams.tels[k]);
        // A tick without telemetry never ran to its end (or the sample was lost): the loop
        // stopped here, unless the plant's telemetry says it held through a missing reply.
        let ran = tel.is_some() || reply.is_some();
        if (state.is_none() || !ran) && k < last_seen {
            // Regression: the supervisor stopped for 3 s lost part of the stream, and the run
            // was called a divergence at the first hole, dropping every good tick after it.
            rec.lost(k as u64);
            continue;
        }
        let Some(state) = state.filter(|_| ran) else {
            if interrupted {
                rec.interrupt();
                return Ok(rec.finish(None));
            }
            if cause.is_some() {
                return Ok(rec.finish(None));
            }
            let why = match &streams.diverged {
                Some(d) if d.tick as usize <= k + 1 => d.cause.clone(),
                _ => format!("the supervisor lost tick {k} of the stream"),
            };
            if k == 0 {
                return Err(anyhow!("{why}"));
            }
            rec.plant_failed(why);
            return Ok(rec.finish(None));
        };
        if !rec.tick(&state, reply.as_ref(), &study.reference.rows[k].joint.q) {
            return Ok(rec.finish(None));
        }
        rec.applied(tel.as_ref());
        if let Some(d) = &streams.diverged
            && d.tick as usize == k + 1
        {
            rec.plant_failed(d.cause.clone());
            return Ok(rec.finish(None));
        }
    }
    Ok(rec.finish(streams.states[n + 1].as_ref()))
}

/// `<law>.timing.csv`: the raw CLOCK_MONOTONIC stamps of every tick (ns) and the plant's flags,
/// so any latency can be recomputed. Empty cells: the supervisor did not see that message.
fn write_timing_csv(path: &Path, streams: &Streams) -> Result<()> {
    let (states, torques, tels) = (&streams.states, &streams.torques, &streams.tels);
    let mut w = csv::Writer::from_path(path)
        .with_context(|| format!("cannot create {}", path.display()))?;
    let named = || format!("cannot write {}", path.display());
    w.write_record([
        "k",
        "deadline_ns",
        "wake_ns",
        "state_pub_ns",
        "ctrl_rx_ns",
        "ctrl_pub_ns",
        "torque_rx_ns",
        "missed",
        "held",
        "clamped",
        "ctrl_skipped",
    ])
    .with_context(named)?;
    let opt = |v: Option<u64>| v.map_or(String::new(), |x| x.to_string());
    for k in 0..tels.len().max(states.len()) {
        let (s, t, m) = (
            states.get(k).copied().flatten(),
            torques.get(k).copied().flatten(),
            tels.get(k).copied().flatten(),
        );
        if s.is_none() && t.is_none() && m.is_none() {
            continue;
        }
        let flag = |bit: u32| opt(m.map(|m| u64::from(m.flags & bit != 0)));
        w.write_record([
            k.to_string(),
            opt(s.map(|s| s.t_deadline_ns)),
            opt(s.map(|s| s.t_wake_ns)),
            opt(s.map(|s| s.t_publish_ns)),
            opt(t.map(|t| t.t_state_rx_ns)),
            opt(t.map(|t| t.t_publish_ns)),
            opt(m.and_then(|m| (m.t_torque_rx_ns > 0).then_some(m.t_torque_rx_ns))),
            flag(wire::TEL_MISSED),
            flag(wire::TEL_HELD),
            flag(wire::TEL_CLAMPED),
            opt(t.map(|t| t.skipped)),
        ])
        .with_context(named)?;
    }
    w.flush().with_context(named)?;
    Ok(())
}

fn status_text(s: ExitStatus) -> String {
    use std::os::unix::process::ExitStatusExt;
    match (s.code(), s.signal()) {
        (_, Some(9)) => "was killed (SIGKILL)".into(),
        (_, Some(sig)) => format!("was killed by signal {sig}"),
        (Some(101), _) => "panicked (exit status 101)".into(),
        (Some(c), _) => format!("exited with status {c}"),
        _ => "exited".into(),
    }
}

/// The line of a child's log that says why it stopped: a panic's message, else its last line
/// (backtraces and warnings skipped).
fn last_line(path: &Path) -> String {
    let lines = read_log(path);
    if let Some(i) = lines.iter().position(|l| l.contains("panicked at")) {
        return format!(
            "{} {}",
            lines[i].trim(),
            lines.get(i + 1).map_or("", |l| l.trim())
        );
    }
    lines
        .into_iter()
        .rev()
        .find(|l| {
            !l.contains("warning:")
                && !l.trim_start().starts_with("at ")
                && !l.trim_start().starts_with(|c: char| c.is_ascii_digit())
                && !l.starts_with("note:")
                && !l.starts_with("stack backtrace")
        })
        .unwrap_or_default()
}

/// One line saying what went wrong, or None when both children finished normally.
/// The tick is the one the plant's FAULT message names, else the tick after its last telemetry.
fn fault_cause(ending: &Ending, pair: &Pair, streams: &Streams) -> Option<Fault> {
    let (plant, ctrl) = (ending.plant, ending.controller);
    let (plant_log, ctrl_log) = (&pair.logs.plant, &pair.logs.controller);
    let ok = |s: Option<ExitStatus>| s.is_some_and(|s| s.success());
    if ok(plant) && ok(ctrl) {
        return None;
    }
    let last_torque = streams.torques.iter().rev().flatten().next();
    let last_tel = streams
        .tels
        .iter()
        .rev()
        .flatten()
        .find(|m| m.flags & wire::TEL_SAFE_STOP == 0);
    let tick = streams
        .plant_fault
        .as_ref()
        .map_or(last_tel.map_or(0, |m| m.tick + 1), |f| f.tick);
    let mut parts = Vec::new();
    // A child still running when the supervisor stopped it is not a cause (status None).
    if ctrl.is_some() && !ok(ctrl) {
        let what = ctrl.map_or("did not exit".into(), status_text);
        let line = last_line(ctrl_log);
        parts.push(if line.is_empty() {
            format!("the controller {what}")
        } else {
            format!("the controller {what} ({line})")
        });
    }
    let line = last_line(plant_log);
    if plant.is_some() && !ok(plant) {
        let what = plant.map_or("did not exit".into(), status_text);
        parts.push(if line.is_empty() {
            format!("the plant {what}")
        } else {
            format!(
                "the plant {what}: {}",
                line.trim_start_matches("deltaloop-plant: ")
            )
        });
    }
    // The plant said why it stopped the loop (FAULT): keep that, even if it could not finish
    // (still braking when it was stopped, or its log says something else last).
    if let Some(f) = &streams.plant_fault
        && !line.contains(&f.cause)
    {
        parts.push(format!(
            "the plant stopped the loop at tick {}: {}",
            f.tick, f.cause
        ));
    }
    // How long after the dead peer's last message the supervisor saw it exit.
    if let Some((noticed, who)) = ending.first_exit {
        let last = if who == Sender::Controller {
            last_torque.map(|t| t.t_publish_ns)
        } else {
            last_tel.map(|m| m.t_wake_ns)
        };
        if let Some(t) = last {
            parts.push(format!(
                "the supervisor saw the {} exit {:.1} ms after its last message",
                role(who),
                noticed.saturating_sub(t) as f64 * 1e-6
            ));
        }
    }
    Some(Fault {
        tick,
        cause: parts.join("; "),
    })
}
