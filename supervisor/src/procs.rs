//! The process modes: one `deltaloop-plant` + `deltaloop-controller` pair per law, over iceoryx2.
//!
//! The supervisor creates its observer ports, spawns the pair (found next to its own executable),
//! waits for both to report READY, hands the joint reference to the controller as one slice
//! sample, sends START, and then only observes: it drains large queues every millisecond and never
//! notifies or waits on the loop. Afterwards it rebuilds the run tick by tick through the same
//! [`Recorder`] the in-process loop uses, so every metric comes from the same code.

use crate::record::{LawRun, Recorder};
use crate::study::Study;
use crate::timing::Timing;
use anyhow::{Context, Result, anyhow, bail};
use deltaloop_controller::Output;
use deltaloop_plant::{PlantSample, Vec3};
use deltaloop_protocol::config::{Layout, ProcMode};
use deltaloop_protocol::ipc::{self, OBSERVER_BUFFER};
use deltaloop_protocol::wire::{
    self, ControlMsg, RefSample, StateMsg, TelemetryMsg, TorqueMsg, control,
};
use deltaloop_protocol::{Law, rt};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

/// What one law's process run produced.
pub struct ProcessRun {
    /// A loop fault: its tick and one-line cause (a child died, stalled, or the plant stopped).
    pub fault: Option<(u64, String)>,
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
fn file_by_tick<T>(
    sub: &iceoryx2::port::subscriber::Subscriber<ipc::Svc, T, ()>,
    slots: &mut [Option<T>],
    what: &str,
) -> Result<()>
where
    T: wire::Ticked + Copy + std::fmt::Debug + iceoryx2::prelude::ZeroCopySend,
{
    while let Some(s) = sub.receive().map_err(|e| ipc::err(what)(&e))? {
        if let Some(slot) = slots.get_mut(s.payload().tick() as usize) {
            *slot = Some(*s.payload());
        }
    }
    Ok(())
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
struct Reaped(Option<Child>, &'static str);

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

fn spawn(exe: &Path, args: &[String], log: &Path, name: &'static str) -> Result<Reaped> {
    let err =
        std::fs::File::create(log).with_context(|| format!("cannot create {}", log.display()))?;
    let child = Command::new(exe)
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(err)
        .spawn()
        .with_context(|| format!("cannot start {} (expected next to deltaloop: build all binaries with `cargo build --release`)", exe.display()))?;
    Ok(Reaped(Some(child), name))
}

fn read_log(path: &Path) -> Vec<String> {
    std::fs::read_to_string(path)
        .unwrap_or_default()
        .lines()
        .filter(|l| !l.trim().is_empty())
        .map(str::to_string)
        .collect()
}

/// Runs `law` over the study with a real process pair. `run_dir` holds the resolved config the
/// children read and receives their stderr logs.
pub fn run_law(study: &Study, law: Law, mode: ProcMode, run_dir: &Path) -> Result<ProcessRun> {
    let cfg = &study.config;
    let layout = mode.layout(cfg).clone();
    let config_path = run_dir.join("config.toml");
    let rid = new_run_id();
    let node = ipc::node("supervisor", &rid)?;
    let state_sub = ipc::state(&node, &rid)?
        .subscriber_builder()
        .buffer_size(OBSERVER_BUFFER)
        .create()
        .map_err(|e| ipc::err("state observer")(&e))?;
    let torque_sub = ipc::torque(&node, &rid)?
        .subscriber_builder()
        .buffer_size(OBSERVER_BUFFER)
        .create()
        .map_err(|e| ipc::err("torque observer")(&e))?;
    let tel_sub = ipc::telemetry(&node, &rid)?
        .subscriber_builder()
        .buffer_size(OBSERVER_BUFFER)
        .create()
        .map_err(|e| ipc::err("telemetry observer")(&e))?;
    let (ctl_pub, ctl_sub) = ipc::control_ports(&node, &rid)?;
    let rows = &study.reference.rows;
    let ref_pub = ipc::reference(&node, &rid)?
        .publisher_builder()
        .initial_max_slice_len(rows.len())
        .create()
        .map_err(|e| ipc::err("reference publisher")(&e))?;

    let exe = exe_dir()?;
    let mode_arg = mode.name();
    let common = vec![
        "--run-id".to_string(),
        rid.clone(),
        "--config".into(),
        config_path.display().to_string(),
        "--mode".into(),
        mode_arg.into(),
    ];
    let plant_log = run_dir.join(format!("{law}.plant.log"));
    let ctrl_log = run_dir.join(format!("{law}.controller.log"));
    let mut plant = spawn(&exe.join("deltaloop-plant"), &common, &plant_log, "plant")?;
    let mut ctrl_args = common.clone();
    ctrl_args.extend(["--law".to_string(), law.name().to_string()]);
    let mut controller = spawn(
        &exe.join("deltaloop-controller"),
        &ctrl_args,
        &ctrl_log,
        "controller",
    )?;
    let messages = || -> Vec<String> {
        let mut m = read_log(&plant_log);
        m.extend(read_log(&ctrl_log));
        m
    };

    // Handshake steps: poll the control channel until `done` says the step is complete, failing
    // (with the children's stderr) if a child exits first or 30 s pass.
    let mut await_control = |step: &str, done: &mut dyn FnMut(&ControlMsg) -> bool| -> Result<()> {
        let deadline = rt::now_ns() + 30_000_000_000;
        loop {
            while let Some(m) = ctl_sub
                .receive()
                .map_err(|e| ipc::err("receive control")(&e))?
            {
                if done(m.payload()) {
                    return Ok(());
                }
            }
            for child in [&mut plant, &mut controller] {
                if let Some(status) = child.exited() {
                    bail!(
                        "{} exited before the run started ({status}): {}",
                        child.1,
                        messages().join(" | ")
                    );
                }
            }
            if rt::now_ns() > deadline {
                bail!(
                    "{step} did not happen within 30 s: {}",
                    messages().join(" | ")
                );
            }
            std::thread::sleep(Duration::from_micros(200));
        }
    };
    // READY from both children (ports created, scheduling applied).
    let (mut plant_ready, mut ctrl_ready) = (false, false);
    await_control("the plant/controller pair reporting ready", &mut |m| {
        match (m.kind, m.from) {
            (control::READY, control::PLANT) => plant_ready = true,
            (control::READY, control::CONTROLLER) => ctrl_ready = true,
            _ => {}
        }
        plant_ready && ctrl_ready
    })?;

    // The joint reference, one zero-copy slice sample.
    let sample = ref_pub
        .loan_slice_uninit(rows.len())
        .map_err(|e| ipc::err("loan reference")(&e))?;
    let sample = sample.write_from_fn(|k| {
        let j = &rows[k].joint;
        RefSample {
            q: j.q.into(),
            qd: j.qd.into(),
            qdd: j.qdd.into(),
        }
    });
    sample.send().map_err(|e| ipc::err("send reference")(&e))?;

    // ARMED: the controller holds (and has touched) the reference.
    await_control("the controller taking the reference", &mut |m| {
        m.kind == control::ARMED
    })?;

    let sched_warnings = rt::apply(&rt::Sched {
        core: Layout::cpu(layout.supervisor_cpu),
        fifo_priority: 0,
        lock_memory: false,
    });
    let n = study.reference.n as u64;
    let ts_ns = (cfg.loop_.ts_s * 1e9).round() as u64;
    let mut start = ControlMsg::new(control::START, control::SUPERVISOR);
    start.ticks = n;
    start.q0 = study.reference.q0().into();
    // Both children poll for START every ≤ 1 ms: tick 0 comes 10 ms after it.
    start.t0_ns = rt::now_ns() + 10_000_000;
    let steal_before = crate::timing::steal_jiffies();
    ctl_pub
        .send_copy(start)
        .map_err(|e| ipc::err("send START")(&e))?;

    // Observe until the plant is done (or failed) and both children have exited.
    let len = n as usize + 2;
    let mut states: Vec<Option<StateMsg>> = vec![None; len];
    let mut torques: Vec<Option<TorqueMsg>> = vec![None; len];
    let mut tels: Vec<Option<TelemetryMsg>> = vec![None; len];
    let mut fault: Option<(u64, String)> = None;
    let expected_ns = (n + 2) * ts_ns * 20 + 10_000_000_000;
    let give_up =
        rt::now_ns() + expected_ns.max(u64::from(cfg.loop_.silence_timeout_ms) * 3_000_000);
    let drain = |states: &mut Vec<Option<StateMsg>>,
                 torques: &mut Vec<Option<TorqueMsg>>,
                 tels: &mut Vec<Option<TelemetryMsg>>,
                 fault: &mut Option<(u64, String)>|
     -> Result<()> {
        file_by_tick(&state_sub, states, "observe state")?;
        file_by_tick(&torque_sub, torques, "observe torque")?;
        file_by_tick(&tel_sub, tels, "observe telemetry")?;
        while let Some(m) = ctl_sub
            .receive()
            .map_err(|e| ipc::err("receive control")(&e))?
        {
            if m.payload().kind == control::DIVERGED && fault.is_none() {
                *fault = Some((m.payload().tick, m.payload().text()));
            }
        }
        Ok(())
    };
    // Bounded waits: after STOP, or after one child exits early, the other gets the safe stop
    // (plus the silence timeout for the plant to notice a dead controller), then it is stopped.
    let silence_ns = u64::from(cfg.loop_.silence_timeout_ms) * 1_000_000;
    let grace_ns = u64::from(cfg.faults.safe_stop_ms) * 1_000_000 + 2_000_000_000;
    let mut stop_sent: Option<u64> = None;
    let mut first_exit: Option<(u64, &'static str)> = None;
    loop {
        drain(&mut states, &mut torques, &mut tels, &mut fault)?;
        let (p, c) = (plant.exited(), controller.exited());
        let now = rt::now_ns();
        if first_exit.is_none() {
            first_exit = match (p.is_some(), c.is_some()) {
                (false, true) => Some((now, "controller")),
                (true, false) => Some((now, "plant")),
                _ => None,
            };
        }
        if p.is_some() && c.is_some() {
            break;
        }
        if crate::signals::interrupted() && stop_sent.is_none() {
            let _ = ctl_pub.send_copy(ControlMsg::new(control::STOP, control::SUPERVISOR));
            stop_sent = Some(now);
        }
        let waited_out = match first_exit {
            // The plant is gone. If it exited by itself it released the controller with a final
            // state: give the controller 1 s to finish and say why. If it was killed by a signal
            // nothing will release the controller: stop it now.
            Some((t, "plant")) => {
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
    drain(&mut states, &mut torques, &mut tels, &mut fault)?;
    let plant_status = plant.exited();
    let ctrl_status = controller.exited();
    drop(plant);
    drop(controller);
    let interrupted = stop_sent.is_some();
    let cause = if interrupted {
        None
    } else {
        fault_cause(
            plant_status,
            ctrl_status,
            &plant_log,
            &ctrl_log,
            first_exit,
            &torques,
            &tels,
        )
    };

    let mut child_messages = messages();
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
    write_timing_csv(
        &run_dir.join(format!("{law}.timing.csv")),
        &states,
        &torques,
        &tels,
    )?;
    let mut timing = Timing::from_streams(
        &states,
        &torques,
        &tels,
        n,
        ts_ns,
        mode == ProcMode::Realtime,
    );
    timing.steal = crate::timing::steal_ms_between(&steal_before, &crate::timing::steal_jiffies());
    let run = rebuild(
        interrupted,
        cause.as_ref(),
        law,
        study,
        &states,
        &torques,
        &tels,
        fault.as_ref(),
    )?;
    Ok(ProcessRun {
        fault: cause,
        interrupted,
        run_id: rid,
        run,
        timing,
        child_messages,
    })
}

/// Replays the observed streams through the [`Recorder`], exactly as the in-process loop fills it.
#[allow(clippy::too_many_arguments)]
fn rebuild(
    interrupted: bool,
    cause: Option<&(u64, String)>,
    law: Law,
    study: &Study,
    states: &[Option<StateMsg>],
    torques: &[Option<TorqueMsg>],
    tels: &[Option<TelemetryMsg>],
    fault: Option<&(u64, String)>,
) -> Result<LawRun> {
    let n = study.reference.n;
    let mut rec = Recorder::new(law, n);
    if let Some((tick, text)) = cause {
        rec.fault(*tick, text.clone());
    }
    let sample = |s: &StateMsg| {
        (
            PlantSample {
                k: s.tick,
                q: Vec3::from(s.q),
                qd: Vec3::from(s.qd),
                tau_applied: Vec3::from(s.tau_applied),
            },
            Vec3::from(s.q_true),
            Vec3::from(s.qd_true),
        )
    };
    let mut last_out: Option<Output> = None;
    for k in 0..=n {
        // A realtime tick whose state the controller skipped (it answers the newest) has no torque
        // message; the plant held the previous torque.
        let missed = tels[k].is_some_and(|m| m.flags & wire::TEL_MISSED != 0);
        let torque = torques[k].map(|t| Output {
            tau: Vec3::from(t.tau),
            s: Vec3::from(t.s),
            n_hat: Vec3::from(t.n_hat),
            u: Vec3::from(t.u),
        });
        // Its torque is the one the plant held (τᵃ_{k+1}); the other fields repeat the last reply.
        let held = states
            .get(k + 1)
            .copied()
            .flatten()
            .map(|s| Vec3::from(s.tau_applied));
        let torque = torque.or(match (missed, held) {
            (true, Some(tau)) => Some(Output {
                tau,
                ..last_out.unwrap_or_default()
            }),
            _ => None,
        });
        let (Some(s), Some(out)) = (states[k], torque) else {
            // The loop ended here (interrupt, fault, a child died), or the supervisor lost the sample.
            if interrupted {
                rec.interrupt();
                return Ok(rec.finish(None));
            }
            if cause.is_some() {
                return Ok(rec.finish(None));
            }
            let why = match fault {
                Some((tick, text)) if *tick as usize <= k + 1 => text.clone(),
                _ => format!("the supervisor lost tick {k} of the stream"),
            };
            if k == 0 {
                return Err(anyhow!("{why}"));
            }
            rec.plant_failed(why);
            return Ok(rec.finish(None));
        };
        let (smp, q_true, qd_true) = sample(&s);
        last_out = Some(out);
        if !rec.tick(smp, q_true, qd_true, &study.reference.rows[k].joint.q, out) {
            return Ok(rec.finish(None));
        }
        let flags = tels[k].map_or(0, |m| m.flags);
        rec.applied(
            flags & wire::TEL_CLAMPED != 0,
            flags & wire::TEL_HELD != 0,
            flags & wire::TEL_REJECTED != 0,
        );
        if let Some((tick, text)) = fault
            && *tick as usize == k + 1
        {
            rec.plant_failed(text.clone());
            return Ok(rec.finish(None));
        }
    }
    let after = states[n + 1].map(|s| {
        let (smp, _, qd_true) = sample(&s);
        (smp, qd_true)
    });
    Ok(rec.finish(after))
}

/// `<law>.timing.csv`: the raw CLOCK_MONOTONIC stamps of every tick (ns) and the plant's flags,
/// so any latency can be recomputed. Empty cells: the supervisor did not see that message.
fn write_timing_csv(
    path: &Path,
    states: &[Option<StateMsg>],
    torques: &[Option<TorqueMsg>],
    tels: &[Option<TelemetryMsg>],
) -> Result<()> {
    let mut w = csv::Writer::from_path(path)
        .with_context(|| format!("cannot create {}", path.display()))?;
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
    ])?;
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
        ])?;
    }
    w.flush()?;
    Ok(())
}

fn status_text(s: std::process::ExitStatus) -> String {
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
fn fault_cause(
    plant: Option<std::process::ExitStatus>,
    ctrl: Option<std::process::ExitStatus>,
    plant_log: &Path,
    ctrl_log: &Path,
    first_exit: Option<(u64, &'static str)>,
    torques: &[Option<TorqueMsg>],
    tels: &[Option<TelemetryMsg>],
) -> Option<(u64, String)> {
    let ok = |s: Option<std::process::ExitStatus>| s.is_some_and(|s| s.success());
    if ok(plant) && ok(ctrl) {
        return None;
    }
    let last_torque = torques.iter().rev().flatten().next();
    let last_tel = tels
        .iter()
        .rev()
        .flatten()
        .find(|m| m.flags & wire::TEL_SAFE_STOP == 0);
    let tick = last_tel.map_or(0, |m| m.tick + 1);
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
    if plant.is_some() && !ok(plant) {
        let what = plant.map_or("did not exit".into(), status_text);
        let line = last_line(plant_log);
        parts.push(if line.is_empty() {
            format!("the plant {what}")
        } else {
            format!(
                "the plant {what}: {}",
                line.trim_start_matches("deltaloop-plant: ")
            )
        });
    }
    // How long after the dead peer's last message the supervisor saw it exit.
    if let Some((noticed, who)) = first_exit {
        let last = if who == "controller" {
            last_torque.map(|t| t.t_publish_ns)
        } else {
            last_tel.map(|m| m.t_wake_ns)
        };
        if let Some(t) = last {
            parts.push(format!(
                "the supervisor saw the {who} exit {:.1} ms after its last message",
                noticed.saturating_sub(t) as f64 * 1e-6
            ));
        }
    }
    Some((tick, parts.join("; ")))
}
