//! `deltaloop bench loop`: the loop against the transport's own cost and the machine's limit,
//! measured in one run.
//!
//! Lockstep: (0)–(4) the transport alone (the `deltaloop-baseline` crate: the tick pair in one
//! thread, in two threads
//! through shared memory, over iceoryx2 and over a Unix socket pair, nothing recorded, the median
//! of several interleaved rounds), then
//! the product's loops with the supervisor recording every tick: (c) inproc and (a) the real
//! process pair. Realtime: (d) the default, the split-CPU and the one-CPU yielding layouts at
//! 3.3 kHz, each with the CPU time the host took from its CPUs, and (e) the machine's own
//! wake-up limit (`machine`).
//! All of them step the same plant and controller tick on the same scenario.

mod machine;

use deltaloop_baseline as baseline;
pub use deltaloop_baseline::{Handoff, iox_controller, uds_controller};

use crate::ops::bench::s1_hold_study;
use anyhow::{Context, Result};
use deltaloop_config::Law;
use deltaloop_config::Layout;
use deltaloop_config::LoopMode;
use deltaloop_config::ResolvedLayout;
use deltaloop_runner::inproc;
use deltaloop_runner::lawrun::Keep;
use deltaloop_runner::procs;
use deltaloop_study::Study;
use deltaloop_timing::{StealMs, TimingSummary};
use hdrhistogram::Histogram;
use std::path::Path;
use std::time::Instant;

/// The median and range of `v` (not empty).
fn median_range(v: &[f64]) -> (f64, f64, f64) {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let n = s.len();
    let med = if n % 2 == 1 {
        s[n / 2]
    } else {
        0.5 * (s[n / 2 - 1] + s[n / 2])
    };
    (med, s[0], s[n - 1])
}

/// What the lockstep half measured.
struct Lockstep {
    /// Transport alone, µs per cycle over the one-thread tick pair (median of the rounds): two
    /// threads through shared memory (no transport), iceoryx2, a Unix socket.
    shm_us: f64,
    iox_us: f64,
    uds_us: f64,
    /// The same over iceoryx2 on one CPU, both sides blocking on wake-up events.
    one_cpu_us: f64,
    /// iceoryx2's own code per cycle: both messages through it in one thread, µs over the
    /// one-thread tick pair (median of the rounds), and its per-cycle p50.
    api_us: f64,
    api_handoff_us: f64,
    /// The hand-off measured on every cycle, p50 over all rounds, µs: shared memory, iceoryx2
    /// polling, socket.
    shm_handoff_us: f64,
    iox_handoff_us: f64,
    uds_handoff_us: f64,
    /// The product's lockstep loop: cycles/s of the process pair and of inproc, and the hand-off.
    iox_hz: f64,
    inproc_hz: f64,
    handoff_us: f64,
    /// Every attempt at the transport-alone phase was disturbed by the host; how many were made.
    disturbed: bool,
    attempts: u32,
}

/// Attempts at the transport-alone phase before its figures are printed marked as disturbed.
const PHASE_ATTEMPTS: u32 = 3;

/// Rounds of one series whose fastest and slowest cycle rates differ more than this (×) did not
/// measure the same thing: the host took a CPU in some of them. Undisturbed phases here spread
/// 1.00-1.17×; one with a host burst, 1.39× and more.
const MAX_SPREAD: f64 = 1.25;

/// Share of a pinned CPU's time the host may take (hypervisor steal, `/proc/stat`) during the
/// phase before it is called disturbed.
const MAX_STEAL_SHARE: f64 = 0.01;

/// Why a phase's figures cannot be trusted.
#[derive(Clone, Debug, PartialEq)]
struct Disturbance {
    reason: String,
    /// How far past its threshold the worst sign is (1 = at it), to pick the least disturbed.
    excess: f64,
}

/// None < any disturbance, then by excess.
fn severity(d: &Option<Disturbance>) -> f64 {
    d.as_ref().map_or(0.0, |d| d.excess)
}

/// Whether the rounds of a phase were disturbed: `series` are the per-round cycle rates
/// (cycles/s) of each measurement, by name; `taken` the share of each pinned CPU's time the host
/// took during the phase (0..1). None when every series agrees within [`MAX_SPREAD`] and no CPU
/// lost more than [`MAX_STEAL_SHARE`].
fn disturbance(series: &[(&str, &[f64])], taken: &[(usize, f64)]) -> Option<Disturbance> {
    let mut signs = Vec::new();
    for (name, v) in series {
        let (lo, hi) = v.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), &x| {
            (lo.min(x), hi.max(x))
        });
        if v.len() > 1 && lo > 0.0 && hi / lo > MAX_SPREAD {
            signs.push((
                hi / lo / MAX_SPREAD,
                format!(
                    "rounds of {name} spread {:.2}x ({lo:.0}..{hi:.0} cycles/s)",
                    hi / lo
                ),
            ));
        }
    }
    for &(cpu, share) in taken {
        if share > MAX_STEAL_SHARE {
            signs.push((
                share / MAX_STEAL_SHARE,
                format!("the host took {:.1} % of CPU {cpu}", share * 100.0),
            ));
        }
    }
    if signs.is_empty() {
        return None;
    }
    signs.sort_by(|a, b| b.0.total_cmp(&a.0));
    Some(Disturbance {
        excess: signs[0].0,
        reason: signs
            .into_iter()
            .map(|(_, r)| r)
            .collect::<Vec<_>>()
            .join(", "),
    })
}

/// One transport-alone measurement over the rounds.
struct Series {
    /// Cycle rate of each round, cycles/s.
    hz: Vec<f64>,
    /// The same less the one-thread tick pair, µs per cycle.
    cost_us: Vec<f64>,
    /// The hand-off of every cycle, all rounds.
    hand: Histogram<u64>,
}

impl Series {
    fn new() -> Self {
        Self {
            hz: vec![],
            cost_us: vec![],
            hand: deltaloop_timing::latency_histogram(),
        }
    }

    /// One round's measurement, against the one-thread tick pair's `raw` cycles/s.
    fn push(&mut self, m: &baseline::Measured, raw: f64) -> Result<()> {
        self.cost_us.push(1e6 / m.hz - 1e6 / raw);
        self.hand
            .add(&m.handoff)
            .context("merge hand-off histograms")?;
        self.hz.push(m.hz);
        Ok(())
    }

    /// The p50 hand-off, µs.
    fn hand_p50_us(&self) -> f64 {
        self.hand.value_at_quantile(0.5) as f64 / 1e3
    }
}

/// The per-round figures of the transport-alone phase.
struct Rounds {
    /// (1) the tick pair in one thread, cycles/s.
    raw: Vec<f64>,
    /// (0) two threads through shared memory.
    shm: Series,
    /// (2) iceoryx2, both sides polling.
    iox: Series,
    /// (4) iceoryx2 on one CPU, both sides blocking.
    one: Series,
    /// (3) the Unix socket (its better layout of the round).
    uds: Series,
    /// (5) iceoryx2 in one thread.
    api: Series,
}

impl Rounds {
    fn series(&self) -> [(&'static str, &[f64]); 6] {
        [
            ("(0)", &self.shm.hz),
            ("(1)", &self.raw),
            ("(2)", &self.iox.hz),
            ("(3)", &self.uds.hz),
            ("(4)", &self.one.hz),
            ("(5)", &self.api.hz),
        ]
    }
}

/// `repeats` interleaved rounds of the transport alone (a drift of the machine hits all); the
/// socket's best layout is its baseline (one CPU each, or both on one CPU).
fn transport_rounds(
    ls: &Study,
    cfg_path: &Path,
    ls_dir: &Path,
    pc: Option<usize>,
    cc: Option<usize>,
    repeats: u32,
) -> Result<Rounds> {
    let mut r = Rounds {
        raw: vec![],
        shm: Series::new(),
        iox: Series::new(),
        one: Series::new(),
        uds: Series::new(),
        api: Series::new(),
    };
    for _ in 0..repeats.max(1) {
        let raw = baseline::raw_inproc(ls, pc)?;
        let s = baseline::shared_memory(ls, pc, cc)?;
        let a = baseline::iox_one_thread(ls, pc)?;
        let i = baseline::iox_lockstep(ls, cfg_path, pc, cc, Handoff::Polling)?;
        let o = baseline::iox_lockstep(ls, cfg_path, cc, cc, Handoff::Blocking)?;
        let (us, uo) = (
            baseline::uds_lockstep(ls, cfg_path, ls_dir, pc, cc)?,
            baseline::uds_lockstep(ls, cfg_path, ls_dir, cc, cc)?,
        );
        let u = if us.hz >= uo.hz { us } else { uo };
        r.shm.push(&s, raw)?;
        r.iox.push(&i, raw)?;
        r.one.push(&o, raw)?;
        r.uds.push(&u, raw)?;
        r.api.push(&a, raw)?;
        r.raw.push(raw);
    }
    Ok(r)
}

/// Runs every measurement and prints; the last line is the machine-readable summary.
/// `explain`: each realtime run also names its misses' causes (`--explain`).
pub fn run(
    lockstep_seconds: f64,
    rt_seconds: f64,
    repeats: u32,
    out: &Path,
    explain: bool,
) -> Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    println!(
        "deltaloop bench loop: lockstep/inproc {lockstep_seconds} s simulated ({} ticks) x {repeats} rounds, realtime {rt_seconds} s at 3.3 kHz; machine: {} logical CPUs, kernel {}",
        (lockstep_seconds / 3e-4).round(),
        std::thread::available_parallelism().map_or(0, |n| n.get()),
        std::fs::read_to_string("/proc/sys/kernel/osrelease")
            .map_or("?".into(), |s| s.trim().to_string())
    );
    let ls = s1_hold_study("bench-loop", lockstep_seconds)?;
    let lsf = lockstep(&ls, repeats, out)?;
    // (d) realtime, the default layout, the split-CPU one and the one-CPU yielding one, then (e)
    // the machine's own limit.
    let budget_us = f64::from(ls.config.loop_.torque_budget_us);
    let rt_default = realtime(
        out,
        "realtime",
        rt_seconds,
        Layout::realtime_default(),
        explain,
    )?;
    let rt_split = realtime(
        out,
        "realtime-split",
        rt_seconds,
        Layout::realtime_split_cpus(),
        explain,
    )?;
    let split_cpu = Layout::realtime_split_cpus().resolve().controller_cpu;
    let sp = rt_split.summary();
    let split_steal = steal_share(&sp.cpu_steal_ms, sp.loop_wall_s, split_cpu);
    if let (Some(c), Some((ms, share))) = (split_cpu, split_steal) {
        println!(
            "    the host took {ms:.0} ms from CPU {c}, the split layout's controller CPU: {share:.1e} of the run (counted in 10 ms steps: {:.1e}), against a miss ratio of {:.1e}; a controller alone on a CPU cannot answer while the host holds it or wakes it late from idle (not counted as taken; docs/guide/loop-modes.md), so its misses follow the host, not the loop",
            10e-3 / sp.loop_wall_s.max(1e-9),
            sp.miss_ratio
        );
    }
    let rt_yield = realtime(
        out,
        "realtime-yield",
        rt_seconds,
        Layout::realtime_one_cpu_yield(),
        explain,
    )?;
    let lay = Layout::realtime_default().resolve();
    let (machine, cyclic) = machine_limit(&lay, ls.config.ts_ns(), rt_seconds)?;
    let m = |h: &Histogram<u64>, q: f64| h.value_at_quantile(q) as f64 / 1e3;
    let d = rt_default.summary();
    let y = rt_yield.summary();
    println!(
        "loop vs machine (p99.9): round trip {:.1} us (default layout), {:.1} us (split CPUs), {:.1} us (one CPU, yielding) vs machine wake lateness {:.1} us; the plant's wake lateness {:.1} us (default), {:.1} us (yielding), both waking {} us early, {:.1} us (split, {} us early)",
        d.round_trip.p999_us,
        sp.round_trip.p999_us,
        y.round_trip.p999_us,
        m(&machine, 0.999),
        d.wake_lateness.p999_us,
        y.wake_lateness.p999_us,
        lay.wake_early_us,
        sp.wake_lateness.p999_us,
        Layout::realtime_split_cpus().resolve().wake_early_us
    );
    let mut hists: Vec<(&str, &Histogram<u64>)> = vec![
        ("round trip, default", &rt_default.round_trip.hist),
        ("round trip, split CPUs", &rt_split.round_trip.hist),
        ("round trip, one CPU yielding", &rt_yield.round_trip.hist),
        ("wake lateness, default", &rt_default.wake_lateness.hist),
        ("sleep-only loop", &machine),
    ];
    if let Ok(h) = &cyclic {
        hists.push(("cyclictest", h));
    }
    deltaloop_report::plot::latency_percentiles(
        &out.join("latency"),
        "bench loop: realtime round trip and wake lateness vs the machine",
        &hists,
        Some(budget_us),
    )?;
    println!("figure: {}", out.join("latency.png").display());
    println!(
        "{}",
        summary_line(&SummaryInput {
            lockstep: &lsf,
            realtime: [("rt", &d), ("rt_split", &sp), ("rt_yield", &y)],
            split_steal_share: split_steal.map(|(_, f)| f),
            machine_wake_p999_us: m(&machine, 0.999),
            cyclictest_p999_us: cyclic.as_ref().ok().map(|h| m(h, 0.999)),
        })
    );
    Ok(())
}

/// cyclictest's wake lateness, or why it was not run.
type Cyclictest = std::result::Result<Histogram<u64>, String>;

/// (e) The machine's own wake-up limit on the plant's CPU and priority of `lay`: a sleep-only
/// loop every `ts_ns`, and cyclictest when it can run. Prints both.
fn machine_limit(
    lay: &ResolvedLayout,
    ts_ns: u64,
    seconds: f64,
) -> Result<(Histogram<u64>, Cyclictest)> {
    let (cpu, prio) = (lay.plant_cpu.unwrap_or(0), lay.plant_priority);
    let machine = machine::sleep_only_loop(cpu, prio, ts_ns, seconds)?;
    let cyclic = machine::cyclictest(cpu, prio, ts_ns / 1000, seconds);
    let m = |h: &Histogram<u64>, q: f64| h.value_at_quantile(q) as f64 / 1e3;
    println!(
        "(e) machine: a sleep-only loop on CPU {cpu} at {prio}, every {} us: wake lateness p50 {:.1} us, p99 {:.1} us, p99.9 {:.1} us, max {:.1} us",
        ts_ns / 1000,
        m(&machine, 0.5),
        m(&machine, 0.99),
        m(&machine, 0.999),
        machine.max() as f64 / 1e3
    );
    match &cyclic {
        Ok(h) => println!(
            "    cyclictest -m -p {} -i {} -a {cpu} -t 1: p50 {:.1} us, p99 {:.1} us, p99.9 {:.1} us, max {:.1} us",
            prio.key_value(),
            ts_ns / 1000,
            m(h, 0.5),
            m(h, 0.99),
            m(h, 0.999),
            h.max() as f64 / 1e3
        ),
        Err(why) => println!("    cyclictest: not run ({why})"),
    }
    Ok((machine, cyclic))
}

/// What the machine-readable summary line is made of.
struct SummaryInput<'a> {
    lockstep: &'a Lockstep,
    /// Each realtime layout by its key prefix.
    realtime: [(&'static str, &'a TimingSummary); 3],
    /// The share of the split layout's controller CPU the host took (None: not known).
    split_steal_share: Option<f64>,
    machine_wake_p999_us: f64,
    /// None: cyclictest was not run.
    cyclictest_p999_us: Option<f64>,
}

/// The last line of `bench loop`: `key=value` pairs, `na` for what was not measured.
fn summary_line(s: &SummaryInput<'_>) -> String {
    let l = s.lockstep;
    let mut kv: Vec<(String, String)> = [
        ("lockstep_transport_shm_us", format!("{:.3}", l.shm_us)),
        ("lockstep_transport_iox_us", format!("{:.3}", l.iox_us)),
        ("lockstep_transport_uds_us", format!("{:.3}", l.uds_us)),
        (
            "transport_one_cpu_blocking_us",
            format!("{:.3}", l.one_cpu_us),
        ),
        ("handoff_shm_p50_us", format!("{:.2}", l.shm_handoff_us)),
        ("handoff_iox_p50_us", format!("{:.2}", l.iox_handoff_us)),
        ("handoff_uds_p50_us", format!("{:.2}", l.uds_handoff_us)),
        ("iox_one_thread_us", format!("{:.3}", l.api_us)),
        (
            "handoff_iox_one_thread_p50_us",
            format!("{:.2}", l.api_handoff_us),
        ),
        ("lockstep_iox_hz", format!("{:.0}", l.iox_hz)),
        ("inproc_hz", format!("{:.0}", l.inproc_hz)),
        (
            "lockstep_loop_us",
            format!("{:.3}", 1e6 / l.iox_hz - 1e6 / l.inproc_hz),
        ),
        ("lockstep_handoff_us", format!("{:.2}", l.handoff_us)),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v))
    .collect();
    for (prefix, t) in s.realtime {
        kv.push((
            format!("{prefix}_rtt_p50_us"),
            format!("{:.1}", t.round_trip.p50_us),
        ));
        kv.push((
            format!("{prefix}_rtt_p999_us"),
            format!("{:.1}", t.round_trip.p999_us),
        ));
        kv.push((
            format!("{prefix}_wake_p999_us"),
            format!("{:.1}", t.wake_lateness.p999_us),
        ));
        kv.push((
            format!("{prefix}_miss_ratio"),
            format!("{:.2e}", t.miss_ratio),
        ));
        kv.push((
            format!("{prefix}_rtf"),
            t.realtime_factor.map_or("na".into(), |f| format!("{f:.5}")),
        ));
        kv.push((format!("{prefix}_pauses"), t.pauses.to_string()));
        if prefix == "rt_split" {
            let share = s
                .split_steal_share
                .map_or("na".into(), |f| format!("{f:.2e}"));
            kv.push(("rt_split_steal_share".into(), share));
        }
    }
    let cyclic = s
        .cyclictest_p999_us
        .map_or("na".into(), |v| format!("{v:.1}"));
    kv.extend([
        (
            "machine_wake_p999_us".into(),
            format!("{:.1}", s.machine_wake_p999_us),
        ),
        ("cyclictest_p999_us".into(), cyclic),
        (
            "lockstep_transport_disturbed".into(),
            u8::from(l.disturbed).to_string(),
        ),
        ("lockstep_transport_attempts".into(), l.attempts.to_string()),
    ]);
    kv.iter()
        .map(|(k, v)| format!("{k}={v}"))
        .collect::<Vec<_>>()
        .join(" ")
}

/// The product's lockstep loops, then `repeats` interleaved rounds of the transport alone.
fn lockstep(ls: &Study, repeats: u32, out: &Path) -> Result<Lockstep> {
    let ls_dir = out.join("lockstep");
    std::fs::create_dir_all(&ls_dir)?;
    let cfg_path = ls_dir.join("config.toml");
    std::fs::write(&cfg_path, ls.config.to_toml_string())?;

    // The product's loops first, before anything pins this process: (c) inproc, (a) lockstep.
    let t0 = Instant::now();
    let run = inproc::run_law(ls, Law::TdcIsSta, &Keep::default())?;
    let inproc_hz = run.end.records as f64 / t0.elapsed().as_secs_f64();
    let pr = procs::run_law(
        ls,
        Law::TdcIsSta,
        LoopMode::Lockstep,
        &ls_dir,
        &Keep::default(),
        None,
    )?;
    let iox_hz = pr.timing.cycle_hz();
    let summary = pr.timing.summary();
    let rtt = summary.round_trip;
    // The hand-off itself, both ways: state published → reply received, less the law's compute.
    let handoff_us = rtt.p50_us - summary.controller_compute.p50_us;

    let lay = ls.config.loop_.lockstep.resolve();
    let (pc, cc) = (lay.plant_cpu, lay.controller_cpu);
    let phase = transport_phase(ls, &cfg_path, &ls_dir, (pc, cc), repeats)?;
    let costs = print_transport(&phase, (pc, cc));
    println!("lockstep, the product's loops (the supervisor records every tick):");
    println!(
        "(c) inproc:                        {inproc_hz:>9.0} cycles/s  ({:.3} us/cycle)",
        1e6 / inproc_hz
    );
    println!(
        "(a) lockstep, the process pair:    {iox_hz:>9.0} cycles/s  ({:.3} us/cycle, {:.3} us over inproc; round trip p50 {:.2} us, p99 {:.2} us, p99.9 {:.2} us)",
        1e6 / iox_hz,
        1e6 / iox_hz - 1e6 / inproc_hz,
        rtt.p50_us,
        rtt.p99_us,
        rtt.p999_us
    );
    println!(
        "    the hand-off itself (round trip p50 less the law's compute p50): {handoff_us:.2} us per cycle, both ways, no system call; beyond the transport, the pair shares the 2 CPUs with the supervisor reading and writing every tick"
    );
    let r = &phase.rounds;
    Ok(Lockstep {
        disturbed: phase.disturbed.is_some(),
        attempts: phase.attempts,
        shm_handoff_us: r.shm.hand_p50_us(),
        api_handoff_us: r.api.hand_p50_us(),
        api_us: costs.api_us,
        iox_handoff_us: r.iox.hand_p50_us(),
        uds_handoff_us: r.uds.hand_p50_us(),
        shm_us: costs.shm_us,
        iox_us: costs.iox_us,
        one_cpu_us: costs.one_us,
        uds_us: costs.uds_us,
        iox_hz,
        inproc_hz,
        handoff_us,
    })
}

/// One realtime run of `seconds` on the S1 hold with `layout`, in `out/<name>`; its timing, with
/// the `.hgrm` files and figures written there (and with `explain` its misses' causes).
fn realtime(
    out: &Path,
    name: &str,
    seconds: f64,
    layout: Layout,
    explain: bool,
) -> Result<deltaloop_timing::Timing> {
    let mut rs = s1_hold_study("bench-loop", seconds)?;
    rs.config.loop_.realtime = layout;
    rs.config.record.explain = explain;
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
        None,
    )?;
    pr.timing.write_hgrm(&dir, "tdc-is-sta.")?;
    let budget = f64::from(rs.config.loop_.torque_budget_us);
    deltaloop_report::plot::timing_figures(
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
        "(d) {name:<15} round trip p50 {:.1} us, p99 {:.1} us, p99.9 {:.1} us, max {:.1} us; wake lateness p99.9 {:.1} us; misses {} of {} ({:.2e}); real-time factor {} ({} pauses, {:.1} ms); CPU stolen by the host: {}",
        t.round_trip.p50_us,
        t.round_trip.p99_us,
        t.round_trip.p999_us,
        t.round_trip.max_us,
        t.wake_lateness.p999_us,
        t.deadline_misses,
        t.ticks,
        t.miss_ratio,
        t.realtime_factor
            .map_or("n/a".into(), |f| format!("{f:.5}")),
        t.pauses,
        t.paused_ms,
        if steal.is_empty() {
            "n/a".into()
        } else {
            steal.join(", ")
        }
    );
    if let Some(x) = &pr.timing.explained {
        println!(
            "    misses by cause: {}; late ticks: {} ({}/tdc-is-sta.misses.csv)",
            x.words().unwrap_or_else(|| "none".into()),
            x.late_words().unwrap_or_else(|| "none".into()),
            dir.display()
        );
    }
    Ok(pr.timing)
}

// The transport phase: iceoryx2, a Unix socket and in-process, round for round, with what the
// host took in between.
/// The transport-alone phase as printed: its rounds, and whether the host disturbed it.
struct Phase {
    rounds: Rounds,
    disturbed: Option<Disturbance>,
    attempts: u32,
}

/// The transport alone, pinned as lockstep is (`cpus`: plant, controller). A phase the host
/// disturbed (rounds that disagree, CPU time taken from the pinned CPUs) is repeated; if every
/// attempt was disturbed, the least disturbed one is kept, marked (regression: one noisy minute
/// printed a transport cost of 11.5 µs against 1.1-1.25 µs before and after, as the figure).
fn transport_phase(
    ls: &Study,
    cfg_path: &Path,
    ls_dir: &Path,
    cpus: (Option<usize>, Option<usize>),
    repeats: u32,
) -> Result<Phase> {
    let (pc, cc) = cpus;
    let mut attempts = 0;
    let mut best: Option<(Rounds, Option<Disturbance>)> = None;
    while attempts < PHASE_ATTEMPTS {
        attempts += 1;
        let steal_before = deltaloop_timing::steal_jiffies();
        let t0 = Instant::now();
        let r = transport_rounds(ls, cfg_path, ls_dir, pc, cc, repeats)?;
        let wall_s = t0.elapsed().as_secs_f64();
        let stolen =
            deltaloop_timing::steal_ms_between(&steal_before, &deltaloop_timing::steal_jiffies());
        let taken: Vec<(usize, f64)> = stolen
            .iter()
            .filter(|s| [pc, cc].contains(&Some(s.cpu)))
            .map(|s| (s.cpu, s.ms * 1e-3 / wall_s.max(1e-9)))
            .collect();
        let d = disturbance(&r.series(), &taken);
        let better = best
            .as_ref()
            .is_none_or(|(_, bd)| severity(&d) < severity(bd));
        let clean = d.is_none();
        if let Some(why) = &d {
            println!(
                "lockstep, the transport alone: attempt {attempts} of {PHASE_ATTEMPTS} disturbed ({}){}",
                why.reason,
                if attempts < PHASE_ATTEMPTS {
                    "; repeating it"
                } else {
                    ""
                }
            );
        }
        if better {
            best = Some((r, d));
        }
        if clean {
            break;
        }
    }
    let (rounds, disturbed) = best.expect("at least one attempt");
    Ok(Phase {
        rounds,
        disturbed,
        attempts,
    })
}

/// Transport costs per cycle over the one-thread tick pair, median of the rounds, µs.
struct Costs {
    shm_us: f64,
    iox_us: f64,
    uds_us: f64,
    one_us: f64,
    api_us: f64,
}

/// Prints the transport-alone phase (`cpus`: plant, controller); returns its median costs.
fn print_transport(phase: &Phase, cpus: (Option<usize>, Option<usize>)) -> Costs {
    let Phase {
        rounds: r,
        disturbed,
        attempts,
    } = phase;
    let line = |name: &str, v: &[f64]| {
        let (m, lo, hi) = median_range(v);
        println!(
            "{name:<34} {m:>9.0} cycles/s  ({:.3} us/cycle; rounds {lo:.0}..{hi:.0}/s)",
            1e6 / m
        );
    };
    println!(
        "lockstep, the transport alone (the tick pair, nothing recorded; plant CPU {}, controller CPU {}; median of {} rounds):",
        fmt_cpu(cpus.0),
        fmt_cpu(cpus.1),
        r.raw.len()
    );
    line("(0) two threads, shared memory:", &r.shm.hz);
    line("(1) one thread:", &r.raw);
    line("(2) iceoryx2, both sides polling:", &r.iox.hz);
    line("(3) Unix socket, blocking:", &r.uds.hz);
    line("(4) iceoryx2, one CPU, blocking:", &r.one.hz);
    line("(5) iceoryx2, one thread:", &r.api.hz);
    let (shm_us, slo, shi) = median_range(&r.shm.cost_us);
    let (iox_us, ilo, ihi) = median_range(&r.iox.cost_us);
    let (uds_us, ulo, uhi) = median_range(&r.uds.cost_us);
    let (one_us, olo, ohi) = median_range(&r.one.cost_us);
    let (api_us, alo, ahi) = median_range(&r.api.cost_us);
    println!(
        "transport cost per cycle ((2) or (3) less (1)): iceoryx2 {iox_us:.3} us (rounds {ilo:.3}..{ihi:.3}), Unix socket {uds_us:.3} us (rounds {ulo:.3}..{uhi:.3}): iceoryx2 {:.1}x cheaper{}",
        uds_us / iox_us,
        disturbed.as_ref().map_or(String::new(), |d| format!(
            "; DISTURBED after {attempts} attempts ({}): not a measure of the transport",
            d.reason
        ))
    );
    println!(
        "    the machine's floor, two threads polling one shared slot each way ((0) less (1), no transport, no system call): {shm_us:.3} us (rounds {slo:.3}..{shi:.3})"
    );
    println!(
        "    on one CPU, each side blocking on a wake-up event ((4) less (1), the default realtime layout's hand-offs): {one_us:.3} us (rounds {olo:.3}..{ohi:.3})"
    );
    let q = |h: &Histogram<u64>, p: f64| h.value_at_quantile(p) as f64 / 1e3;
    println!(
        "the hand-off measured on every cycle (state sent -> reply received, less the helper's own time; all rounds): shared memory p50 {:.2} us, p99 {:.2} us; iceoryx2 polling p50 {:.2} us, p99 {:.2} us; iceoryx2 one CPU blocking p50 {:.2} us, p99 {:.2} us; Unix socket p50 {:.2} us, p99 {:.2} us",
        q(&r.shm.hand, 0.5),
        q(&r.shm.hand, 0.99),
        q(&r.iox.hand, 0.5),
        q(&r.iox.hand, 0.99),
        q(&r.one.hand, 0.5),
        q(&r.one.hand, 0.99),
        q(&r.uds.hand, 0.5),
        q(&r.uds.hand, 0.99)
    );
    println!(
        "    iceoryx2 over the machine's floor: {:.2} us per cycle (p50 hand-off), {:.3} us (cycle rate)",
        r.iox.hand_p50_us() - r.shm.hand_p50_us(),
        iox_us - shm_us
    );
    let (own, polled) = (r.api.hand_p50_us(), r.iox.hand_p50_us());
    println!(
        "what bounds (2), per cycle at p50: iceoryx2's own code {own:.2} us (both messages sent and taken back in one thread, (5): no second CPU), and {:.2} us for what it moves between the two CPUs (its polling p50 {polled:.2} us less that), where one shared slot each way moves them in {:.2} us (0); by cycle rate, (5) less (1): {api_us:.3} us (rounds {alo:.3}..{ahi:.3})",
        polled - own,
        r.shm.hand_p50_us()
    );
    Costs {
        shm_us,
        iox_us,
        uds_us,
        one_us,
        api_us,
    }
}

/// CPU time the host took from `cpu` during the run (ms) and its share of the loop's wall time.
fn steal_share(steal: &[StealMs], loop_wall_s: f64, cpu: Option<usize>) -> Option<(f64, f64)> {
    let c = cpu?;
    let ms = steal.iter().find(|s| s.cpu == c)?.ms;
    (loop_wall_s > 0.0).then(|| (ms, ms * 1e-3 / loop_wall_s))
}

fn fmt_cpu(c: Option<usize>) -> String {
    c.map_or("any".into(), |c| c.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_range_takes_the_middle_or_the_mean_of_the_two_middles() {
        assert_eq!(median_range(&[3.0, 1.0, 2.0]), (2.0, 1.0, 3.0));
        assert_eq!(median_range(&[4.0, 1.0, 2.0, 3.0]), (2.5, 1.0, 4.0));
        assert_eq!(median_range(&[5.0]), (5.0, 5.0, 5.0));
    }

    /// Regression: in one noisy minute the transport cost came out at 11.5 µs (against 1.1-1.25
    /// µs before and after) and was printed as the figure.
    #[test]
    fn regression_a_phase_whose_rounds_disagree_or_lost_cpu_time_is_disturbed() {
        // Measured rounds: a clean phase (spread ≤ 1.17x) ...
        let clean: [(&str, &[f64]); 3] = [
            ("(1)", &[121_222.0, 122_593.0, 121_975.0]),
            ("(2)", &[91_833.0, 107_542.0, 105_307.0]),
            ("(3)", &[47_577.0, 49_015.0, 48_907.0]),
        ];
        assert_eq!(disturbance(&clean, &[(0, 0.002), (1, 0.0)]), None);
        // ... and a disturbed one (1.39x), named with the series and its range.
        let noisy: [(&str, &[f64]); 2] = [
            ("(1)", &[86_829.0, 121_437.0, 118_246.0]),
            ("(2)", &[73_745.0, 102_676.0, 100_996.0]),
        ];
        let d = disturbance(&noisy, &[]).unwrap();
        assert!(
            d.reason
                .starts_with("rounds of (1) spread 1.40x (86829..121437 cycles/s)"),
            "{}",
            d.reason
        );
        assert!(
            d.reason.contains("rounds of (2) spread 1.39x"),
            "{}",
            d.reason
        );
        // CPU time the host took from a pinned CPU, even with rounds that agree.
        let d = disturbance(&clean, &[(1, 0.05)]).unwrap();
        assert_eq!(d.reason, "the host took 5.0 % of CPU 1");
        assert!((d.excess - 5.0).abs() < 1e-9);
        // The least disturbed attempt is kept.
        assert!(severity(&None) < severity(&Some(d.clone())));
        // One round cannot disagree with itself.
        assert_eq!(disturbance(&[("(2)", &[50_000.0])], &[]), None);
    }

    #[test]
    fn steal_share_is_the_stolen_time_of_that_cpu_over_the_loop_time() {
        let steal = [StealMs { cpu: 0, ms: 30.0 }, StealMs { cpu: 1, ms: 90.0 }];
        assert_eq!(steal_share(&steal, 60.0, Some(1)), Some((90.0, 1.5e-3)));
        assert_eq!(steal_share(&steal, 60.0, Some(0)), Some((30.0, 5e-4)));
        assert_eq!(steal_share(&steal, 60.0, Some(2)), None);
        assert_eq!(steal_share(&steal, 60.0, None), None);
        assert_eq!(steal_share(&steal, 0.0, Some(0)), None);
    }
}
