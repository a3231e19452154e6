//! `deltaloop bench loop`: the cost of the transport, measured in one run.
//!
//! (a) lockstep over iceoryx2 (the real process pair), (b) the same lockstep loop over a blocking
//! Unix domain socket pair (plant in this process, controller in a helper process, pinned like
//! lockstep), (c) the in-process loop, (d) a realtime run at 3.3 kHz. All four step the same
//! plant and controller tick ([`deltaloop_plant::PlantSide`], [`deltaloop_controller::ControllerSide`])
//! on the same scenario; the transport's cost per cycle is 1/lockstep_hz − 1/inproc_hz.

use crate::bench::s1_hold_study;
use crate::inproc;
use crate::lawrun::Keep;
use crate::procs;
use crate::study::Study;
use anyhow::{Context, Result, bail};
use deltaloop_config::LoopMode;
use deltaloop_config::config::Layout;
use deltaloop_config::{Law, RunConfig};
use deltaloop_plant::Arrival;
use deltaloop_transport::rt;
use deltaloop_transport::wire::{StateMsg, TorqueMsg};
use std::io::{Read, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::Path;
use std::time::Instant;

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
    for w in rt::apply(&rt::Sched {
        core: cpu,
        fifo_priority: 0,
        lock_memory: false,
    }) {
        eprintln!("deltaloop uds-controller: warning: {w}");
    }
    let mut s =
        UnixStream::connect(socket).with_context(|| format!("connect {}", socket.display()))?;
    let mut ctrl = study.controller_side(Law::TdcIsSta);
    let last = study.reference.n + 1;
    loop {
        let st: StateMsg = match read_msg(&mut s) {
            Ok(m) => m,
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => return Ok(()),
            Err(e) => return Err(e.into()),
        };
        let r = study.reference.row((st.tick as usize).min(last)).joint;
        // The same controller tick every mode runs, so the baseline does the same work.
        s.write_all(bytes_of(&ctrl.answer(&st, &r)))?;
    }
}

/// Lockstep over a blocking Unix socket pair, plant on `plant_cpu`, controller on `ctrl_cpu`:
/// cycles per second.
fn uds_lockstep(
    study: &Study,
    config_path: &Path,
    dir: &Path,
    plant_cpu: Option<usize>,
    ctrl_cpu: Option<usize>,
) -> Result<f64> {
    let sock = dir.join("uds.sock");
    let _ = std::fs::remove_file(&sock);
    let listener = UnixListener::bind(&sock).with_context(|| format!("bind {}", sock.display()))?;
    let exe = std::env::current_exe()?;
    let mut args = vec![
        "uds-controller".to_string(),
        "--socket".into(),
        sock.display().to_string(),
        "--config".into(),
        config_path.display().to_string(),
    ];
    if let Some(c) = ctrl_cpu {
        args.extend(["--cpu".to_string(), c.to_string()]);
    }
    let mut child = std::process::Command::new(exe)
        .args(&args)
        .spawn()
        .context("start the uds-controller helper")?;
    let (mut s, _) = listener.accept()?;
    for w in rt::apply(&rt::Sched {
        core: plant_cpu,
        fifo_priority: 0,
        lock_memory: false,
    }) {
        eprintln!("deltaloop bench loop: warning: {w}");
    }
    let mut plant = study.plant_side()?;
    let ticks = study.reference.n as u64;
    let t0 = Instant::now();
    for k in 0..=ticks {
        s.write_all(bytes_of(&plant.state()))?;
        let t: TorqueMsg = read_msg(&mut s)?;
        if t.tick != k {
            bail!("uds baseline: reply for tick {} at tick {k}", t.tick);
        }
        if let Err(stop) = plant.advance(Arrival::Reply(t)) {
            bail!("uds baseline: {}", stop.cause());
        }
    }
    let hz = (ticks + 1) as f64 / t0.elapsed().as_secs_f64();
    drop(s);
    let _ = child.wait();
    let _ = std::fs::remove_file(&sock);
    Ok(hz)
}

/// Runs the four measurements and prints; the last line is the machine-readable summary.
pub fn run(lockstep_seconds: f64, rt_seconds: f64, out: &Path) -> Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    println!(
        "deltaloop bench loop: lockstep/inproc {lockstep_seconds} s simulated ({} ticks), realtime {rt_seconds} s at 3.3 kHz; machine: {} logical CPUs",
        (lockstep_seconds / 3e-4).round(),
        std::thread::available_parallelism().map_or(0, |n| n.get())
    );
    let ls = s1_hold_study("bench-loop", lockstep_seconds)?;
    let ls_dir = out.join("lockstep");
    std::fs::create_dir_all(&ls_dir)?;
    std::fs::write(ls_dir.join("config.toml"), ls.config.to_toml_string())?;

    // (c) inproc first (no pinning yet), then (a) iceoryx2 lockstep, then (b) the socket baseline.
    let t0 = Instant::now();
    let run = inproc::run_law(&ls, Law::TdcIsSta, &Keep::default())?;
    let inproc_hz = run.end.records as f64 / t0.elapsed().as_secs_f64();
    println!(
        "(c) inproc:            {inproc_hz:>12.0} cycles/s  ({:.3} us/cycle)",
        1e6 / inproc_hz
    );

    let pr = procs::run_law(
        &ls,
        Law::TdcIsSta,
        LoopMode::Lockstep,
        &ls_dir,
        &Keep::default(),
    )?;
    let iox_hz = pr.timing.cycle_hz();
    let rtt = pr.timing.summary().round_trip;
    println!(
        "(a) lockstep iceoryx2: {iox_hz:>12.0} cycles/s  ({:.3} us/cycle; round trip p50 {:.2} us, p99 {:.2} us, p99.9 {:.2} us)",
        1e6 / iox_hz,
        rtt.p50_us,
        rtt.p99_us,
        rtt.p999_us
    );
    // The socket's best layout is the baseline: one CPU each (as lockstep), or both on one CPU.
    let lay = &ls.config.loop_.lockstep;
    let (pc, cc) = (Layout::cpu(lay.plant_cpu), Layout::cpu(lay.controller_cpu));
    let cfg_path = ls_dir.join("config.toml");
    let uds_split = uds_lockstep(&ls, &cfg_path, &ls_dir, pc, cc)?;
    let uds_shared = uds_lockstep(&ls, &cfg_path, &ls_dir, cc, cc)?;
    let uds_hz = uds_split.max(uds_shared);
    println!(
        "(b) lockstep UDS:      {uds_hz:>12.0} cycles/s  ({:.3} us/cycle; best of one CPU each {uds_split:.0}/s and one shared CPU {uds_shared:.0}/s)",
        1e6 / uds_hz
    );
    let (iox_cost, uds_cost) = (
        1e6 / iox_hz - 1e6 / inproc_hz,
        1e6 / uds_hz - 1e6 / inproc_hz,
    );
    println!(
        "transport cost per cycle: iceoryx2 {iox_cost:.3} us, Unix socket {uds_cost:.3} us, ratio {:.2} (targets: iceoryx2 < 3 us and <= 1/3 of the socket's)",
        iox_cost / uds_cost
    );

    // (d) realtime.
    let rs = s1_hold_study("bench-loop", rt_seconds)?;
    let rt_dir = out.join("realtime");
    std::fs::create_dir_all(&rt_dir)?;
    std::fs::write(rt_dir.join("config.toml"), rs.config.to_toml_string())?;
    let pr = procs::run_law(
        &rs,
        Law::TdcIsSta,
        LoopMode::Realtime,
        &rt_dir,
        &Keep::default(),
    )?;
    pr.timing.write_hgrm(&rt_dir, "")?;
    let t = pr.timing.summary();
    for m in &pr.child_messages {
        eprintln!("{m}");
    }
    println!(
        "(d) realtime:          round trip p50 {:.1} us, p99 {:.1} us, p99.9 {:.1} us, max {:.1} us; wake lateness p99.9 {:.1} us; misses {} of {} ({:.2e}) (targets: p99.9 <= 110 us, miss ratio <= 2e-4)",
        t.round_trip.p50_us,
        t.round_trip.p99_us,
        t.round_trip.p999_us,
        t.round_trip.max_us,
        t.wake_lateness.p999_us,
        t.deadline_misses,
        t.ticks,
        t.miss_ratio
    );
    let steal: Vec<String> = t
        .cpu_steal_ms
        .iter()
        .map(|c| format!("cpu{} {:.0} ms", c.cpu, c.ms))
        .collect();
    println!(
        "    CPU time stolen by the hypervisor during the realtime run: {}",
        if steal.is_empty() {
            "n/a".into()
        } else {
            steal.join(", ")
        }
    );
    println!("histograms: {}", rt_dir.display());
    println!(
        "lockstep_iox_hz={iox_hz:.0} lockstep_uds_hz={uds_hz:.0} inproc_hz={inproc_hz:.0} rt_rtt_p999_us={:.1} rt_miss_ratio={:.2e}",
        t.round_trip.p999_us, t.miss_ratio
    );
    Ok(())
}
