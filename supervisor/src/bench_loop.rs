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
use hdrhistogram::Histogram;
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
    let ls_summary = pr.timing.summary();
    let rtt = ls_summary.round_trip;
    // The hand-off itself, both ways: state published → reply received, less the law's compute.
    let handoff = rtt.p50_us - ls_summary.controller_compute.p50_us;
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
        "transport cost per cycle: iceoryx2 {iox_cost:.3} us, Unix socket {uds_cost:.3} us, ratio {:.2}; the iceoryx2 figure includes the supervisor recording every tick beside the loop on the same 2 CPUs (the socket baseline records nothing)",
        iox_cost / uds_cost
    );
    println!(
        "    the hand-off itself (lockstep round trip p50 less the law's compute p50): {handoff:.2} us per cycle, both ways, no system call"
    );

    // (d) realtime, the default layout and the split-CPU one, then (e) the machine's own limit.
    let budget_us = f64::from(ls.config.loop_.torque_budget_us);
    let rt_default = realtime(out, "realtime", rt_seconds, Layout::realtime_default())?;
    let rt_split = realtime(
        out,
        "realtime-split",
        rt_seconds,
        Layout::realtime_split_cpus(),
    )?;
    let lay = Layout::realtime_default();
    let (cpu, prio) = (
        Layout::cpu(lay.plant_cpu).unwrap_or(0),
        lay.plant_priority.unwrap_or(0),
    );
    let ts_ns = ls.config.ts_ns();
    let machine = sleep_only_loop(cpu, prio, ts_ns, rt_seconds)?;
    let cyclic = cyclictest(cpu, prio, ts_ns / 1000, rt_seconds);
    let m = |h: &Histogram<u64>, q: f64| h.value_at_quantile(q) as f64 / 1e3;
    println!(
        "(e) machine: a sleep-only loop on CPU {cpu} at SCHED_FIFO {prio}, every {} us: wake lateness p50 {:.1} us, p99 {:.1} us, p99.9 {:.1} us, max {:.1} us",
        ts_ns / 1000,
        m(&machine, 0.5),
        m(&machine, 0.99),
        m(&machine, 0.999),
        machine.max() as f64 / 1e3
    );
    match &cyclic {
        Ok(h) => println!(
            "    cyclictest -m -p {prio} -i {} -a {cpu} -t 1: p50 {:.1} us, p99 {:.1} us, p99.9 {:.1} us, max {:.1} us",
            ts_ns / 1000,
            m(h, 0.5),
            m(h, 0.99),
            m(h, 0.999),
            h.max() as f64 / 1e3
        ),
        Err(why) => println!("    cyclictest: not run ({why})"),
    }
    let (d, sp) = (rt_default.summary(), rt_split.summary());
    println!(
        "loop vs machine (p99.9): round trip {:.1} us (default layout), {:.1} us (split CPUs) vs machine wake lateness {:.1} us; the plant's wake lateness {:.1} us after waking {} us early",
        d.round_trip.p999_us,
        sp.round_trip.p999_us,
        m(&machine, 0.999),
        d.wake_lateness.p999_us,
        lay.wake_early_us.unwrap_or(0)
    );
    let mut hists: Vec<(&str, &Histogram<u64>)> = vec![
        ("round trip, default", &rt_default.round_trip.hist),
        ("round trip, split CPUs", &rt_split.round_trip.hist),
        ("wake lateness, default", &rt_default.wake_lateness.hist),
        ("sleep-only loop", &machine),
    ];
    if let Ok(h) = &cyclic {
        hists.push(("cyclictest", h));
    }
    crate::plot::latency_percentiles(
        &out.join("latency"),
        "bench loop: realtime round trip and wake lateness vs the machine",
        &hists,
        Some(budget_us),
    )?;
    println!("figure: {}", out.join("latency.png").display());
    println!(
        "lockstep_iox_hz={iox_hz:.0} lockstep_uds_hz={uds_hz:.0} inproc_hz={inproc_hz:.0} lockstep_handoff_us={handoff:.2} rt_rtt_p50_us={:.1} rt_rtt_p999_us={:.1} rt_miss_ratio={:.2e} rt_split_rtt_p50_us={:.1} rt_split_rtt_p999_us={:.1} rt_split_miss_ratio={:.2e} machine_wake_p999_us={:.1} cyclictest_p999_us={}",
        d.round_trip.p50_us,
        d.round_trip.p999_us,
        d.miss_ratio,
        sp.round_trip.p50_us,
        sp.round_trip.p999_us,
        sp.miss_ratio,
        m(&machine, 0.999),
        cyclic
            .as_ref()
            .map_or("na".to_string(), |h| format!("{:.1}", m(h, 0.999)))
    );
    Ok(())
}

/// One realtime run of `seconds` on the S1 hold with `layout`, in `out/<name>`; its timing, with
/// the `.hgrm` files and figures written there.
fn realtime(out: &Path, name: &str, seconds: f64, layout: Layout) -> Result<crate::timing::Timing> {
    let mut rs = s1_hold_study("bench-loop", seconds)?;
    rs.config.loop_.realtime = layout;
    // A virtual CPU the host freezes for 30 ms must not end the measurement: count the misses.
    rs.config.faults.controller_silence_ticks =
        rs.config.faults.controller_silence_ticks.max(10_000);
    let dir = out.join(name);
    std::fs::create_dir_all(&dir)?;
    std::fs::write(dir.join("config.toml"), rs.config.to_toml_string())?;
    let pr = procs::run_law(
        &rs,
        Law::TdcIsSta,
        LoopMode::Realtime,
        &dir,
        &Keep::default(),
    )?;
    pr.timing.write_hgrm(&dir, "tdc-is-sta.")?;
    let budget = f64::from(rs.config.loop_.torque_budget_us);
    crate::plot::timing_figures(
        &dir,
        "tdc-is-sta.",
        &format!("tdc-is-sta, {name}"),
        &pr.timing,
        budget,
    )?;
    for m in &pr.child_messages {
        eprintln!("{m}");
    }
    let t = pr.timing.summary();
    let steal: Vec<String> = t
        .cpu_steal_ms
        .iter()
        .map(|c| format!("cpu{} {:.0} ms", c.cpu, c.ms))
        .collect();
    println!(
        "(d) {name:<15} round trip p50 {:.1} us, p99 {:.1} us, p99.9 {:.1} us, max {:.1} us; wake lateness p99.9 {:.1} us; misses {} of {} ({:.2e}); CPU stolen by the host: {}",
        t.round_trip.p50_us,
        t.round_trip.p99_us,
        t.round_trip.p999_us,
        t.round_trip.max_us,
        t.wake_lateness.p999_us,
        t.deadline_misses,
        t.ticks,
        t.miss_ratio,
        if steal.is_empty() {
            "n/a".into()
        } else {
            steal.join(", ")
        }
    );
    Ok(pr.timing)
}

/// The machine's own limit, as cyclictest measures it: a thread on `cpu` at SCHED_FIFO `prio`
/// sleeps to absolute deadlines every `ts_ns` for `seconds`; the histogram of its wake
/// lateness (ns). Memory is locked and allocated before the loop, as in the plant.
fn sleep_only_loop(cpu: usize, prio: i32, ts_ns: u64, seconds: f64) -> Result<Histogram<u64>> {
    let n = (seconds * 1e9 / ts_ns as f64).round() as u64;
    let t = std::thread::spawn(move || {
        let warnings = rt::apply(&rt::Sched {
            core: Some(cpu),
            fifo_priority: prio,
            lock_memory: false,
        });
        let mut h = crate::timing::latency_histogram();
        let t0 = rt::now_ns() + 1_000_000;
        for k in 0..n {
            let d = t0 + k * ts_ns;
            rt::sleep_until_ns(d);
            let _ = h.record(rt::now_ns().saturating_sub(d).max(1));
        }
        (h, warnings)
    });
    let (h, warnings) = t
        .join()
        .map_err(|_| anyhow::anyhow!("the sleep-only loop panicked"))?;
    for w in warnings {
        eprintln!("deltaloop bench loop: warning: {w}");
    }
    Ok(h)
}

/// `cyclictest` (rt-tests) with the same CPU, priority and period, if it is installed; its
/// latency histogram in ns (1 µs buckets; overflows beyond 10 ms counted at 10 ms).
fn cyclictest(
    cpu: usize,
    prio: i32,
    interval_us: u64,
    seconds: f64,
) -> Result<Histogram<u64>, String> {
    let o = std::process::Command::new("cyclictest")
        .args(["-m", "-q", "-t", "1", "-h", "10000"])
        .args(["-p", &prio.to_string(), "-a", &cpu.to_string()])
        .args(["-i", &interval_us.to_string()])
        .args(["-D", &format!("{}", seconds.ceil() as u64)])
        .stdin(std::process::Stdio::null())
        .output()
        .map_err(|e| format!("{e}; install rt-tests for it"))?;
    if !o.status.success() {
        return Err(format!(
            "exit {}: {}",
            o.status,
            String::from_utf8_lossy(&o.stderr).trim()
        ));
    }
    parse_cyclictest_histogram(&String::from_utf8_lossy(&o.stdout))
}

/// cyclictest's `-h` output: lines "<µs> <count>" and comments; overflows go to the top bucket.
fn parse_cyclictest_histogram(text: &str) -> Result<Histogram<u64>, String> {
    let mut h = crate::timing::latency_histogram();
    for line in text.lines() {
        if let Some(rest) = line.strip_prefix("# Histogram Overflows:") {
            let n: u64 = rest.trim().parse().unwrap_or(0);
            let _ = h.record_n(10_000_000, n);
            continue;
        }
        let mut f = line.split_whitespace();
        if let (Some(us), Some(count), None) = (f.next(), f.next(), f.next())
            && let (Ok(us), Ok(count)) = (us.parse::<u64>(), count.parse::<u64>())
        {
            let _ = h.record_n((us * 1000).max(1), count);
        }
    }
    if h.is_empty() {
        return Err("no histogram in its output".into());
    }
    Ok(h)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cyclictest_histogram_is_read_in_microseconds_with_overflows_at_the_top() {
        let text = "# /dev/cpu_dma_latency set to 0us\n000000 000000\n000003 000010\n000004 000089\n000120 000001\n# Total: 000000101\n# Min Latencies: 00003\n# Histogram Overflows: 00002\n";
        let h = parse_cyclictest_histogram(text).unwrap();
        assert_eq!(h.len(), 102);
        assert_eq!(h.value_at_quantile(0.5), h.highest_equivalent(4_000));
        assert!(h.max() >= 10_000_000);
        assert!(parse_cyclictest_histogram("# nothing\n").is_err());
    }
}
