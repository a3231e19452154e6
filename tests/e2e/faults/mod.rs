//! Faults, signals and debris, end to end with real processes and real signals. Each test checks
//! the exit code, the message, the files on disk, and that no child process outlives the run.

use crate::common;
use common::spawn;

use common::{
    FaultKind, RunStatus, children_mentioning, deltaloop, iceoryx_leftovers, outcome, summary,
};
use serde_json::Value;
use std::path::Path;
use std::process::Child;
use std::time::{Duration, Instant};

mod crashes;
mod long;
mod signals;
mod stalls;
mod supervisor_stopped;

/// S1 plus a hold (long enough to act on mid-run), one law, realtime unless `extra` says otherwise.
fn config(dir: &Path, hold_s: f64, extra: &str) -> String {
    let p = dir.join("cfg.toml");
    // Tests run in parallel. Several SCHED_FIFO loops pinned to one CPU starve each other's
    // controllers (FIFO does not time-slice), so these runs use a fair layout (unpinned,
    // SCHED_OTHER, no early-wake spin) and a 300-tick (90 ms) silence window: what they test is
    // fault handling, not latency.
    let silence = "[faults]\ncontroller_silence_ticks = 300\n";
    let faults = if extra.contains("[faults]") {
        extra.replace("[faults]\n", silence)
    } else {
        format!("{extra}{silence}")
    };
    let layout = "[loop.realtime]\nplant_cpu = -1\ncontroller_cpu = -1\nsupervisor_cpu = -1\nplant_priority = 0\ncontroller_priority = 0\nwake_early_us = 0\nlock_memory = false\n";
    let layout = if faults.contains("[loop.realtime]") {
        String::new()
    } else {
        layout.to_string()
    };
    std::fs::write(&p, format!("name = \"fault\"\n[scenario]\npath = \"s1\"\nhold_s = {hold_s}\n[plant]\nfriction = true\n[controller]\nlaws = [\"tdc\"]\n{faults}{layout}")).unwrap();
    p.display().to_string()
}

/// The processes of the run in `out` whose command line contains `who`.
fn pids_of(out: &Path, who: &str) -> Vec<u32> {
    children_mentioning(out.to_str().unwrap())
        .into_iter()
        .filter(|&p| {
            std::fs::read(format!("/proc/{p}/cmdline"))
                .is_ok_and(|c| String::from_utf8_lossy(&c).contains(who))
        })
        .collect()
}

/// Whether the loop of `out` has started: the supervisor creates `tdc.timing.csv` once the
/// handshake is done, just before START (the children's logs exist from their spawn, before the
/// handshake: regression, a supervisor stopped 800 ms after them on a loaded host was stopped
/// before START, lost nothing, and the run that should have lost data ended ok).
fn loop_started(out: &Path) -> bool {
    out.join("tdc.timing.csv").is_file()
}

/// Waits until the loop of `out` runs plus `after_ms`, then sends `sig` to `who`.
fn signal_child(out: &Path, who: &str, sig: i32, after_ms: u64) {
    let t0 = Instant::now();
    loop {
        let pids = pids_of(out, who);
        if loop_started(out) && !pids.is_empty() {
            std::thread::sleep(Duration::from_millis(after_ms));
            for p in pids {
                // SAFETY: signalling a process we found by its command line.
                unsafe { libc::kill(p as i32, sig) };
            }
            return;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(20),
            "the pair never started"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn finish(child: Child) -> (Option<i32>, String) {
    let o = child.wait_with_output().unwrap();
    (
        o.status.code(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

/// The run folder is complete and no process or iceoryx2 resource of it is left.
fn assert_kept_and_clean(out: &Path) -> Value {
    for f in [
        "config.toml",
        "trace.csv",
        "summary.json",
        "report.md",
        "tdc.timing.csv",
    ] {
        assert!(out.join(f).exists(), "{f} missing");
    }
    assert!(
        std::fs::read_to_string(out.join("trace.csv"))
            .unwrap()
            .lines()
            .count()
            > 100,
        "the trace up to the stop is kept"
    );
    assert!(
        children_mentioning(out.to_str().unwrap()).is_empty(),
        "a child outlived the run"
    );
    let s = summary(out);
    for id in s["run_ids"].as_object().unwrap().values() {
        assert!(iceoryx_leftovers(id.as_str().unwrap()).is_empty());
    }
    s
}
