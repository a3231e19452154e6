//! Helpers shared by the end-to-end tests.

use iceoryx2::node::NodeView;
use iceoryx2::prelude::*;
pub mod python;

#[allow(unused_imports)]
pub use deltaloop_study::record::{FaultKind, RunStatus};
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Runs `deltaloop` with `args` from the repository root.
pub fn deltaloop(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_deltaloop"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("deltaloop runs")
}

/// `deltaloop <args>` started from the repository root, output captured.
pub fn spawn(args: &[&str]) -> std::process::Child {
    Command::new(env!("CARGO_BIN_EXE_deltaloop"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("deltaloop starts")
}

/// [`spawn`] in a process group of its own, so that a signal to the group reaches the
/// supervisor and its children as a terminal's Ctrl-C does.
pub fn spawn_group(args: &[&str]) -> std::process::Child {
    use std::os::unix::process::CommandExt;
    Command::new(env!("CARGO_BIN_EXE_deltaloop"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .process_group(0)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("deltaloop starts")
}

/// Waits for `child` at most `limit`; kills it (and fails) if it takes longer.
pub fn finish_within(
    mut child: std::process::Child,
    limit: std::time::Duration,
    what: &str,
) -> Output {
    let t0 = std::time::Instant::now();
    while child.try_wait().unwrap().is_none() {
        if t0.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            panic!("{what}: still running after {limit:?}");
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    child.wait_with_output().unwrap()
}

/// Asserts exit 1 with exactly one line on stderr, no panic; returns that line.
pub fn one_line_error(out: &Output) -> String {
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert_eq!(err.lines().count(), 1, "not one line: {err:?}");
    assert!(!err.contains("panicked"), "{err}");
    err.trim_end().to_string()
}

/// Makes a FIFO (named pipe) at `path`.
pub fn mkfifo(path: &Path) {
    let c = std::ffi::CString::new(path.to_str().unwrap()).unwrap();
    // SAFETY: a valid NUL-terminated path; mkfifo only reads it.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0, "mkfifo");
}

/// Process ids of `deltaloop-plant`/`deltaloop-controller` whose command line mentions `needle`.
pub fn children_mentioning(needle: &str) -> Vec<u32> {
    let mut found = Vec::new();
    for entry in std::fs::read_dir("/proc").unwrap().flatten() {
        let Ok(pid) = entry.file_name().to_string_lossy().parse::<u32>() else {
            continue;
        };
        let Ok(cmd) = std::fs::read(entry.path().join("cmdline")) else {
            continue;
        };
        let cmd = String::from_utf8_lossy(&cmd);
        if (cmd.contains("deltaloop-plant") || cmd.contains("deltaloop-controller"))
            && cmd.contains(needle)
        {
            found.push(pid);
        }
    }
    found
}

/// iceoryx2 nodes and services whose name carries `run_id`.
pub fn iceoryx_leftovers(run_id: &str) -> Vec<String> {
    let config = Config::default();
    let mut left = Vec::new();
    Node::<ipc::Service>::list(&config, |state| {
        let name = match &state {
            NodeState::Alive(v) => v.details().as_ref().map(|d| d.name().to_string()),
            NodeState::Dead(v) => v.details().as_ref().map(|d| d.name().to_string()),
            _ => None,
        };
        if let Some(n) = name.filter(|n| n.contains(run_id)) {
            left.push(format!("node {n}"));
        }
        CallbackProgression::Continue
    })
    .unwrap();
    ipc::Service::list(&config, |s| {
        let name = s.static_details.name().to_string();
        if name.contains(run_id) {
            left.push(format!("service {name}"));
        }
        CallbackProgression::Continue
    })
    .unwrap();
    left
}

/// `deltaloop run <config> --mode <mode> --out <out> <extra…>`, however it ends.
pub fn run_output(config: &str, mode: &str, out: &Path, extra: &[&str]) -> Output {
    let mut args = vec![
        "run",
        config,
        "--mode",
        mode,
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    // A realtime run names its misses' causes where it can, so a test's INCONCLUSIVE verdict
    // (its disturbance line) says what took the ticks.
    if mode == "realtime" && can_explain() && !args.contains(&"--explain") {
        args.push("--explain");
    }
    deltaloop(&args)
}

/// The rows of a CSV file, each by column name.
pub fn csv_rows(path: &Path) -> Vec<std::collections::HashMap<String, String>> {
    let mut r = csv::Reader::from_path(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let head: Vec<String> = r.headers().unwrap().iter().map(str::to_string).collect();
    r.records()
        .map(|x| {
            let x = x.unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            head.iter()
                .cloned()
                .zip(x.iter().map(str::to_string))
                .collect()
        })
        .collect()
}

/// Whether this host lets a run record the kernel's events (`--explain`: root and a tracefs
/// that takes a new instance; a container may show tracefs read-only). Probed once.
pub fn can_explain() -> bool {
    static CAN: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *CAN.get_or_init(|| {
        // SAFETY: geteuid has no preconditions.
        if unsafe { libc::geteuid() } != 0 {
            return false;
        }
        let probe = Path::new("/sys/kernel/tracing/instances")
            .join(format!("deltaloop-probe-{}", std::process::id()));
        let made = std::fs::create_dir(&probe).is_ok();
        let _ = std::fs::remove_dir(&probe);
        made
    })
}

/// `deltaloop run <config> --mode <mode> --out <out> <extra…>`, asserted to succeed; its summary.json.
pub fn run(config: &str, mode: &str, out: &Path, extra: &[&str]) -> Value {
    let o = run_output(config, mode, out, extra);
    assert!(
        o.status.success(),
        "{mode} run failed: {}\n{}",
        String::from_utf8_lossy(&o.stderr),
        String::from_utf8_lossy(&o.stdout)
    );
    summary(out)
}

/// No child process and no iceoryx2 node or service of the run is left.
pub fn assert_clean(out: &Path, summary: &Value) {
    assert!(
        children_mentioning(out.to_str().unwrap()).is_empty(),
        "child processes outlived the run"
    );
    let ids = summary["run_ids"]
        .as_object()
        .expect("process runs record their run ids");
    assert!(!ids.is_empty());
    for id in ids.values() {
        let left = iceoryx_leftovers(id.as_str().unwrap());
        assert!(left.is_empty(), "iceoryx2 resources left behind: {left:?}");
    }
}

/// A JSON file, parsed.
pub fn json(p: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
}

/// A run folder's summary.json, parsed.
pub fn summary(dir: &Path) -> Value {
    json(&dir.join("summary.json"))
}

/// The max-joint RMS tracking error (rad) of `law` in a summary.
pub fn max_joint_rms(summary: &Value, law: &str) -> f64 {
    summary["laws"][law]["rms_rad"]
        .as_array()
        .unwrap_or_else(|| panic!("no rms_rad of {law}"))
        .iter()
        .map(|v| v.as_f64().unwrap())
        .fold(0.0, f64::max)
}

/// How `law` ended, as its summary says: the typed `status` and, for a fault, its `fault_kind`.
pub fn outcome(summary: &Value, law: &str) -> (RunStatus, Option<FaultKind>) {
    let m = &summary["laws"][law];
    let status = serde_json::from_value(m["status"].clone())
        .unwrap_or_else(|e| panic!("status of {law}: {e}: {m}"));
    let kind = serde_json::from_value(m["fault_kind"].clone())
        .unwrap_or_else(|e| panic!("fault_kind of {law}: {e}: {m}"));
    (status, kind)
}

/// A long run of `law` in `out` completed with every tick on disk and nothing lost on any stream;
/// returns its peak RSS (MiB) of supervisor, plant and controller.
pub fn assert_complete_and_kept(summary: &Value, out: &Path, law: &str) -> [f64; 3] {
    let rss = assert_complete(summary, out, law);
    let m = &summary["laws"][law];
    let f = std::fs::File::open(out.join("trace.csv")).unwrap();
    let lines = std::io::BufRead::lines(std::io::BufReader::new(f)).count() as u64;
    assert_eq!(
        lines,
        m["ticks"].as_u64().unwrap() + 2,
        "header + ticks 0..=N"
    );
    rss
}

/// `law` ran every tick the scenario planned (0..=N) and the supervisor saw every message of
/// each: the summary says so, and the round-trip interval log on disk holds N + 1 round trips.
/// Each process's peak memory (MiB: supervisor, plant, controller).
pub fn assert_complete(summary: &Value, out: &Path, law: &str) -> [f64; 3] {
    let m = &summary["laws"][law];
    assert_eq!(outcome(summary, law), (RunStatus::Ok, None), "{m}");
    assert_eq!(m["lost_ticks"], 0, "{m}");
    assert_eq!(m["ticks"], summary["ticks"], "{m}");
    let t = &summary["timing"][law];
    let lost = &t["supervisor_lost_samples"];
    for stream in ["state", "torque", "telemetry"] {
        assert_eq!(lost[stream], 0, "{lost}");
    }
    let ticks = m["ticks"].as_u64().unwrap() + 1;
    assert_eq!(t["ticks"], ticks, "{t}");
    assert_eq!(t["round_trip"]["count"], ticks, "{t}");
    let log = out.join(format!("{law}.round_trip.hlog"));
    let logged: u64 = deltaloop_timing::hlog::read(&log)
        .unwrap()
        .intervals
        .iter()
        .map(|iv| iv.hist.len())
        .sum();
    assert_eq!(logged, ticks, "round trips in {}", log.display());
    let rss = &t["peak_rss_mib"];
    ["supervisor", "plant", "controller"].map(|w| rss[w].as_f64().unwrap())
}

/// Each process's peak memory in the long run is at most 1.2× the short run's, or at most 10 MiB
/// more: a process's peak includes the pages of fixed-size shared-memory segments (≈ 19 MiB per
/// run in all) that it touches as its queues fill, which depends on how far the load lets it fall
/// behind, not on the run's length. Growth per tick would show as hundreds of MiB here.
pub fn assert_memory_flat(short: [f64; 3], long: [f64; 3]) {
    for (i, who) in ["supervisor", "plant", "controller"].iter().enumerate() {
        assert!(
            long[i] <= 1.2 * short[i] || long[i] - short[i] <= 10.0,
            "{who}: {} MiB in the long run vs {} MiB",
            long[i],
            short[i]
        );
    }
}

/// Every wire type with its fields in declaration order, each passed to the macro `$m` as
/// `$m!(Type { field, … })`; a `Vec` of the results. The one list the layout tests share.
#[allow(unused_macros)]
macro_rules! wire_types {
    ($m:ident) => {
        vec![
            $m!(StateMsg {
                tick,
                flags,
                _pad,
                q,
                qd,
                tau_applied,
                q_true,
                qd_true,
                t_deadline_ns,
                t_wake_ns,
                t_publish_ns,
                t_poll_until_ns
            }),
            $m!(TorqueMsg {
                tick,
                skipped,
                tau,
                s,
                n_hat,
                u,
                t_state_rx_ns,
                t_publish_ns,
                t_poll_until_ns
            }),
            $m!(TelemetryMsg {
                tick,
                flags,
                _pad,
                t_deadline_ns,
                t_wake_ns,
                t_state_pub_ns,
                t_torque_rx_ns,
                late_dropped,
                misses,
                arrival_ns
            }),
            $m!(ControlMsg {
                kind,
                from,
                tick,
                ticks,
                q0,
                t0_ns,
                text
            }),
            $m!(RefSample { tick, q, qd, qdd }),
        ]
    };
}
#[allow(unused_imports)]
pub(crate) use wire_types;

/// Why the machine may have disturbed the timing of `law` in a realtime run, as the run's own
/// record says (`timing.<law>.disturbance`: the plant paused or woke a tick or more late, misses
/// beyond 2 % of the ticks or a burst of 5, with the host's steal); None: nothing in the record.
pub fn disturbance(summary: &Value, law: &str) -> Option<String> {
    summary["timing"][law]["disturbance"]
        .as_str()
        .map(|why| format!("{law}: {why}"))
}

/// A timing-dependent outcome, judged by the run's record: Ok if it held (`check`); Err(why) if
/// it did not in a run the machine disturbed (`disturbed`: see [`disturbance`]), which says
/// nothing about the code and is run again; a panic if it did not in an undisturbed run.
pub fn judge(disturbed: Option<String>, check: Result<(), String>) -> Result<(), String> {
    match (check, disturbed) {
        (Ok(()), _) => Ok(()),
        (Err(wrong), Some(why)) => Err(format!("{wrong} (disturbed: {why})")),
        (Err(wrong), None) => panic!("undisturbed and still wrong: {wrong}"),
    }
}

/// How many times a realtime test is attempted before it is called inconclusive.
pub const ATTEMPTS: u32 = 3;

/// A realtime test on a host that may stall it: `attempt(n)` (n = 1..=[`ATTEMPTS`]) asserts
/// what must hold whatever the host does itself (a panic is a failure) and returns Err(why) only
/// when an outcome that depends on timing failed in a run the machine disturbed (see [`judge`]).
/// Each such attempt is said on stderr and run again; after the last, one line
/// `INCONCLUSIVE on this host: <test>: <why>` and None (the timing outcome is not asserted: CI
/// must not fail on a hypervisor's bad hour). The first attempt that returns Ok gives Some.
pub fn on_a_noisy_host<T>(
    test: &str,
    mut attempt: impl FnMut(u32) -> Result<T, String>,
) -> Option<T> {
    for n in 1..=ATTEMPTS {
        // One line each, whatever the reason quotes (a run's stderr).
        // Straight to stderr, past the test harness's capture: a retry and an inconclusive
        // test show in the log of a passing run too (and can be counted).
        let say = |line: String| {
            use std::io::Write as _;
            let _ = writeln!(std::io::stderr(), "{line}");
        };
        match attempt(n).map_err(|why| why.lines().collect::<Vec<_>>().join(" ⏎ ")) {
            Ok(v) => return Some(v),
            Err(why) if n < ATTEMPTS => say(format!(
                "{test}: attempt {n} of {ATTEMPTS} disturbed by the machine, run again: {why}"
            )),
            Err(why) => say(format!("INCONCLUSIVE on this host: {test}: {why}")),
        }
    }
    None
}

/// The plant's own stalls in the record of `law` (its process woke late: simulated time paused,
/// or it woke a tick or more late), whatever else the record says; None if it kept to the clock.
pub fn plant_stalled(summary: &Value, law: &str) -> Option<String> {
    let t = &summary["timing"][law];
    let ts_us = summary["ts_s"].as_f64().unwrap_or(3e-4) * 1e6;
    let pauses = t["pauses"].as_u64().unwrap_or(0);
    let late_us = t["wake_lateness"]["max_us"].as_f64().unwrap_or(0.0);
    (pauses > 0 || late_us >= ts_us).then(|| {
        format!(
            "{law}: the plant paused {pauses} time(s) ({} ms) and woke at worst {late_us} µs late",
            t["paused_ms"]
        )
    })
}

/// Misses in the record of `law` beyond what the run's classifier allows (more than
/// [`MAX_MISS_SHARE`](deltaloop_timing::MAX_MISS_SHARE) of the ticks, or a burst
/// of [`MAX_MISS_BURST`](deltaloop_timing::MAX_MISS_BURST)), whatever else it says.
pub fn missed_too_many(summary: &Value, law: &str) -> Option<String> {
    use deltaloop_timing::{MAX_MISS_BURST, MAX_MISS_SHARE};
    let t = &summary["timing"][law];
    let share = t["miss_ratio"].as_f64().unwrap_or(0.0);
    let burst = t["max_consecutive_misses"].as_u64().unwrap_or(0);
    (share > MAX_MISS_SHARE || burst >= MAX_MISS_BURST).then(|| {
        format!(
            "{law}: {} misses ({:.1} %), {burst} in a row",
            t["deadline_misses"],
            share * 100.0
        )
    })
}

/// The ticks of `law` in the run folder's trace.csv, in order.
pub fn trace_ticks(out: &Path, law: &str) -> Vec<u64> {
    let f = std::fs::File::open(out.join("trace.csv")).unwrap();
    let prefix = format!("{law},");
    std::io::BufRead::lines(std::io::BufReader::new(f))
        .skip(1)
        .map(Result::unwrap)
        .filter_map(|l| {
            let rest = l.strip_prefix(&prefix)?;
            Some(rest.split(',').next().unwrap().parse().unwrap())
        })
        .collect()
}

/// What holds whatever the host did: `law` ended with a typed status (returned), every tick of
/// its record is on disk in order (`ticks` counts the ticks after tick 0 the metrics cover, so
/// the trace has `ticks` + 1 rows), and a tick missing between them is one the summary counts
/// as lost (`lost_ticks` may also count ticks after the last row: a fault's own tick).
pub fn assert_every_tick_on_disk(summary: &Value, out: &Path, law: &str) -> RunStatus {
    let (status, _) = outcome(summary, law);
    let m = &summary["laws"][law];
    let ticks = m["ticks"]
        .as_u64()
        .unwrap_or_else(|| panic!("ticks of {law}: {m}"));
    let lost = m["lost_ticks"].as_u64().unwrap_or(0);
    let ks = trace_ticks(out, law);
    assert_every_tick_counted(&ks, ticks, lost, &format!("{law}: {m}"));
    status
}

/// The rule of [`assert_every_tick_on_disk`] over a law's trace ticks `ks`.
fn assert_every_tick_counted(ks: &[u64], ticks: u64, lost: u64, what: &str) {
    assert_eq!(
        ks.len() as u64,
        ticks + 1,
        "trace rows vs ticks 0..={ticks}: {what}"
    );
    assert!(
        ks.windows(2).all(|w| w[0] < w[1]),
        "ticks out of order: {what}"
    );
    let holes = ks.last().map_or(0, |&last| last + 1 - ks.len() as u64);
    assert!(
        ks.first().is_none_or(|&k| k == 0) && holes <= lost,
        "{holes} ticks missing from the trace, {lost} counted lost: {what}"
    );
}

/// Regression: the rule read `ticks` (ticks after tick 0 the metrics cover, records − 1) as the
/// last tick, so a run with ticks lost in the middle and counted as lost failed it.
#[test]
fn regression_every_tick_on_disk_accepts_ticks_counted_lost() {
    assert_every_tick_counted(&[0, 1, 2, 3], 3, 0, "whole");
    assert_every_tick_counted(&[0, 1, 5, 6], 3, 3, "ticks 2..=4 lost");
    assert_every_tick_counted(&[0, 1, 2], 2, 7, "lost after the last row");
    let uncounted = std::panic::catch_unwind(|| assert_every_tick_counted(&[0, 1, 5], 2, 1, "x"));
    assert!(uncounted.is_err(), "three missing, one counted lost");
    let short = std::panic::catch_unwind(|| assert_every_tick_counted(&[0, 1], 2, 0, "x"));
    assert!(short.is_err(), "fewer rows than the metrics cover");
}

/// `deltaloop replay <out>` reproduces the run's trace.csv byte for byte.
pub fn assert_replays(out: &Path) {
    let o = deltaloop(&["replay", out.to_str().unwrap()]);
    let (stdout, stderr) = (
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr),
    );
    assert!(
        o.status.success() && stdout.contains("byte for byte"),
        "replay of {}: {stdout}{stderr}",
        out.display()
    );
}

/// The folder holding the C ABI's library (`libdeltaloop_peer.so`, built with the tests: a
/// dev-dependency), next to the test binary.
pub fn peer_lib_dir() -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    let dir = exe.parent().unwrap().to_path_buf();
    assert!(
        dir.join("libdeltaloop_peer.so").is_file(),
        "no libdeltaloop_peer.so in {}",
        dir.display()
    );
    dir
}

/// `examples/<example>`'s program `exe`, built once with its `make` against this build's library
/// (into the target folder); None (and one line saying what is missing) without the compiler
/// (`cc` or `c++`) or make.
pub fn built(example: &'static str, exe: &str, compiler: &str) -> Option<PathBuf> {
    static BUILT: std::sync::Mutex<std::collections::BTreeMap<&'static str, Option<PathBuf>>> =
        std::sync::Mutex::new(std::collections::BTreeMap::new());
    let mut built = BUILT.lock().unwrap_or_else(|e| e.into_inner());
    built
        .entry(example)
        .or_insert_with(|| {
            for tool in [compiler, "make"] {
                if std::process::Command::new(tool)
                    .arg("--version")
                    .output()
                    .is_err()
                {
                    eprintln!(
                        "SKIPPED: no `{tool}` on this machine (apt-get install build-essential)"
                    );
                    return None;
                }
            }
            let lib = peer_lib_dir();
            let path = lib.join(exe);
            let o = std::process::Command::new("make")
                .arg("-C")
                .arg(python::root().join("examples").join(example))
                .arg(format!("LIB={}", lib.display()))
                .arg(format!("OUT={}", path.display()))
                .arg("--always-make")
                .output()
                .unwrap();
            assert!(
                o.status.success(),
                "make {example}: {}",
                python::text(&o.stderr)
            );
            Some(path)
        })
        .clone()
}

/// `tests/peers/<name>.c` built against this build's library (C99, every warning an error), once;
/// None (and one line saying so) without `cc`.
pub fn c_peer(name: &'static str) -> Option<PathBuf> {
    static BUILT: std::sync::Mutex<std::collections::BTreeMap<&'static str, Option<PathBuf>>> =
        std::sync::Mutex::new(std::collections::BTreeMap::new());
    let mut built = BUILT.lock().unwrap_or_else(|e| e.into_inner());
    built
        .entry(name)
        .or_insert_with(|| {
            if std::process::Command::new("cc")
                .arg("--version")
                .output()
                .is_err()
            {
                eprintln!("SKIPPED: no `cc` on this machine (apt-get install build-essential)");
                return None;
            }
            let (lib, root) = (peer_lib_dir(), python::root());
            let exe = lib.join(name);
            let o = std::process::Command::new("cc")
                .args(["-std=c99", "-Wall", "-Wextra", "-Werror", "-I"])
                .arg(root.join("peer/include"))
                .arg(root.join("tests/peers").join(format!("{name}.c")))
                .arg("-o")
                .arg(&exe)
                .arg(format!("-L{}", lib.display()))
                // DT_RPATH, not DT_RUNPATH: the library built with these tests, even when cargo's
                // LD_LIBRARY_PATH names another build's (target/debug after a `cargo build`).
                .arg(format!("-Wl,--disable-new-dtags,-rpath,{}", lib.display()))
                .arg("-ldeltaloop_peer")
                .output()
                .unwrap();
            assert!(
                o.status.success(),
                "cc {name}.c: {}",
                python::text(&o.stderr)
            );
            Some(exe)
        })
        .clone()
}

/// The C `tdc` controller (examples/c-controller).
pub fn c_tdc() -> Option<PathBuf> {
    built("c-controller", "c-tdc", "cc")
}

/// The run id of the live run whose config lies in `out` (from its children's command lines).
pub fn run_id_of(out: &Path, run: &mut std::process::Child) -> String {
    let end = std::time::Instant::now() + std::time::Duration::from_secs(20);
    loop {
        for pid in children_mentioning(out.to_str().unwrap()) {
            let cmd = std::fs::read(format!("/proc/{pid}/cmdline")).unwrap_or_default();
            let args: Vec<String> = cmd
                .split(|&b| b == 0)
                .map(|a| String::from_utf8_lossy(a).into_owned())
                .collect();
            if let Some(i) = args.iter().position(|a| a == "--run-id") {
                return args[i + 1].clone();
            }
        }
        assert!(run.try_wait().unwrap().is_none(), "the run ended early");
        assert!(
            std::time::Instant::now() < end,
            "the run's processes never showed up"
        );
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
}

/// A controller that reported an error answering tick 200 (`said`, quoted in the fault) ended
/// the run in `out` as its own fault at that tick, and at once: the plant's record of tick 200
/// (its state, then the stop) follows tick 199's, not a silence window (2 s in lockstep) later.
pub fn assert_step_error_stopped_the_loop_at_once(out: &Path, said: &str) {
    let s = summary(out);
    let m = &s["laws"]["tdc"];
    assert_eq!(
        outcome(&s, "tdc"),
        (RunStatus::Fault, Some(FaultKind::ControllerFailed)),
        "{m}"
    );
    assert_eq!(m["status_tick"], 200, "{m}");
    let fault = m["fault"].as_str().unwrap_or_default();
    assert!(fault.contains(said), "{fault}");
    assert!(!fault.contains("controller silent"), "{fault}");
    let mut rd = csv::Reader::from_path(out.join("tdc.timing.csv")).unwrap();
    let published: std::collections::BTreeMap<u64, u64> = rd
        .records()
        .map(|r| r.unwrap())
        .filter_map(|r| Some((r[0].parse().ok()?, r[3].parse().ok()?)))
        .collect();
    let gap_ms = (published[&200] - published[&199]) as f64 * 1e-6;
    assert!(gap_ms < 1000.0, "tick 200 came {gap_ms} ms after tick 199");
}
