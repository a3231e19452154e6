//! The transport alone: the same plant and controller tick ([`deltaloop_plant::PlantSide`],
//! [`deltaloop_controller::ControllerSide`]) with nothing recorded, (1) in one thread, (2) over
//! iceoryx2 and (3) over a blocking Unix socket pair, plant in this process and controller in a
//! helper process (`deltaloop iox-controller` / `uds-controller`), pinned like lockstep, and (4)
//! over iceoryx2 on one CPU, both sides blocking. The difference of (2), (3) or (4) and (1) per
//! cycle is what the transport costs. (0) moves the same messages between two threads through one
//! shared slot each way, no transport at all: the machine's own floor for a hand-off between the
//! two CPUs. (5) sends both messages through iceoryx2 and takes them back in one thread: what
//! iceoryx2's own code costs per cycle, with no second CPU and no cache line moving between CPUs.
//! (2) costs about (5) plus (0): the library's instructions plus the lines the CPUs trade.
//!
//! The yardsticks of `bench loop`, and nothing of a run: no recorder, no report, no link, no
//! figures (tests/e2e/crate_graph.rs). Built as the loop processes are (the release profile
//! optimises every crate alike): a baseline built with less optimisation than the code it is
//! compared with would not measure the transport.

pub mod paced;

use anyhow::{Context, Result, bail};
use deltaloop_config::{Law, Priority, RunConfig};
use deltaloop_controller::ControllerSide;
use deltaloop_plant::Arrival;
use deltaloop_study::{Study, latency_histogram};
use deltaloop_transport::ipc::{self, IpcContext};
use deltaloop_transport::rt;
use deltaloop_transport::wire::{StateMsg, TorqueMsg};
use hdrhistogram::Histogram;
use std::cell::UnsafeCell;
use std::io::{Read, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// How long either side of a baseline waits for its peer before it gives up.
const PEER_TIMEOUT: Duration = Duration::from_secs(10);

/// A probe the iceoryx2 helper echoes before the loop starts (tick numbers the loop never uses).
const PROBE_TICK: u64 = u64::MAX;

/// One lockstep baseline run: its cycle rate and the hand-off measured on every cycle.
pub struct Measured {
    /// Cycles per second.
    pub hz: f64,
    /// Per cycle, ns: state sent → reply received, less the helper's time from receiving the
    /// state to sending the reply (both sides read CLOCK_MONOTONIC): the two one-way hand-offs.
    pub handoff: Histogram<u64>,
}

/// The hand-off of one cycle: `sent` → `received` less the controller's own time (its stamps).
fn record_handoff(h: &mut Histogram<u64>, sent: u64, received: u64, t: &TorqueMsg) {
    let ctrl = t.t_publish_ns.saturating_sub(t.t_state_rx_ns);
    let _ = h.record(received.saturating_sub(sent).saturating_sub(ctrl).max(1));
}

/// Pins this thread to `cpu` as SCHED_OTHER, as lockstep runs; warnings go to stderr.
fn pin(who: &str, cpu: Option<usize>) {
    for w in rt::apply(&rt::Sched {
        core: cpu,
        priority: Priority::Other,
        lock_memory: false,
    }) {
        eprintln!("deltaloop {who}: warning: {w}");
    }
}

/// Steps the plant through the study's ticks; `exchange` takes each state to the controller and
/// brings its reply back. The cycle rate and the hand-off of every cycle.
fn drive(
    study: &Study,
    what: &str,
    mut exchange: impl FnMut(StateMsg) -> Result<TorqueMsg>,
) -> Result<Measured> {
    let mut plant = study.plant_side()?;
    let ticks = study.reference.n as u64;
    let mut hist = latency_histogram();
    let t0 = Instant::now();
    for k in 0..=ticks {
        let sent_ns = rt::now_ns();
        let t = exchange(plant.state())?;
        record_handoff(&mut hist, sent_ns, rt::now_ns(), &t);
        if t.tick != k {
            bail!("{what} baseline: reply for tick {} at tick {k}", t.tick);
        }
        if let Err(stop) = plant.advance(Arrival::Reply(t)) {
            bail!("{what} baseline: {}", stop.cause());
        }
    }
    Ok(Measured {
        hz: (ticks + 1) as f64 / t0.elapsed().as_secs_f64(),
        handoff: hist,
    })
}

/// The controller's reply to `st`, received at `rx_ns`: the same controller tick every mode runs,
/// so each baseline does the same work, with the helper's own stamps for the hand-off.
fn answer(study: &Study, ctrl: &mut ControllerSide, st: &StateMsg, rx_ns: u64) -> TorqueMsg {
    let last = study.reference.n + 1;
    let r = study.reference.row((st.tick as usize).min(last)).joint;
    let mut reply = ctrl.answer(st, &r);
    reply.t_state_rx_ns = rx_ns;
    reply.t_publish_ns = rt::now_ns();
    reply
}

/// The plant and controller tick in one thread on `cpu`, nothing recorded: cycles per second.
pub fn raw_inproc(study: &Study, cpu: Option<usize>) -> Result<f64> {
    pin("bench loop", cpu);
    let mut ctrl = study.controller_side(Law::TdcIsSta);
    let m = drive(study, "inproc", |st| {
        Ok(answer(study, &mut ctrl, &st, rt::now_ns()))
    })?;
    Ok(m.hz)
}

/// One message at a time from one thread to another: the payload, and the count of messages put
/// so far, which publishes it. Aligned apart so that the two directions share no cache line.
#[repr(align(128))]
#[derive(Default)]
struct Slot<T> {
    count: AtomicU64,
    msg: UnsafeCell<T>,
}

// SAFETY: `put` and `take` hand the payload over strictly in turn (see `put`), so the writer and
// the reader never touch `msg` at the same time.
unsafe impl<T: Send> Sync for Slot<T> {}

impl<T: Copy> Slot<T> {
    /// Puts message number `n` (1, 2, …). The caller must know that the reader has taken message
    /// `n − 1`: in a ping-pong, the reply to it has arrived.
    fn put(&self, m: T, n: u64) {
        // SAFETY: the reader took message n − 1 and reads again only after `count` reaches n.
        unsafe { *self.msg.get() = m };
        self.count.store(n, Ordering::Release);
    }

    /// Spins until message `n` is there and copies it out; `None` after [`PEER_TIMEOUT`].
    fn take(&self, n: u64) -> Option<T> {
        let since = Instant::now();
        let mut spins = 0u32;
        while self.count.load(Ordering::Acquire) < n {
            std::hint::spin_loop();
            spins = spins.wrapping_add(1);
            if spins.is_multiple_of(4096) && since.elapsed() > PEER_TIMEOUT {
                return None;
            }
        }
        // SAFETY: the writer published message n (Acquire pairs with its Release) and writes
        // message n + 1 only after our reply.
        Some(unsafe { *self.msg.get() })
    }
}

/// (0) The plant here on `plant_cpu`, the controller in a second thread on `ctrl_cpu`, each
/// message copied through a shared slot and polled for: no transport, no system call. What a
/// hand-off between these two CPUs costs at the least (cache lines moving between them).
pub fn shared_memory(
    study: &Study,
    plant_cpu: Option<usize>,
    ctrl_cpu: Option<usize>,
) -> Result<Measured> {
    let state = Slot::<StateMsg>::default();
    let torque = Slot::<TorqueMsg>::default();
    let last = study.reference.n as u64;
    std::thread::scope(|scope| {
        let controller = scope.spawn(|| -> Result<()> {
            pin("bench loop (shared-memory controller)", ctrl_cpu);
            let mut ctrl = study.controller_side(Law::TdcIsSta);
            for n in 1..=last + 1 {
                let Some(st) = state.take(n) else {
                    bail!("shared-memory baseline: no state {n} within {PEER_TIMEOUT:?}");
                };
                let rx = rt::now_ns();
                torque.put(answer(study, &mut ctrl, &st, rx), n);
            }
            Ok(())
        });
        pin("bench loop", plant_cpu);
        let mut n = 0;
        let measured = drive(study, "shared memory", |st| {
            n += 1;
            state.put(st, n);
            torque.take(n).with_context(|| {
                format!(
                    "shared-memory baseline: no reply to tick {} within {PEER_TIMEOUT:?}",
                    st.tick
                )
            })
        });
        let helper = controller.join();
        let measured = measured?;
        helper.map_err(|_| {
            anyhow::anyhow!("shared-memory baseline: the controller thread panicked")
        })??;
        Ok(measured)
    })
}

/// How the two sides of the iceoryx2 baseline wait for each other.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Handoff {
    /// Both poll their subscriber: the transport's own cost (needs a CPU each).
    Polling,
    /// Both block on a wake-up event after each message, as the default realtime layout does on
    /// one CPU: a notification and a context switch each way.
    Blocking,
}

/// (5) The plant and controller tick in one thread on `cpu`, each message published on the
/// product's iceoryx2 service and taken back from a subscriber of the same thread: the library's
/// own code per cycle (loan, copy, deliver, receive, release, reclaim), nothing between CPUs.
pub fn iox_one_thread(study: &Study, cpu: Option<usize>) -> Result<Measured> {
    let run_id = ipc::new_run_id();
    let node = ipc::node("bench-one-thread", &run_id)?;
    let state = ipc::state(&node, &run_id)?;
    let torque = ipc::torque(&node, &run_id)?;
    let state_tx = state.publisher("state publisher")?;
    let state_rx = state.subscriber(Some(ipc::LOOP_BUFFER), "state subscriber")?;
    let torque_tx = torque.publisher("torque publisher")?;
    let torque_rx = torque.subscriber(Some(ipc::LOOP_BUFFER), "torque subscriber")?;
    pin("bench loop", cpu);
    let mut ctrl = study.controller_side(Law::TdcIsSta);
    drive(study, "iox one-thread", |st| {
        state_tx.send_copy(st).ipc("publish state")?;
        let Some(got) = state_rx.receive().ipc("receive state")? else {
            bail!("iox one-thread baseline: state {} not delivered", st.tick);
        };
        let rx = rt::now_ns();
        torque_tx
            .send_copy(answer(study, &mut ctrl, &got, rx))
            .ipc("publish torque")?;
        let Some(reply) = torque_rx.receive().ipc("receive torque")? else {
            bail!("iox one-thread baseline: reply {} not delivered", st.tick);
        };
        Ok(reply)
    })
}

/// The controller side of the iceoryx2 baseline (hidden subcommand `iox-controller`): waits for
/// each state as `handoff` says, answers it, echoes probes, and ends after the last tick.
pub fn iox_controller(
    run_id: &str,
    config: &Path,
    cpu: Option<usize>,
    handoff: Handoff,
) -> Result<()> {
    let study = Study::new(RunConfig::from_file(config)?)?;
    pin("iox-controller", cpu);
    let node = ipc::node("bench-controller", run_id)?;
    let state = ipc::state(&node, run_id)?.subscriber(None, "state subscriber")?;
    let torque = ipc::torque(&node, run_id)?.publisher("torque publisher")?;
    let state_ready = ipc::listener(&node, run_id, "state-ready")?;
    let torque_ready = ipc::notifier(&node, run_id, "torque-ready")?;
    let mut ctrl = study.controller_side(Law::TdcIsSta);
    let last = study.reference.n as u64;
    let mut heard = Instant::now();
    loop {
        let Some(st) = state.receive().ipc("receive state")? else {
            if heard.elapsed() > PEER_TIMEOUT {
                bail!("iox-controller: no state for {PEER_TIMEOUT:?}");
            }
            match handoff {
                Handoff::Polling => std::hint::spin_loop(),
                Handoff::Blocking => {
                    // A signal only cuts the wait short; the loop looks again.
                    let _ = state_ready.timed_wait(Duration::from_millis(10));
                }
            }
            continue;
        };
        let rx = rt::now_ns();
        heard = Instant::now();
        let reply = if st.tick == PROBE_TICK {
            TorqueMsg {
                tick: PROBE_TICK,
                ..TorqueMsg::default()
            }
        } else {
            answer(&study, &mut ctrl, &st, rx)
        };
        torque.send_copy(reply).ipc("publish torque")?;
        if handoff == Handoff::Blocking {
            torque_ready.notify().ipc("notify torque")?;
        }
        if st.tick == last {
            return Ok(());
        }
    }
}

/// Lockstep over iceoryx2, each side waiting as `handoff` says, plant here on `plant_cpu`,
/// controller in a helper process on `ctrl_cpu`: cycles per second.
pub fn iox_lockstep(
    study: &Study,
    config_path: &Path,
    plant_cpu: Option<usize>,
    ctrl_cpu: Option<usize>,
    handoff: Handoff,
) -> Result<Measured> {
    let run_id = ipc::new_run_id();
    let node = ipc::node("bench-plant", &run_id)?;
    let state = ipc::state(&node, &run_id)?.publisher("state publisher")?;
    let torque =
        ipc::torque(&node, &run_id)?.subscriber(Some(ipc::LOOP_BUFFER), "torque subscriber")?;
    let state_ready = ipc::notifier(&node, &run_id, "state-ready")?;
    let torque_ready = ipc::listener(&node, &run_id, "torque-ready")?;
    let mut args = vec!["--run-id", &run_id];
    if handoff == Handoff::Blocking {
        args.push("--blocking");
    }
    let mut child = helper("iox-controller", &args, config_path, ctrl_cpu)?;
    // Until the helper echoes a probe, its ports may not be connected yet.
    let since = Instant::now();
    'probe: loop {
        state
            .send_copy(StateMsg {
                tick: PROBE_TICK,
                ..StateMsg::default()
            })
            .ipc("publish probe")?;
        state_ready.notify().ipc("notify probe")?;
        std::thread::sleep(Duration::from_millis(1));
        while let Some(s) = torque.receive().ipc("receive torque")? {
            if s.tick == PROBE_TICK {
                break 'probe;
            }
        }
        if since.elapsed() > PEER_TIMEOUT {
            let _ = child.kill();
            bail!("iox baseline: the helper did not answer within {PEER_TIMEOUT:?}");
        }
    }
    pin("bench loop", plant_cpu);
    let measured = drive(study, "iox", |st| {
        state.send_copy(st).ipc("publish state")?;
        if handoff == Handoff::Blocking {
            state_ready.notify().ipc("notify state")?;
        }
        let sent = Instant::now();
        loop {
            if let Some(reply) = next_reply(&torque)? {
                return Ok(reply);
            }
            if sent.elapsed() > PEER_TIMEOUT {
                bail!(
                    "iox baseline: no reply to tick {} within {PEER_TIMEOUT:?}",
                    st.tick
                );
            }
            match handoff {
                Handoff::Polling => std::hint::spin_loop(),
                Handoff::Blocking => {
                    // Drop wake-ups already seen, look once more, then sleep until a new one
                    // (the plant process waits the same way).
                    torque_ready.try_wait().ipc("drain torque events")?;
                    if !torque.has_samples().unwrap_or(true) {
                        ipc::wait_event(&torque_ready, 10_000_000)?;
                    }
                }
            }
        }
    });
    if measured.is_err() {
        let _ = child.kill();
    }
    let measured = measured?;
    let status = child.wait()?;
    if !status.success() {
        bail!("iox baseline: the helper ended with {status}");
    }
    Ok(measured)
}

/// The next reply in `torque`, past any echo of a probe: the probes sent every millisecond until
/// the first echo may have queued several at the helper, whose echoes come after the loop has
/// started.
fn next_reply(torque: &ipc::TorqueIn) -> Result<Option<TorqueMsg>> {
    while let Some(s) = torque.receive().ipc("receive torque")? {
        if s.tick != PROBE_TICK {
            return Ok(Some(s));
        }
    }
    Ok(None)
}

/// Starts `deltaloop <sub> <args> --config <config> [--cpu N]`.
fn helper(
    sub: &str,
    args: &[&str],
    config: &Path,
    cpu: Option<usize>,
) -> Result<std::process::Child> {
    let mut cmd = std::process::Command::new(std::env::current_exe()?);
    cmd.arg(sub).args(args).arg("--config").arg(config);
    if let Some(c) = cpu {
        cmd.args(["--cpu", &c.to_string()]);
    }
    cmd.spawn()
        .with_context(|| format!("start the {sub} helper"))
}

/// Plain-data message as bytes (the wire types are `#[repr(C)]` with explicit padding).
fn bytes_of<T: Copy>(v: &T) -> &[u8] {
    // SAFETY: T is one of our repr(C) wire types: Copy, no references, no implicit padding.
    unsafe { std::slice::from_raw_parts((v as *const T).cast::<u8>(), size_of::<T>()) }
}

fn read_msg<T: Copy + Default>(s: &mut UnixStream) -> std::io::Result<T> {
    let mut v = T::default();
    // SAFETY: as above; every bit pattern of these f64/u64/u32 fields is valid.
    let buf =
        unsafe { std::slice::from_raw_parts_mut((&mut v as *mut T).cast::<u8>(), size_of::<T>()) };
    s.read_exact(buf)?;
    Ok(v)
}

/// The controller side of the Unix-socket baseline (hidden subcommand `uds-controller`).
pub fn uds_controller(socket: &Path, config: &Path, cpu: Option<usize>) -> Result<()> {
    let study = Study::new(RunConfig::from_file(config)?)?;
    pin("uds-controller", cpu);
    let mut s =
        UnixStream::connect(socket).with_context(|| format!("connect {}", socket.display()))?;
    let mut ctrl = study.controller_side(Law::TdcIsSta);
    loop {
        let st: StateMsg = match read_msg(&mut s) {
            Ok(m) => m,
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => return Ok(()),
            Err(e) => return Err(e.into()),
        };
        let rx = rt::now_ns();
        s.write_all(bytes_of(&answer(&study, &mut ctrl, &st, rx)))?;
    }
}

/// Lockstep over a blocking Unix socket pair, plant on `plant_cpu`, controller on `ctrl_cpu`:
/// cycles per second.
pub fn uds_lockstep(
    study: &Study,
    config_path: &Path,
    dir: &Path,
    plant_cpu: Option<usize>,
    ctrl_cpu: Option<usize>,
) -> Result<Measured> {
    let sock = dir.join("uds.sock");
    let _ = std::fs::remove_file(&sock);
    let listener = UnixListener::bind(&sock).with_context(|| format!("bind {}", sock.display()))?;
    let sock_arg = sock.display().to_string();
    let mut child = helper(
        "uds-controller",
        &["--socket", &sock_arg],
        config_path,
        ctrl_cpu,
    )?;
    let (mut s, _) = listener.accept()?;
    pin("bench loop", plant_cpu);
    let measured = drive(study, "uds", |st| {
        s.write_all(bytes_of(&st))?;
        Ok(read_msg(&mut s)?)
    });
    drop(s);
    let _ = child.wait();
    let _ = std::fs::remove_file(&sock);
    measured
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Regression: a late echo of a queued probe reached the loop as tick 0's reply, and `bench
    /// loop` stopped with "iox baseline: reply for tick 18446744073709551615 at tick 0".
    #[test]
    fn regression_a_late_probe_echo_is_not_taken_for_a_reply() {
        let run_id = ipc::new_run_id();
        let node = ipc::node("bench-test", &run_id).unwrap();
        let torque = ipc::torque(&node, &run_id).unwrap();
        let tx = torque.publisher("publisher").unwrap();
        let rx = torque
            .subscriber(Some(ipc::LOOP_BUFFER), "subscriber")
            .unwrap();
        for tick in [PROBE_TICK, PROBE_TICK, 0] {
            tx.send_copy(TorqueMsg {
                tick,
                ..TorqueMsg::default()
            })
            .unwrap();
        }
        assert_eq!(next_reply(&rx).unwrap().map(|r| r.tick), Some(0));
        tx.send_copy(TorqueMsg {
            tick: PROBE_TICK,
            ..TorqueMsg::default()
        })
        .unwrap();
        assert!(next_reply(&rx).unwrap().is_none());
    }
}
