//! A realtime run of the real process pair: it tracks S1 as well as the inproc run allows, given
//! its measured latency and the deadlines it missed, writes its timing histograms, and replays
//! byte for byte; the overrun policy when the plant's own process is stopped mid-run; and
//! `deltaloop bench loop` end to end. Their own test binary, so no other test's processes share
//! the CPUs with them (cargo runs test binaries one at a time), and one at a time within it (they
//! pin SCHED_FIFO loops to the same CPU). What must hold whatever the host does is asserted on
//! every run; what depends on timing only on a run whose own record says the machine left it
//! alone (`common::on_a_noisy_host`).

use crate::common;

use common::{
    FaultKind, RunStatus, assert_clean, assert_every_tick_on_disk, assert_replays, disturbance,
    judge, missed_too_many, on_a_noisy_host, outcome, run, run_output, summary,
};
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Mutex;
use std::time::Duration;

/// Held by each test: two FIFO loops on one CPU would starve each other.
pub(crate) static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

/// Whether the realtime run `sr` of `laws` tracked each joint within its allowance of the inproc
/// run `si` (given the deadlines it missed); the first breach otherwise.
fn tracking_within_allowance(si: &Value, sr: &Value, laws: &[&str]) -> Result<(), String> {
    for &law in laws {
        let m = &sr["laws"][law];
        let t = &sr["timing"][law];
        if m["completed"] != true {
            return Err(format!("{law}: not completed: {m}"));
        }
        let misses = t["deadline_misses"].as_f64().unwrap();
        if t["miss_ratio"].as_f64().unwrap() >= 0.05 {
            return Err(format!("{law}: miss ratio ≥ 5 %: {t}"));
        }
        for j in 0..3 {
            let (r, i) = (
                m["rms_rad"][j].as_f64().unwrap(),
                si["laws"][law]["rms_rad"][j].as_f64().unwrap(),
            );
            // Each missed deadline holds the last torque for a tick. With the matched laws tracking
            // to ~4e-8 rad, that shows: measured on 2 vCPUs, 9 / 36 / 72 misses raised tde-is's
            // joint-0 RMS by 0.19 / 0.44 / 0.69 µrad. The allowance, 1 µrad + 0.1 µrad per miss,
            // tops out at 14 µrad at the 5 % miss ceiling below: still 30x under the smallest wiring
            // error, one extra tick of delay, which costs tde-is 4e-4 rad (docs/delay-sweep).
            let allowed = 3.0 * i + 1e-6 + 1e-7 * misses;
            if r >= allowed {
                return Err(format!(
                    "{law} joint {j}: realtime {r:e} vs inproc {i:e}, allowed {allowed:e} \
                     with {misses} misses; timing: {t}"
                ));
            }
        }
    }
    Ok(())
}

/// What the records of `laws` in `s` say disturbed the run, all of it; None for none.
fn disturbance_of(s: &Value, laws: &[&str]) -> Option<String> {
    let why: Vec<String> = laws.iter().filter_map(|l| disturbance(s, l)).collect();
    (!why.is_empty()).then(|| why.join(" | "))
}

/// Each law's `.hgrm` files are written and hold a real distribution.
fn assert_histograms(out: &Path, laws: &[&str]) {
    for law in laws {
        for h in [
            "round_trip",
            "wake_lateness",
            "period_jitter",
            "state_to_controller",
            "controller_compute",
        ] {
            let text = std::fs::read_to_string(out.join(format!("{law}.{h}.hgrm"))).unwrap();
            assert!(
                text.lines()
                    .filter(|l| l.trim_start().starts_with(|c: char| c.is_ascii_digit()))
                    .count()
                    > 10,
                "{law}.{h}.hgrm is thin"
            );
        }
    }
}

#[test]
fn realtime_run_tracks_s1_close_to_inproc_and_writes_histograms() {
    let test = "realtime_run_tracks_s1_close_to_inproc_and_writes_histograms";
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let tmp = tempfile::tempdir().unwrap();
    let laws = ["tde-is", "pid"];
    let args = ["--law", "tde-is", "--law", "pid"];
    let si = run(
        "configs/s1-nominal.toml",
        "inproc",
        &tmp.path().join("inproc"),
        &args,
    );
    // The host may stall the loop for milliseconds (a shared 2-vCPU VM; regression: one stall of
    // 5 ms, 78 misses, failed this test while another build ran).
    on_a_noisy_host(test, |n| {
        let b = tmp.path().join(format!("rt-{n}"));
        let o = run_output("configs/s1-nominal.toml", "realtime", &b, &args);
        let err = String::from_utf8_lossy(&o.stderr);
        let sr = summary(&b);
        // Whatever the host did: each law ended with a typed status (the exit status says
        // whether all are ok), every tick it ran is on disk, the round trip was measured, the
        // run replays byte for byte from its folder alone, and nothing is left behind.
        // The run stops at the first law that does not end ok: the laws after it never ran
        // (regression: `tde-is` faulted on a loaded host and the test panicked reading `pid`).
        let ran: Vec<&str> = laws
            .into_iter()
            .filter(|l| !sr["laws"][l].is_null())
            .collect();
        let mut all_ok = true;
        for law in laws {
            if !ran.contains(&law) {
                assert!(
                    !all_ok,
                    "{law} did not run though the laws before it ended ok: {err}"
                );
                continue;
            }
            all_ok &= assert_every_tick_on_disk(&sr, &b, law) == RunStatus::Ok;
            let t = &sr["timing"][law];
            assert!(t["round_trip"]["p50_us"].as_f64().unwrap() > 0.0, "{t}");
        }
        assert_eq!(o.status.success(), all_ok, "{err}");
        assert_replays(&b);
        crate::whatif::assert_as_recorded_replays(&b, &ran);
        assert_clean(&b, &sr);
        let report = std::fs::read_to_string(b.join("report.md")).unwrap();
        assert!(
            report.contains("## Loop timing (realtime)") && report.contains("deadline misses"),
            "{report}"
        );
        assert!(report.contains("### The plant's own stalls"), "{report}");
        // Each reply acted at its measured arrival, recorded per tick: measured from the tick's
        // deadline, a real latency (tens of µs at the median), never absurd.
        let trace = std::fs::read_to_string(b.join("trace.csv")).unwrap();
        let mut arrivals: Vec<u64> = trace
            .lines()
            .skip(1)
            .filter_map(|l| l.rsplit(',').next()?.parse().ok())
            .collect();
        arrivals.sort_unstable();
        assert!(!arrivals.is_empty(), "no applied reply");
        let median = arrivals[arrivals.len() / 2];
        assert!(median > 1_000, "median arrival {median} ns");
        assert!(*arrivals.last().unwrap() < 1_000_000_000);

        // Regression: tick 0 was missed in most runs (iceoryx2 connected the ports, mapping each
        // peer's data segment, inside tick 0's budget; then the notifiers still opened their
        // listener's socket in the first notify: tick 0's round trip 135–190 µs of 150). The cause
        // is guarded deterministically by protocol/transport/tests/connect_now.rs. Here only what a
        // busy host cannot fake: a systematic regression misses tick 0 in every law of a run the
        // host left alone, while a disturbed tick 0 (it is the slowest tick of a run, ≈ 120 µs in
        // a debug build) may miss in any of them (seen: both, while another build ran).
        let tick0: Vec<String> = ran
            .iter()
            .map(|law| {
                let row0 = trace
                    .lines()
                    .find(|l| l.starts_with(&format!("{law},0,")))
                    .unwrap_or_else(|| panic!("no tick 0 of {law}"));
                row0.split(',').nth_back(2).unwrap().to_string()
            })
            .collect();
        judge(
            disturbance_of(&sr, &ran),
            if tick0.iter().any(|r| r == "applied") {
                Ok(())
            } else {
                Err(format!("tick 0 missed in every law: {tick0:?}"))
            },
        )?;

        // What depends on timing: both laws ran, completed and tracked as the inproc run allows.
        judge(
            disturbance_of(&sr, &ran),
            if ran.len() == laws.len() {
                tracking_within_allowance(&si, &sr, &laws)
            } else {
                Err(format!("the run stopped before {:?}", &laws[ran.len()..]))
            },
        )?;
        for law in laws {
            assert_eq!(sr["timing"][law]["ticks"], 2668, "{law}");
        }
        assert!(arrivals.len() > 5000, "{} arrivals", arrivals.len());
        assert_histograms(&b, &laws);
        assert!(report.contains("measured latency cost: RMS ×"), "{report}");
        Ok(())
    });
}

/// A compensated law in realtime over the process pair, with 150 µs of transport delay and the
/// delay measured from the drives' reports: the run replays byte for byte (the controller's
/// measurements, predictions and learned inertia are all deterministic in its inputs), the
/// trace carries M̂ for every answered tick, and, when the host left the run alone, `tde-is`
/// keeps its accuracy (within 10× of its inproc RMS with no delay, where uncompensated it loses
/// about 90× on S2 to 150 µs alone).
#[test]
fn a_compensated_realtime_run_measures_its_delay_and_replays() {
    let test = "a_compensated_realtime_run_measures_its_delay_and_replays";
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let tmp = tempfile::tempdir().unwrap();
    let si = run(
        "configs/s2-fast.toml",
        "inproc",
        &tmp.path().join("ideal"),
        &["--law", "tde-is"],
    );
    let ideal = common::max_joint_rms(&si, "tde-is");
    on_a_noisy_host(test, |n| {
        let b = tmp.path().join(format!("rt-{n}"));
        let args = [
            "--law",
            "tde-is",
            "--transport-delay-us",
            "150",
            "--compensate",
            "predict",
            "--compensate-delay",
            "measured",
        ];
        let o = run_output("configs/s2-fast.toml", "realtime", &b, &args);
        let sr = summary(&b);
        let status = assert_every_tick_on_disk(&sr, &b, "tde-is");
        // A divergence is a result (exit 0), judged below by the run's record.
        assert_eq!(
            o.status.success(),
            matches!(status, RunStatus::Ok | RunStatus::Diverged),
            "{status:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        assert_replays(&b);
        let mut r = csv::Reader::from_path(b.join("trace.csv")).unwrap();
        let head = r.headers().unwrap().clone();
        let at = |name: &str| head.iter().position(|h| h == name).unwrap();
        let (m_hat, reply) = (at("m_hat_1"), at("reply"));
        let rows: Vec<csv::StringRecord> = r.records().map(Result::unwrap).collect();
        let answered = rows.iter().filter(|x| &x[reply] == "applied").count();
        let known = rows.iter().filter(|x| !x[m_hat].is_empty()).count();
        // The supervisor's copy of the law steps on every reply it saw: all of them, unless it
        // fell behind the loop (then M̂ is unknown from the first reply it lost on).
        if sr["timing"]["tde-is"]["supervisor_lost_samples"]["torque"] == 0 {
            assert!(known >= answered, "M̂ on {known} rows, {answered} applied");
        }
        let rms = common::max_joint_rms(&sr, "tde-is");
        judge(
            disturbance_of(&sr, &["tde-is"]),
            if status == RunStatus::Ok && rms <= 10.0 * ideal {
                Ok(())
            } else {
                Err(format!(
                    "{status:?}: RMS {rms:.3e} rad, {:.1}× its inproc {ideal:.3e}",
                    rms / ideal
                ))
            },
        )
    });
}

/// The config of the stall tests: configs/s1-nominal.toml with `loop` (lines) added to `[loop]`.
fn s1_with_loop(dir: &Path, lines: &str) -> String {
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/s1-nominal.toml"),
    )
    .unwrap()
    .replace("[loop]\n", &format!("[loop]\n{lines}"));
    let p = dir.join("s1.toml");
    std::fs::write(&p, text).unwrap();
    p.display().to_string()
}

/// A stopped plant: how its run ended, its summary, and whether the stop landed inside the loop.
struct Stalled {
    err: String,
    code: Option<i32>,
    s: Value,
    /// The stop began after tick 0's wake and some tick (or the safe stop) woke after it ended:
    /// by this machine's CLOCK_MONOTONIC, which the plant's stamps in `tdc.timing.csv` use.
    landed: bool,
}

impl Stalled {
    /// What holds whatever the host did: a typed status that the exit code agrees with, every
    /// tick on disk, a byte-for-byte replay, nothing left behind. The status.
    fn assert_invariants(&self, out: &Path) -> RunStatus {
        let status = assert_every_tick_on_disk(&self.s, out, "tdc");
        assert_eq!(
            self.code == Some(0),
            // Exit 0: the run ended as the physics did (ok, or diverged: a result).
            status.is_physical(),
            "{}",
            self.err
        );
        assert_replays(out);
        assert_clean(out, &self.s);
        status
    }
}

/// The length of the stop, ms: 100 ticks, the freeze that once flung the robot (catch-up).
const STOP_MS: u64 = 30;

/// A realtime run of `tdc` on `config` with a 1 s hold (`extra` appended) into `out`, whose
/// plant process is stopped (SIGSTOP) for [`STOP_MS`] about 300 ms into the loop, then let go on
/// (SIGCONT), the way a host freezes a virtual CPU.
fn stall_the_plant(config: &str, out: &Path, extra: &[&str]) -> Stalled {
    let mut args = vec![
        "run",
        config,
        "--mode",
        "realtime",
        "--law",
        "tdc",
        "--hold-s",
        "1",
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let child = common::spawn(&args);
    let t0 = std::time::Instant::now();
    let plant = loop {
        let plant = common::children_mentioning(out.to_str().unwrap())
            .into_iter()
            .find(|p| {
                std::fs::read(format!("/proc/{p}/cmdline"))
                    .is_ok_and(|c| String::from_utf8_lossy(&c).contains("deltaloop-plant"))
            });
        if let Some(p) = plant.filter(|_| out.join("tdc.timing.csv").is_file()) {
            break p as i32;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "the loop never started"
        );
        std::thread::sleep(Duration::from_millis(5));
    };
    std::thread::sleep(Duration::from_millis(300));
    let stopped = deltaloop_transport::rt::now_ns();
    // SAFETY: stopping and resuming the run's plant, found by its command line (a grandchild of
    // this test, alive until the run ends).
    unsafe { libc::kill(plant, libc::SIGSTOP) };
    std::thread::sleep(Duration::from_millis(STOP_MS));
    unsafe { libc::kill(plant, libc::SIGCONT) };
    let resumed = deltaloop_transport::rt::now_ns();
    let o = common::finish_within(child, Duration::from_secs(120), "the stalled run");
    let mut wakes = csv::Reader::from_path(out.join("tdc.timing.csv")).unwrap();
    let wakes: Vec<u64> = wakes
        .records()
        .filter_map(|r| r.unwrap()[2].parse().ok())
        .collect();
    let landed = wakes.first().is_some_and(|&w| w < stopped) && wakes.iter().any(|&w| w > resumed);
    Stalled {
        err: String::from_utf8_lossy(&o.stderr).into_owned(),
        code: o.status.code(),
        s: summary(out),
        landed,
    }
}

/// Err (run again) for a stop that missed the loop: it came before tick 0 or after the last.
fn landed(st: &Stalled) -> Result<(), String> {
    st.landed.then_some(()).ok_or_else(|| {
        format!(
            "the {STOP_MS} ms stop missed the loop (no pause, worst wake {} µs late)",
            st.s["timing"]["tdc"]["wake_lateness"]["max_us"]
        )
    })
}

/// The default overrun policy, `stretch`: a plant stopped for 30 ms mid-run pauses simulated
/// time instead of running the backlog blind. The run completes, says where it paused (summary
/// and report), runs slower than real time for it, replays byte for byte, and tracks as an
/// undisturbed run does.
#[test]
fn a_stalled_plant_pauses_simulated_time_and_tracks_as_if_undisturbed() {
    let test = "a_stalled_plant_pauses_simulated_time_and_tracks_as_if_undisturbed";
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let tmp = tempfile::tempdir().unwrap();
    let si = run(
        "configs/s1-nominal.toml",
        "inproc",
        &tmp.path().join("inproc"),
        &["--law", "tdc", "--hold-s", "1"],
    );
    on_a_noisy_host(test, |n| {
        let out = tmp.path().join(format!("stretch-{n}"));
        let st = stall_the_plant("configs/s1-nominal.toml", &out, &[]);
        let s = &st.s;
        let t = &s["timing"]["tdc"];
        // Whatever the host did: a typed status, every tick on disk, a byte-for-byte replay, no
        // debris; and the host's own stalls, if any, paused the loop too (it never catches up).
        let status = st.assert_invariants(&out);
        landed(&st)?;
        let list = t["pause_list"].as_array().unwrap();
        let long = list
            .iter()
            .find(|p| p["ms"].as_f64().unwrap() >= STOP_MS as f64 - 5.0)
            .unwrap_or_else(|| panic!("no pause of the {STOP_MS} ms stop: {t}"));
        assert!(t["pauses"].as_u64().unwrap() >= 1, "{t}");
        // The total (ns, in ms) and each listed pause (in ms) round apart by a few 1e-15 ms.
        assert!(
            t["paused_ms"].as_f64().unwrap() + 1e-6 >= long["ms"].as_f64().unwrap(),
            "{t}"
        );
        // Paused, not caught up: no tick woke the stop's length late.
        assert!(
            t["wake_lateness"]["max_us"].as_f64().unwrap() < 1000.0 * (STOP_MS as f64 - 5.0),
            "{t}"
        );
        let rtf = t["realtime_factor"].as_f64().unwrap();
        assert!(rtf < 1.0 && rtf > 0.5, "real-time factor {rtf}: {t}");
        let tick = long["tick"].as_u64().unwrap();
        let report = std::fs::read_to_string(out.join("report.md")).unwrap();
        let stalls = report
            .split("### The plant's own stalls")
            .nth(1)
            .unwrap_or_else(|| panic!("no stalls section: {report}"));
        assert!(stalls.contains(&format!("- tick {tick} (t = ")), "{stalls}");
        assert!(!report.contains("**Frozen loop**"), "{report}");
        // What depends on timing beyond the stop (the stop itself makes the record say
        // "disturbed"; pauses of the host's own do no harm to the tracking either, which is the
        // point): completed and tracking as inproc does, unless the misses say otherwise.
        let disturbed = disturbed_beyond_the_stop(s, tick);
        judge(
            disturbed.clone(),
            (status == RunStatus::Ok)
                .then_some(())
                .ok_or(format!("{status:?}: {}", st.err)),
        )?;
        judge(disturbed, tracking_within_allowance(&si, s, &["tdc"]))
    });
}

/// What disturbed a run whose plant was stopped on purpose at `stop_tick`, beyond that stop:
/// misses past the classifier's bounds, the host taking CPU time (steal) or the plant's own
/// process stalling elsewhere (regression: 10 ms of steal and two more pauses of the plant
/// cost 15 misses and the tracking allowance, and the test called that undisturbed).
fn disturbed_beyond_the_stop(s: &Value, stop_tick: u64) -> Option<String> {
    let t = &s["timing"]["tdc"];
    let steal_ms: f64 = t["cpu_steal_ms"]
        .as_array()
        .map(|a| a.iter().filter_map(|c| c["ms"].as_f64()).sum())
        .unwrap_or(0.0);
    let other_pauses = t["pause_list"]
        .as_array()
        .map_or(0, |a| a.iter().filter(|p| p["tick"] != stop_tick).count());
    missed_too_many(s, "tdc")
        .or_else(|| (steal_ms >= 1.0).then(|| format!("the host took {steal_ms} ms of CPU")))
        .or_else(|| {
            (other_pauses > 0).then(|| format!("the plant stalled {other_pauses} more time(s)"))
        })
}

/// `--overrun catch-up`, the old behaviour: the plant runs the stop's backlog on the wall clock
/// without control. No pause, the 30 ms late wake is recorded and named as a frozen loop.
#[test]
fn a_stalled_plant_with_catch_up_runs_the_backlog_and_names_the_freeze() {
    let test = "a_stalled_plant_with_catch_up_runs_the_backlog_and_names_the_freeze";
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let tmp = tempfile::tempdir().unwrap();
    on_a_noisy_host(test, |n| {
        let out = tmp.path().join(format!("catch-up-{n}"));
        let st = stall_the_plant("configs/s1-nominal.toml", &out, &["--overrun", "catch-up"]);
        let s = &st.s;
        let t = &s["timing"]["tdc"];
        // 100 ticks without control may fling the robot into a fault: any typed status will do.
        st.assert_invariants(&out);
        assert_eq!(t["pauses"], 0, "{t}");
        assert_eq!(t["paused_ms"], 0.0, "{t}");
        assert!(
            t["realtime_factor"].is_null() || t["realtime_factor"] == 1.0,
            "{t}"
        );
        landed(&st)?;
        let late_us = t["wake_lateness"]["max_us"].as_f64().unwrap();
        assert!(late_us >= 1000.0 * (STOP_MS as f64 - 5.0), "{t}");
        let report = std::fs::read_to_string(out.join("report.md")).unwrap();
        for text in [&st.err, &report] {
            assert!(text.contains("the plant once woke "), "{text}");
        }
        assert!(report.contains("**Frozen loop**"), "{report}");
        Ok(())
    });
}

/// `--overrun fault` (bound 20 ms, above what this host does to the plant on its own): the stop
/// ends the run as a fault of kind `plant_overrun`, after a safe stop, every tick up to the
/// fault on disk, the run replayable and nothing left behind.
#[test]
fn a_stalled_plant_with_fault_stops_the_run_as_a_plant_overrun() {
    let test = "a_stalled_plant_with_fault_stops_the_run_as_a_plant_overrun";
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let tmp = tempfile::tempdir().unwrap();
    let cfg = s1_with_loop(tmp.path(), "overrun_after_us = 20000\n");
    on_a_noisy_host(test, |n| {
        let out = tmp.path().join(format!("fault-{n}"));
        let st = stall_the_plant(&cfg, &out, &["--overrun", "fault"]);
        let s = &st.s;
        let status = assert_every_tick_on_disk(s, &out, "tdc");
        assert_replays(&out);
        assert_clean(&out, s);
        let (status, kind) = (status, outcome(s, "tdc").1);
        if status == RunStatus::Ok {
            // Only a stop that missed the loop leaves it running to its end.
            landed(&st)?;
        }
        assert_eq!(
            (status, kind),
            (RunStatus::Fault, Some(FaultKind::PlantOverrun)),
            "{}",
            st.err
        );
        assert_eq!(st.code, Some(1), "{}", st.err);
        let late_ms: f64 = st
            .err
            .split_once("overrun: the plant process woke ")
            .and_then(|(_, r)| r.split_once(" ms late")?.0.parse().ok())
            .unwrap_or_else(|| panic!("no overrun cause: {}", st.err));
        assert!(late_ms > 20.0, "{}", st.err);
        assert!(st.err.contains("safe stop"), "{}", st.err);
        let m = &s["laws"]["tdc"];
        assert_eq!(m["completed"], false, "{m}");
        assert_eq!(m["fault_at_tick"], m["ticks"].as_u64().unwrap() + 1, "{m}");
        Ok(())
    });
}

/// What says the machine disturbed the yielding layout's run of `deltaloop bench loop`: its
/// plant paused (`rt_yield_pauses`) or woke a tick late (`rt_yield_wake_p999_us`), or the host
/// stole CPU time (its `(d) realtime-yield` line); None for nothing.
fn yield_run_disturbed(kv: &BTreeMap<&str, &str>, line: &str) -> Option<String> {
    let num = |k: &str| kv[k].parse::<f64>().unwrap();
    let stolen = line
        .split_once("CPU stolen by the host: ")
        .map_or("", |(_, r)| r);
    let stole = stolen
        .split(", ")
        .any(|c| c.split(' ').nth(1).and_then(|ms| ms.parse::<f64>().ok()) > Some(0.0));
    (num("rt_yield_pauses") > 0.0 || num("rt_yield_wake_p999_us") >= 300.0 || stole)
        .then(|| line.to_string())
}

/// `deltaloop bench loop`, short: every baseline and loop runs to its end, the helpers exit, the
/// last line carries every key with a number, and the files docs/performance.md points at are there.
#[test]
fn bench_loop_runs_every_measurement_and_ends_with_its_key_value_line() {
    let test = "bench_loop_runs_every_measurement_and_ends_with_its_key_value_line";
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let tmp = tempfile::tempdir().unwrap();
    on_a_noisy_host(test, |n| {
        bench_loop_once(&tmp.path().join(format!("bench-{n}")))
    });
}

/// One `deltaloop bench loop` into `out`: asserts what holds whatever the host does; Err(why) if
/// the yielding layout missed too much in a run the machine disturbed.
fn bench_loop_once(out: &Path) -> Result<(), String> {
    let o = common::deltaloop(&[
        "bench",
        "loop",
        "--lockstep-seconds",
        "0.1",
        "--rt-seconds",
        "0.1",
        "--repeats",
        "1",
        "--out",
        out.to_str().unwrap(),
    ]);
    let (stdout, stderr) = (
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr),
    );
    assert!(o.status.success(), "{stdout}{stderr}");
    let last = stdout.lines().last().unwrap();
    let kv: BTreeMap<&str, &str> = last
        .split_whitespace()
        .map(|p| {
            p.split_once('=')
                .unwrap_or_else(|| panic!("{p:?} in {last}"))
        })
        .collect();
    // Either a number or, for what this machine may not give (cyclictest not installed, no
    // steal accounting), "na".
    let may_be_na = ["rt_split_steal_share", "cyclictest_p999_us"];
    let keys = [
        "lockstep_transport_shm_us",
        "lockstep_transport_iox_us",
        "lockstep_transport_uds_us",
        "transport_one_cpu_blocking_us",
        "handoff_shm_p50_us",
        "handoff_iox_p50_us",
        "handoff_uds_p50_us",
        "iox_one_thread_us",
        "handoff_iox_one_thread_p50_us",
        "lockstep_iox_hz",
        "inproc_hz",
        "lockstep_loop_us",
        "lockstep_handoff_us",
        "rt_rtt_p50_us",
        "rt_rtt_p999_us",
        "rt_wake_p999_us",
        "rt_miss_ratio",
        "rt_rtf",
        "rt_pauses",
        "rt_split_rtt_p50_us",
        "rt_split_rtt_p999_us",
        "rt_split_wake_p999_us",
        "rt_split_miss_ratio",
        "rt_split_rtf",
        "rt_split_pauses",
        "rt_split_steal_share",
        "rt_yield_rtt_p50_us",
        "rt_yield_rtt_p999_us",
        "rt_yield_wake_p999_us",
        "rt_yield_miss_ratio",
        "rt_yield_rtf",
        "rt_yield_pauses",
        "machine_wake_p999_us",
        "cyclictest_p999_us",
        "lockstep_transport_disturbed",
        "lockstep_transport_attempts",
    ];
    assert_eq!(
        kv.keys().copied().collect::<Vec<_>>(),
        {
            let mut k = keys.to_vec();
            k.sort_unstable();
            k
        },
        "{last}"
    );
    for (k, v) in &kv {
        if *v == "na" && may_be_na.contains(k) {
            continue;
        }
        let x: f64 = v.parse().unwrap_or_else(|_| panic!("{k}={v}"));
        assert!(x.is_finite(), "{k}={v}");
        // Per-cycle costs are differences of two rates, and the lockstep hand-off one of two
        // medians (round trip less compute): each may dip below zero in a noisy round;
        // everything else is a rate, a latency or a ratio measured on real cycles.
        if !(k.starts_with("lockstep_transport")
            || *k == "transport_one_cpu_blocking_us"
            || *k == "iox_one_thread_us"
            || *k == "lockstep_loop_us"
            || *k == "lockstep_handoff_us")
        {
            // Wake lateness counts from the deadline, which a plant that wakes early and busy-waits
            // meets: 0 is a real value.
            let may_be_zero = k.ends_with("miss_ratio")
                || k.ends_with("pauses")
                || k.ends_with("steal_share")
                || k.ends_with("wake_p999_us");
            assert!(x > 0.0 || (may_be_zero && x == 0.0), "{k}={v}");
        }
        // Simulated over wall time: 1 unless the plant paused for its own stalls.
        if k.ends_with("_rtf") {
            assert!(x <= 1.0, "{k}={v}");
        }
    }
    // The three realtime layouts ran every tick of S1 (0.8 s, ticks 0..=2667).
    for layout in ["realtime ", "realtime-split ", "realtime-yield "] {
        let line = stdout
            .lines()
            .find(|l| l.starts_with(&format!("(d) {layout}")))
            .unwrap_or_else(|| panic!("no (d) {layout} line: {stdout}"));
        assert!(line.contains(" of 2668 ("), "{line}");
    }
    for f in [
        "latency.png",
        "latency.svg",
        "lockstep/config.toml",
        "realtime/tdc-is-sta.round_trip.hgrm",
        "realtime/tdc-is-sta.latency.png",
        "realtime/tdc-is-sta.timeline.svg",
        "realtime-split/tdc-is-sta.round_trip.hgrm",
        "realtime-split/tdc-is-sta.timeline.png",
        "realtime-yield/tdc-is-sta.round_trip.hgrm",
        "realtime-yield/tdc-is-sta.latency.svg",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    assert!(
        !out.join("lockstep/uds.sock").exists(),
        "socket left behind"
    );
    // The helper controllers exited with their baselines.
    let needle = out.to_str().unwrap();
    for entry in std::fs::read_dir("/proc").unwrap().flatten() {
        if let Ok(cmd) = std::fs::read(entry.path().join("cmdline")) {
            let cmd = String::from_utf8_lossy(&cmd);
            assert!(
                !(cmd.contains("-controller") && cmd.contains(needle)),
                "a helper outlived the bench: {cmd}"
            );
        }
    }
    // What depends on timing, judged only on a run the machine left alone: yielding hands the
    // CPU over. A yield that did not (a spin, or a controller below the plant's priority) would
    // leave the controller no CPU until the plant's 150 µs poll ran out, a miss on every tick.
    let num = |k: &str| kv[k].parse::<f64>().unwrap();
    let yielded = stdout
        .lines()
        .find(|l| l.starts_with("(d) realtime-yield "))
        .unwrap();
    let check = if num("rt_yield_miss_ratio") >= 0.05 || num("rt_yield_rtt_p50_us") >= 100.0 {
        Err(format!("the yielding layout missed or lagged: {last}"))
    } else {
        Ok(())
    };
    judge(yield_run_disturbed(&kv, yielded), check)
}
