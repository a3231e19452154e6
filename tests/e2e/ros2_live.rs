//! `run --ros2` as a listening node meets it: when the live topics arrive against the loop's
//! own clock, and what `/diagnostics` says. A Cyclone DDS watcher (`examples/ros2/watch.py
//! --arrival`) takes every sample with its CLOCK_MONOTONIC arrival; the run's `<law>.timing.csv`
//! dates tick 0 on the same clock. Discovery stays on loopback, each test on a domain of its own.

use crate::common::python::{python, root, text};
use serde_json::Value;
use std::path::Path;
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

const TS_NS: u64 = 300_000;

/// The watcher of law `tdc` on `domain`, writing `out`, stamping arrivals.
fn watcher(domain: u16, out: &Path) -> Child {
    Command::new(python())
        .arg(root().join("examples/ros2/watch.py"))
        .args(["--domain", &domain.to_string(), "--law", "tdc", "--arrival"])
        .args(["--idle-s", "4", "--out", out.to_str().unwrap()])
        .current_dir(root())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("watch.py starts")
}

/// `run CONFIG --mode realtime --ros2 --out OUT` on `domain`, started.
fn live_run(domain: u16, config: &Path, out: &Path) -> Child {
    Command::new(env!("CARGO_BIN_EXE_deltaloop"))
        .args([
            "run",
            config.to_str().unwrap(),
            "--mode",
            "realtime",
            "--ros2",
        ])
        .args(["--out", out.to_str().unwrap()])
        .current_dir(root())
        .env("ROS_DOMAIN_ID", domain.to_string())
        .env_remove("ROS_AUTOMATIC_DISCOVERY_RANGE")
        .env_remove("ROS_LOCALHOST_ONLY")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("deltaloop starts")
}

fn wait(mut child: Child, limit: Duration, what: &str) -> Output {
    let t0 = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if t0.elapsed() > limit {
            let _ = child.kill();
            panic!("{what}: still running after {limit:?}");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    child.wait_with_output().unwrap()
}

/// S1 with `hold_s` of hold, tdc, a fault-test layout (unpinned, SCHED_OTHER: tests run in
/// parallel), every 10th tick published.
fn config(dir: &Path, hold_s: f64) -> std::path::PathBuf {
    let p = dir.join("live.toml");
    std::fs::write(
        &p,
        format!(
            "name = \"live\"\n[scenario]\npath = \"s1\"\nhold_s = {hold_s}\n[controller]\nlaws = [\"tdc\"]\n[faults]\ncontroller_silence_ticks = 3000\n[loop.realtime]\nplant_cpu = -1\ncontroller_cpu = -1\nsupervisor_cpu = -1\nplant_priority = 0\ncontroller_priority = 0\nwake_early_us = 0\nlock_memory = false\n[ros2]\nevery = 10\n"
        ),
    )
    .unwrap();
    p
}

/// The watcher's samples of `topic` (ROS name without the leading `/`).
fn samples(path: &Path, topic: &str) -> Vec<Value> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str::<Value>(l).unwrap())
        .filter(|v| v["topic"].as_str().unwrap().trim_start_matches("rt/") == topic)
        .collect()
}

fn stamp_ns(v: &Value) -> u64 {
    v["sec"].as_u64().unwrap() * 1_000_000_000 + v["nanosec"].as_u64().unwrap()
}

/// Each tick's deadline in `tdc.timing.csv` (CLOCK_MONOTONIC ns), by tick: when the loop ran
/// it (a loaded host's plant pauses simulated time over its own stalls, so tick k may run later
/// than tick 0 + k·Ts).
fn deadlines(out: &Path) -> std::collections::HashMap<u64, u64> {
    let t = std::fs::read_to_string(out.join("tdc.timing.csv")).unwrap();
    t.lines()
        .skip(1)
        .filter_map(|l| {
            let mut c = l.split(',');
            Some((c.next()?.parse().ok()?, c.next()?.parse().ok()?))
        })
        .collect()
}

/// Runs S1 + `hold_s` with the watcher listening from before the run; `during` gets the run's
/// child once the loop runs. The run's folder and the watcher's file.
fn watched_run(
    domain: u16,
    tmp: &Path,
    hold_s: f64,
    during: impl FnOnce(&Path),
) -> (std::path::PathBuf, std::path::PathBuf) {
    let (out, seen) = (tmp.join("run"), tmp.join("watch.jsonl"));
    let w = watcher(domain, &seen);
    // The watcher's participant is up before the run's (its topics are matched as they appear).
    std::thread::sleep(Duration::from_secs(2));
    let run = live_run(domain, &config(tmp, hold_s), &out);
    let t0 = Instant::now();
    while !out.join("tdc.timing.csv").is_file() {
        assert!(
            t0.elapsed() < Duration::from_secs(30),
            "the loop never started"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    during(&out);
    let o = wait(run, Duration::from_secs(120), "the run");
    assert!(o.status.success(), "the run: {}", text(&o.stderr));
    let w = wait(w, Duration::from_secs(60), "watch.py");
    assert!(w.status.success(), "watch.py: {}", text(&w.stderr));
    (out, seen)
}

/// Regression: at 3.3 kHz the live joint states came 2.5 s after their tick and then in a burst
/// at the end (the supervisor finished a tick 8192 ticks after it), and a ROS-default reader lost
/// samples in the bursts. Every joint state is stamped k·Ts; the first reaches a reader already
/// listening within 0.5 s of tick 0; arrival − the tick's deadline (`tdc.timing.csv`: on a quiet
/// host, tick 0's + k·Ts) has p99 ≤ 50 ms and varies by ≤ 0.2 s over the run (the first ticks
/// come together once DDS discovery has matched the watcher, tens of ms after tick 0).
#[test]
#[ignore = "about 20 s: an 8.8 s realtime run and a Cyclone DDS watcher"]
fn regression_live_joint_states_came_late_and_in_bursts() {
    let tmp = tempfile::tempdir().unwrap();
    let (out, seen) = watched_run(181, tmp.path(), 8.0, |_| {});
    let due = deadlines(&out);
    let js = samples(&seen, "deltaloop/tdc/joint_states");
    assert!(js.len() > 1000, "{} joint states", js.len());
    let mut late: Vec<i64> = js
        .iter()
        .filter_map(|m| {
            let s = stamp_ns(m);
            assert_eq!(
                s % (10 * TS_NS),
                0,
                "a stamp off k·Ts (every 10th tick): {m}"
            );
            let d = *due.get(&(s / TS_NS))?;
            Some(m["arrival_ns"].as_i64().unwrap() - d as i64)
        })
        .collect();
    let first_k = stamp_ns(&js[0]) / TS_NS;
    let first = js[0]["arrival_ns"].as_i64().unwrap() - due[&0] as i64;
    assert!(
        first < 500_000_000,
        "the first joint state (tick {first_k}) came {:.3} s after tick 0",
        first as f64 * 1e-9
    );
    late.sort_unstable();
    let ms = |ns: i64| ns as f64 * 1e-6;
    let p99 = late[late.len() * 99 / 100];
    let spread = late[late.len() - 1] - late[0];
    assert!(
        p99 <= 50_000_000 && spread <= 200_000_000,
        "arrival − tick time: p99 {:.1} ms, min {:.1} ms, max {:.1} ms",
        ms(p99),
        ms(late[0]),
        ms(late[late.len() - 1])
    );
}

/// Regression: each law's first `/diagnostics` status said `ticks=1 … real_time_factor=0.000`,
/// the last 8192 ticks were never reported, and no status was a WARN though the run missed
/// ticks. With the controller stopped for 40 ms (SIGSTOP) a second into the loop: the statuses
/// count every tick of the trace and every miss, each covers a second of the loop (at a
/// real-time factor, not 0), and one after the stop is a WARN.
#[test]
#[ignore = "about 12 s: a 3.8 s realtime run and a Cyclone DDS watcher"]
fn regression_diagnostics_miss_the_last_ticks_and_never_warn() {
    let tmp = tempfile::tempdir().unwrap();
    let (out, seen) = watched_run(182, tmp.path(), 3.0, |out| {
        std::thread::sleep(Duration::from_millis(1000));
        let pids = crate::common::children_mentioning(out.to_str().unwrap());
        let ctrl: Vec<u32> = pids
            .into_iter()
            .filter(|p| {
                std::fs::read(format!("/proc/{p}/cmdline"))
                    .is_ok_and(|c| text(&c).contains("deltaloop-controller"))
            })
            .collect();
        assert!(!ctrl.is_empty(), "the controller runs");
        for &p in &ctrl {
            // SAFETY: stopping and resuming a child of the run this test started.
            unsafe { libc::kill(p as i32, libc::SIGSTOP) };
        }
        std::thread::sleep(Duration::from_millis(40));
        for &p in &ctrl {
            unsafe { libc::kill(p as i32, libc::SIGCONT) };
        }
    });
    let trace = std::fs::read_to_string(out.join("trace.csv")).unwrap();
    let header: Vec<&str> = trace.lines().next().unwrap().split(',').collect();
    let reply = header.iter().position(|h| *h == "reply").unwrap();
    let rows: Vec<Vec<&str>> = trace
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect())
        .collect();
    let missed = rows.iter().filter(|r| r[reply] != "applied").count() as u64;
    assert!(missed > 0, "the 40 ms stop missed ticks");
    let diag: Vec<Value> = samples(&seen, "diagnostics")
        .into_iter()
        .map(|d| d["status"][0].clone())
        .filter(|s| s["name"] == "deltaloop/tdc")
        .collect();
    let num = |s: &Value, k: &str| -> f64 { s["values"][k].as_str().unwrap().parse().unwrap() };
    let ticks: f64 = diag.iter().map(|s| num(s, "ticks")).sum();
    let misses: f64 = diag.iter().map(|s| num(s, "misses")).sum();
    assert_eq!(
        ticks as usize,
        rows.len(),
        "the statuses count every tick of the trace: {diag:#?}"
    );
    assert_eq!(misses as u64, missed, "and every miss: {diag:#?}");
    // A status a second of wall time (a loaded host's plant pauses simulated time over its own
    // stalls: the loop may take longer than its 3.8 s), the last one for what is left.
    let due = deadlines(&out);
    let wall_s = (due.values().max().unwrap() - due[&0]) as f64 * 1e-9;
    assert!(
        (wall_s.floor() as usize..=wall_s.ceil() as usize + 1).contains(&diag.len()),
        "{} statuses over {wall_s:.2} s: {diag:#?}",
        diag.len()
    );
    for s in &diag[..diag.len() - 1] {
        let rtf = num(s, "real_time_factor");
        assert!(
            num(s, "ticks") > 300.0 && (0.1..=2.0).contains(&rtf),
            "a status of a second of the loop: {s}"
        );
    }
    let warned = diag
        .iter()
        .any(|s| s["level"].as_u64() == Some(1) && num(s, "misses") > 0.0);
    assert!(warned, "a WARN after the misses: {diag:#?}");
}
