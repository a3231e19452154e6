//! A realtime run of the real process pair: it tracks S1 as well as the inproc run allows, given
//! its measured latency and the deadlines it missed, writes its timing histograms, and replays
//! byte for byte; and `deltaloop bench loop` end to end. Their own test binary, so no other
//! test's processes share the CPUs with them (cargo runs test binaries one at a time), and one
//! at a time within it (both pin SCHED_FIFO loops to the same CPU).

mod common;

use common::{assert_clean, run};
use std::collections::BTreeMap;
use std::sync::Mutex;

/// Held by each test: two FIFO loops on one CPU would starve each other.
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

/// Whether the realtime run `sr` tracked each joint within its allowance of the inproc run `si`
/// (given the deadlines it missed); the first breach otherwise.
fn tracking_within_allowance(si: &serde_json::Value, sr: &serde_json::Value) -> Result<(), String> {
    for law in ["tde-is", "pid"] {
        let m = &sr["laws"][law];
        let t = &sr["timing"][law];
        if m["completed"] != true {
            return Err(format!("{law}: {m}"));
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

/// Whether the host stalled the plant of run `sr` a tick (300 µs) or more in some law.
fn stalled(sr: &serde_json::Value) -> bool {
    ["tde-is", "pid"].iter().any(|law| {
        sr["timing"][law]["wake_lateness"]["max_us"]
            .as_f64()
            .is_some_and(|us| us >= 300.0)
    })
}

#[test]
fn realtime_run_tracks_s1_close_to_inproc_and_writes_histograms() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("inproc"), tmp.path().join("rt"));
    let laws = ["--law", "tde-is", "--law", "pid"];
    let si = run("configs/s1-nominal.toml", "inproc", &a, &laws);
    // The host may stall the loop for milliseconds (a shared 2-vCPU VM): a run it stalled (the
    // plant woke a tick or more late) and that missed the allowance below is run again, at most
    // three times, each such attempt said on stderr (regression: one stall of 5 ms, 78 misses,
    // failed the test while another build ran).
    let mut sr = serde_json::Value::Null;
    for attempt in 1..=3 {
        let _ = std::fs::remove_dir_all(&b);
        sr = run("configs/s1-nominal.toml", "realtime", &b, &laws);
        match tracking_within_allowance(&si, &sr) {
            Ok(()) => break,
            Err(why) if attempt < 3 && stalled(&sr) => {
                eprintln!("attempt {attempt}: the host stalled the loop: {why}");
            }
            Err(why) => panic!("{why}"),
        }
    }
    for law in ["tde-is", "pid"] {
        let m = &sr["laws"][law];
        let t = &sr["timing"][law];
        assert_eq!(m["completed"], true, "{law}: {m}");
        assert_eq!(t["ticks"], 2668);
        assert!(t["round_trip"]["p50_us"].as_f64().unwrap() > 0.0);
        for h in [
            "round_trip",
            "wake_lateness",
            "period_jitter",
            "state_to_controller",
            "controller_compute",
        ] {
            let text = std::fs::read_to_string(b.join(format!("{law}.{h}.hgrm"))).unwrap();
            assert!(
                text.lines()
                    .filter(|l| l.trim_start().starts_with(|c: char| c.is_ascii_digit()))
                    .count()
                    > 10,
                "{law}.{h}.hgrm is thin"
            );
        }
    }
    let report = std::fs::read_to_string(b.join("report.md")).unwrap();
    assert!(report.contains("## Loop timing (realtime)") && report.contains("deadline misses"));
    assert!(report.contains("measured latency cost: RMS ×"), "{report}");
    // Each reply acted at its measured arrival, recorded per tick: the run replays in-process
    // byte for byte from its folder alone.
    let trace = std::fs::read_to_string(b.join("trace.csv")).unwrap();
    let arrivals: Vec<u64> = trace
        .lines()
        .skip(1)
        .filter_map(|l| l.rsplit(',').next()?.parse().ok())
        .collect();
    // Measured from the tick's deadline: a real latency (tens of µs at the median), longer when
    // the plant woke late, never absurd.
    let mut sorted = arrivals.clone();
    sorted.sort_unstable();
    assert!(arrivals.len() > 5000, "{} arrivals", arrivals.len());
    assert!(
        sorted[sorted.len() / 2] > 1_000,
        "median arrival {} ns",
        sorted[sorted.len() / 2]
    );
    assert!(*sorted.last().unwrap() < 1_000_000_000);
    // Regression: tick 0 was missed in most runs (iceoryx2 connected the ports, mapping each
    // peer's data segment, inside tick 0's budget; then the notifiers still opened their
    // listener's socket in the first notify: tick 0's round trip 135–190 µs of 150). The cause is
    // guarded deterministically by protocol/transport/tests/connect_now.rs. Here only what a busy
    // host cannot fake: a systematic regression misses tick 0 in every law, while one disturbed
    // tick 0 (it is the slowest tick of a run, ≈ 120 µs in a debug build) may miss in one of them.
    let tick0: Vec<String> = ["tde-is", "pid"]
        .iter()
        .map(|law| {
            let row0 = trace
                .lines()
                .find(|l| l.starts_with(&format!("{law},0,")))
                .unwrap_or_else(|| panic!("no tick 0 of {law}"));
            row0.split(',').nth_back(2).unwrap().to_string()
        })
        .collect();
    assert!(
        tick0.iter().any(|r| r == "applied"),
        "tick 0 missed in every law: {tick0:?}"
    );
    let o = common::deltaloop(&["replay", b.to_str().unwrap()]);
    let (out, err) = (
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr),
    );
    assert!(
        o.status.success() && out.contains("byte for byte"),
        "{out}{err}"
    );
    assert_clean(&b, &sr);
}

/// `deltaloop bench loop`, short: every baseline and loop runs to its end, the helpers exit, the
/// last line carries every key with a number, and the files docs/performance.md points at are there.
#[test]
fn bench_loop_runs_every_measurement_and_ends_with_its_key_value_line() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("bench");
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
        "rt_split_rtt_p50_us",
        "rt_split_rtt_p999_us",
        "rt_split_wake_p999_us",
        "rt_split_miss_ratio",
        "rt_split_steal_share",
        "rt_yield_rtt_p50_us",
        "rt_yield_rtt_p999_us",
        "rt_yield_wake_p999_us",
        "rt_yield_miss_ratio",
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
        // Per-cycle costs are differences of two rates and may dip below zero in a noisy round;
        // everything else is a rate, a latency or a ratio measured on real cycles.
        if !(k.starts_with("lockstep_transport")
            || *k == "transport_one_cpu_blocking_us"
            || *k == "iox_one_thread_us")
            && *k != "lockstep_loop_us"
        {
            // Wake lateness counts from the deadline, which a plant that wakes early and busy-waits
            // meets: 0 is a real value.
            let may_be_zero = k.ends_with("miss_ratio")
                || k.ends_with("steal_share")
                || k.ends_with("wake_p999_us");
            assert!(x > 0.0 || (may_be_zero && x == 0.0), "{k}={v}");
        }
    }
    // Yielding hands the CPU over: a yield that did not (a spin, or a controller below the
    // plant's priority) would leave the controller no CPU until the plant's 150 µs poll ran out,
    // a miss on every tick.
    let num = |k: &str| kv[k].parse::<f64>().unwrap();
    assert!(num("rt_yield_miss_ratio") < 0.05, "{last}");
    assert!(num("rt_yield_rtt_p50_us") < 100.0, "{last}");
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
}
